"""One interface to every learner: rooms in, an `AffordanceModel` out.

Rooms are split by room, never by pose: a seeded quarter of them (at least one, when there are two or more)
is held out for validation, which picks the structured SVM's iteration and zSVM's z and gives the model's
validation metrics. With a single room, validation uses the training room (and says so).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..features import FeatureLayout
from ..settings import Settings
from ..skeleton import get_skeleton
from .examples import RoomExamples, data_set_rooms, room_examples
from .f1_argmax import f1_loss
from .learners import Fitted, get_learner
from .model import AffordanceModel
from .ssvm import decision


def metrics(scores: np.ndarray, labels: np.ndarray, threshold: float) -> dict:
    positive, predicted = labels > 0, scores > threshold
    tp, fp = int(np.sum(positive & predicted)), int(np.sum(~positive & predicted))
    fn = int(np.sum(positive & ~predicted))
    return {
        "precision": tp / (tp + fp) if tp + fp else 0.0,
        "recall": tp / (tp + fn) if tp + fn else 0.0,
        "f1": 1.0 - float(f1_loss(tp, fp, positive.sum())),
        "positives": int(positive.sum()),
        "negatives": int((~positive).sum()),
    }


def split_rooms(
    names: list[str], seed: int, fraction: float = 0.25, positives: dict[str, int] | None = None
) -> tuple[list[str], list[str]]:
    """(training, validation) rooms: a seeded `fraction` held out, drawn separately from the rooms that hold
    positives and those that do not, so that both sides keep positives whenever two rooms hold any.
    A single room (or a single room with positives) is used for both."""
    positives = positives or {}
    holding = [n for n in names if positives.get(n, 1) > 0]
    if len(names) < 2 or len(holding) < 2:
        return list(names), list(names)
    rng = np.random.default_rng(seed)
    validation = []
    for group in (holding, [n for n in names if n not in holding]):
        order = rng.permutation(len(group))
        held = min(len(group) - (group is holding), max(group is holding, int(round(fraction * len(group)))))
        validation += [group[i] for i in order[:held]]
    validation = sorted(validation)
    return [n for n in names if n not in validation], validation


def fit(learner: str, train: RoomExamples, validation: RoomExamples, params: dict, seed: int) -> Fitted:
    """(weights, bias, threshold, what the learner reports) of one registered learner."""
    return get_learner(learner).fit(train, validation, params, np.random.default_rng(seed))


def train(
    data: str | Path,
    affordance: str,
    learner: str,
    settings: Settings | None = None,
    params: dict | None = None,
    seed: int = 0,
    on_room: Callable[[str], None] | None = None,
) -> AffordanceModel:
    get_learner(learner)  # an unknown learner fails before the rooms are read
    settings = settings or Settings()
    layout = FeatureLayout.from_settings(settings.features, settings.voxel)
    rooms = data_set_rooms(data)
    examples = {}
    for name, cloud, labels in rooms:
        examples[name] = room_examples(cloud, labels, affordance, settings, layout)
        if on_room:
            on_room(name)
    train_names, validation_names = split_rooms(
        list(examples), seed, positives={n: e.positives for n, e in examples.items()}
    )
    training, validation = stack(examples, train_names), stack(examples, validation_names)
    if training.positives == 0:
        raise ValueError(f"{data}: the training rooms hold no {affordance} label")
    weights, bias, threshold, report = fit(learner, training, validation, params or {}, seed)
    skeleton = get_skeleton(affordance, settings.skeleton_dirs)
    return AffordanceModel(
        affordance=affordance,
        layout=layout.describe(),
        fingerprint=layout.fingerprint,
        weights=np.asarray(weights, dtype=np.float64),
        bias=float(bias),
        threshold=float(threshold),
        learner=learner,
        parameters={**(params or {}), "seed": seed, **({"report": report} if report else {})},
        skeleton={
            "joints": skeleton.joints.round(4).tolist(),
            "torso_height": skeleton.torso_height,
            "source": skeleton.source,
        },
        grid=settings.grid.model_dump(),
        training={
            "rooms": train_names,
            "positives": training.positives,
            "negatives": int(len(training.y) - training.positives),
        },
        validation={
            "rooms": validation_names,
            **metrics(decision(validation.X, np.append(weights, bias)), validation.y, threshold),
        },
    )


def stack(examples: dict[str, RoomExamples], names: list[str]) -> RoomExamples:
    return RoomExamples(
        "+".join(names),
        np.concatenate([examples[n].X for n in names]),
        np.concatenate([examples[n].y for n in names]),
    )
