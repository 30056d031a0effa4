"""One interface to every learner: rooms in, an `AffordanceModel` out.

Rooms are split by room, never by pose: a seeded quarter of them (at least one, when there are two or more)
is held out for validation, which picks the structured SVM's iteration and zSVM's z, chooses the pose and
place thresholds, and gives the model's validation metrics. With a single room, validation uses the training
room (and says so).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import replace
from pathlib import Path

import numpy as np

from .. import version
from ..geometry.features import FeatureLayout
from ..settings import Settings
from .baselines import undersampled_indices
from .cache import RoomCache
from .examples import ExampleSet, Room, RoomExamples, Task, data_set_rooms, example_set, load_rooms, stack
from .f1_argmax import f1_loss
from .fitted import Fitted
from .learners import get_learner
from .model import AffordanceModel
from .thresholds import fit_places, place_floor, place_threshold, pose_threshold, room_scores


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


def place_model_report(scored: list, model: AffordanceModel, settings: Settings) -> dict:
    """Place recall and false skeletons per room of the place model on the rooms it was fitted on, at
    its own cut (or `map.place_probability` when set)."""
    cut = settings.map.place_probability
    cut = model.places.cut if cut is None else cut
    counts = np.sum(
        [
            c.places(model.places.probability(c.evidence), cut, settings.map.nms_radius)
            for c in (r.model_candidates(model) for r in scored)
        ],
        axis=0,
    )
    labels = sum(len(r.label_best) for r in scored)
    return {
        "probability_place_recall": counts[0] / labels if labels else 0.0,
        "probability_false_per_room": counts[2] / max(1, len(scored)),
    }


def fit(learner: str, train: RoomExamples, validation: RoomExamples, params: dict, seed: int) -> Fitted:
    """What one registered learner fits (weights, bias, threshold, report, and a cascade's second stage)."""
    return get_learner(learner).fit(train, validation, params, np.random.default_rng(seed))


def train(
    data: str | Path,
    affordance: str,
    learner: str,
    settings: Settings | None = None,
    params: dict | None = None,
    seed: int = 0,
    on_room: Callable[[str], None] | None = None,
    cache: RoomCache | None = None,
) -> AffordanceModel:
    """A model of one affordance from a data set folder: rooms split into training and validation by room.
    `on_room` hears each room twice: its fields, then its examples; with `cache`, both are kept there."""
    get_learner(learner)  # an unknown learner fails before the rooms are read
    settings = settings or Settings()
    task = Task(affordance, settings, FeatureLayout.from_settings(settings))
    rooms = load_rooms(data_set_rooms(data), settings, on_room, cache)
    examples = example_set(rooms, task, cache=cache, on_room=on_room)
    train_names, validation_names = split_rooms(
        list(examples), seed, positives={n: examples.positives(n) for n in examples}
    )
    if sum(examples.positives(n) for n in train_names) == 0:
        raise ValueError(f"{data}: the training rooms hold no {affordance} label")
    return train_on_rooms(examples, train_names, validation_names, task, learner, params, seed)


def train_on_rooms(
    examples: Mapping[str, RoomExamples],
    train_names: list[str],
    validation_names: list[str],
    task: Task,
    learner: str,
    params: dict | None = None,
    seed: int = 0,
    negatives_per_positive: float | None = None,
    own_threshold: bool = False,
    real: list[Room] = (),
) -> AffordanceModel:
    """Fit on the training rooms' examples, then choose the pose and place thresholds on the validation
    rooms scored as `afford map` scores them (`calibrate`). `negatives_per_positive` undersamples the
    training examples further, and `own_threshold` keeps the learner's own pose threshold: the paper's
    imbalance test, which is about how each learner's own decision rule bears the imbalance. `real` rooms
    calibrate the place model beside the validation rooms."""
    examples = ExampleSet.of(examples)
    # at most learn.max_negatives and max_positives: memory stops growing with the number of training rooms
    learn = task.settings.learn
    training = stack(
        examples, train_names, learn.max_negatives, np.random.default_rng([seed, 2]), learn.max_positives
    )
    validation = stack(examples, validation_names)
    if training.positives == 0:
        raise ValueError(f"the training rooms {', '.join(train_names)} hold no {task.affordance} label")
    if negatives_per_positive is not None:
        keep = undersampled_indices(training.y, negatives_per_positive, np.random.default_rng([seed, 1]))
        training = replace(training, X=training.X[keep], y=training.y[keep], weight=training.weights[keep])
    fitted = fit(learner, training, validation, params or {}, seed)
    model = AffordanceModel(
        affordance=task.affordance,
        layout=task.layout.describe(),
        fingerprint=task.layout.fingerprint,
        weights=np.asarray(fitted.weights, dtype=np.float64),
        bias=float(fitted.bias),
        threshold=float(fitted.threshold),
        learner=learner,
        parameters={**(params or {}), "seed": seed, **({"report": fitted.report} if fitted.report else {})},
        skeleton=task.skeleton_record(),
        grid=task.settings.grid.model_dump(),
        training={
            "affordmap": version(),  # the release whose recipe made it (CHANGELOG.md)
            "rooms": train_names,
            "positives": training.positives,
            "negatives": int(len(training.y) - training.positives),
            "negatives_stand_for": int(training.weights[training.y < 0].sum()),
        },
        rescorer=fitted.rescorer,
    )
    validation_rooms = [examples.room(name) for name in validation_names]
    return calibrate(model, validation_rooms, task, not own_threshold, real)


def calibrate(
    model: AffordanceModel, validation: list[Room], task: Task, pose: bool = True, real: list[Room] = ()
) -> AffordanceModel:
    """The model's pose threshold (with `pose`), place thresholds and place model chosen on the validation
    rooms scored as `afford map` scores them (`thresholds.py`), the place model and its cut on the `real`
    rooms too (weighed by `learn.real_share`); its validation report. Changes `model`; a model calibrated
    again keeps its learner's own threshold in the report."""
    settings = task.settings
    learner_threshold = (model.validation or {}).get("learner_threshold", float(model.threshold))
    scored = [room_scores(model, room, task.layout, settings) for room in validation]
    if pose:
        model.threshold = pose_threshold(scored)
    # places count from each room's own median score, so the threshold survives scans unlike the training
    # rooms; the absolute threshold's choice is kept for the comparison (benchmarks/accuracy.py)
    absolute, absolute_places = place_threshold(scored)
    model.place_threshold, relative_places = place_threshold(scored, relative=True)
    model.place_reference = "room-median"
    # ... floored by an absolute score where that does better: a room with few or none of the affordance's
    # places has a low median, and the relative cut alone lets its best non-places through
    model.place_floor, places = place_floor(scored, model.place_threshold)
    # ... and the place model that replaces those cuts: each candidate place's probability from its evidence
    real_scored = [room_scores(model, room, task.layout, settings) for room in real]
    place_model = fit_places(
        scored,
        model.threshold,
        settings.learn.place_false_budget,
        settings.map.nms_radius,
        real_scored,
        settings.learn.real_share,
    )
    model.place_model = place_model.to_dict() if place_model else None
    if place_model:
        places.update(place_model_report(scored, model, settings))
        if real_scored:
            real_report = place_model_report(real_scored, model, settings)
            places["real"] = {"rooms": [room.name for room in real], **real_report}
    positives = sum(int((r.labels > 0).sum()) for r in scored)
    model.validation = {
        "rooms": [room.name for room in validation],
        "learner_threshold": learner_threshold,
        **metrics(
            np.concatenate([r.scores for r in scored]),
            np.concatenate([r.labels for r in scored]),
            model.threshold,
        ),
        "positives": positives,
        **places,
        "absolute_place_threshold": absolute,
        "absolute_place_f1": absolute_places["place_f1"],
        "relative_place_f1": relative_places["place_f1"],
    }
    return model
