"""The shipped default models, rebuilt reproducibly: generate rooms, train every affordance, write the files.

The rooms are `afford synth --rooms 500 --seed 1` (every scan style in turn), dealt by generation index as
`benchmarks/accuracy.py` deals them: the last `TEST` rooms are held out (the benchmark measures the shipped
models on them), the `VALIDATION` before them choose the thresholds, the rest train: the recipe of the shipped
models. Two rebuilds make the same files; docs/accuracy.md ("A rebuild on today's labels") compares them
with the shipped ones.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..geometry.skeleton import skeleton_files
from ..settings import Settings
from .cache import RoomCache

# 500 rooms (404 train: the learning curve still gains from 144 to 404, docs/accuracy.md) deal each of the six
# scan styles to 7-9 validation and 7-9 test rooms
ROOMS, SEED, VALIDATION, TEST, LEARNER = 500, 1, 48, 48, "cascade"


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


def split_by_index(names: list[str], validation: int, test: int) -> tuple[list[str], list[str], list[str]]:
    """(train, validation, test) room names, dealt by generation index (the number at the end of a generated
    room's name), not by name: names start with the room kind and kinds are dealt round-robin, so every part
    holds every kind."""
    if validation < 1 or test < 0 or len(names) < validation + test + 1:
        raise ValueError(
            f"{len(names)} rooms cannot make {validation} validation and {test} test rooms and still train"
        )
    ordered = sorted(names, key=lambda name: int(name.rsplit("-", 1)[1]))
    cut = len(ordered) - validation - test
    return ordered[:cut], ordered[cut : cut + validation], ordered[cut + validation :]


def data_record(rooms: int, seed: int, test_names: list[str], styles: list[str]) -> dict:
    """What a default model was trained on, as its file records it."""
    return {
        "generator": "afford synth",
        "rooms": rooms,
        "seed": seed,
        "styles": list(styles),
        "held_out_test_rooms": test_names,
    }


def data_set_styles(data: Path) -> list[str]:
    """The scan styles a generated data set's rooms were dealt (its summary.json)."""
    from ..jsonfile import read_json

    return list(read_json(Path(data) / "summary.json", ValueError).get("styles", []))


def rebuild_default_models(
    out: Path,
    learners: dict[str, str] | str = LEARNER,
    rooms: int = ROOMS,
    seed: int = SEED,
    workers: int = 1,
    on_step: Callable[[str], None] | None = None,
    real: list | None = None,
) -> list[Path]:
    """`learners`: one learner for every affordance, or {affordance: learner} (say, from `winners`); `real`:
    labelled real rooms (`examples.RoomFiles`) that calibrate the place models beside the validation rooms."""
    from ..synth.batch import synthesize
    from ..synth.dataset import SynthOptions

    with tempfile.TemporaryDirectory(prefix="afford-defaults-") as data:
        synthesize(SynthOptions(rooms, seed), data, workers)
        if on_step:
            on_step(f"{rooms} rooms generated")
        # the rooms' cache goes with them: nobody trains on these files again
        return train_default_models(
            Path(data), out, learners, seed, on_step, cache=RoomCache(Path(data) / "cache"), real=real
        )


def train_default_models(
    data: Path,
    out: Path,
    learners: dict[str, str] | str = LEARNER,
    seed: int = SEED,
    on_step: Callable[[str], None] | None = None,
    validation: int = VALIDATION,
    test: int = TEST,
    cache: RoomCache | None = None,
    real: list | None = None,
) -> list[Path]:
    """Train every affordance on a generated data set split by `split_by_index`, write the model files;
    rooms are read one at a time from `cache` (default `learn.cache_dir`). `real` rooms (`RoomFiles`)
    calibrate the place models beside the validation rooms (`train.calibrate`); never trained on."""
    from ..geometry.features import FeatureLayout
    from .examples import Task, data_set_rooms, load_rooms, split_examples
    from .train import train_on_rooms

    settings = Settings()
    cache = cache or RoomCache.from_settings(settings)
    layout = FeatureLayout.from_settings(settings)
    rooms = {room.name: room for room in load_rooms(data_set_rooms(data), settings, cache=cache)}
    real_rooms = load_rooms(real, settings, cache=cache) if real else []
    train_names, validation_names, test_names = split_by_index(list(rooms), validation, test)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for affordance in sorted(skeleton_files(settings.skeleton_dirs)):
        learner = learners if isinstance(learners, str) else learners.get(affordance, LEARNER)
        task = Task(affordance, settings, layout)
        examples = split_examples(rooms, train_names, validation_names, task, cache)
        model = train_on_rooms(
            examples, train_names, validation_names, task, learner, seed=seed, real=real_rooms
        )
        model.parameters["data"] = data_record(len(rooms), seed, test_names, data_set_styles(data))
        written.append(model.save(out / f"{affordance}.model.json"))
        if on_step:
            v = model.validation
            on_step(
                f"{affordance} ({learner}): validation pose F1 {v['f1']:.3f}, place recall "
                f"{v['place_recall']:.2f}, {v['false_per_room']:.1f} false skeletons per room"
                + (
                    f"; real rooms: place recall {v['real']['probability_place_recall']:.2f}, "
                    f"{v['real']['probability_false_per_room']:.1f} false per room"
                    if "real" in v
                    else ""
                )
            )
    return written
