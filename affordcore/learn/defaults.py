"""The shipped default models, rebuilt reproducibly: generate rooms, train every affordance, write the files.

Training uses a 0.2 m pose grid (features do not depend on the grid step, and the positives keep their
density): the 0.1 m grid over a dozen generated rooms is millions of poses per affordance, more than the
scikit-learn baselines fit in memory, and it teaches a linear model nothing the 0.2 m grid does not.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..settings import Settings
from ..skeleton import skeleton_files

ROOMS, SEED, KINDS, TRAIN_STEP = 12, 1, ("living", "office", "workshop"), 0.2


def winners(results_json: Path) -> dict[str, str]:
    """{affordance: its winning learner} from an `afford evaluate` results.json: the best F1 over folds less
    one standard deviation, so that a learner carried by one lucky fold does not ship (docs/learning.md
    shows such a case)."""
    from ..jsonfile import read_json

    best: dict[str, tuple[float, str]] = {}
    for row in read_json(Path(results_json), ValueError).get("results", []):
        score = row["f1"] - row.get("f1_std", 0.0)
        if score > best.get(row["affordance"], (-np.inf, ""))[0]:
            best[row["affordance"]] = (score, row["learner"])
    return {affordance: learner for affordance, (_, learner) in best.items()}


def rebuild_default_models(
    out: Path,
    learners: dict[str, str] | str,
    rooms: int = ROOMS,
    seed: int = SEED,
    workers: int = 1,
    on_step: Callable[[str], None] | None = None,
) -> list[Path]:
    """`learners`: one learner for every affordance, or {affordance: learner} (say, from `winners`)."""
    from ..synth.dataset import SynthOptions, synthesize
    from .train import train

    settings = Settings()
    settings = settings.model_copy(update={"grid": settings.grid.model_copy(update={"step": TRAIN_STEP})})
    out.mkdir(parents=True, exist_ok=True)
    written = []
    with tempfile.TemporaryDirectory(prefix="afford-defaults-") as data:
        synthesize(SynthOptions(rooms, seed, KINDS), data, workers)
        if on_step:
            on_step(f"{rooms} rooms generated")
        for affordance in sorted(skeleton_files(settings.skeleton_dirs)):
            learner = learners if isinstance(learners, str) else learners.get(affordance, "ssvm")
            model = train(data, affordance, learner, settings, seed=seed)
            model.parameters["data"] = {
                "generator": "afford synth",
                "rooms": rooms,
                "seed": seed,
                "kinds": list(KINDS),
                "train_grid_step": TRAIN_STEP,
            }
            written.append(model.save(out / f"{affordance}.model.json"))
            if on_step:
                on_step(f"{affordance} ({learner}): validation F1 {model.validation['f1']:.3f}")
    return written
