"""The cascade: one of the paper's linear learners scores every pose without features, then gradient-boosted
trees rescore its best few percent from their full features.

Why: a linear score of geometric features ranks poses poorly (a seat and a desk top look alike to it), but
its top 3 % of poses hold nearly every positive, and trees, which need a pose's full features, cost too much
a pose for millions of poses and little for the few it passes on. The trees are trained on exactly what they
will see at inference: each training room is scored by the first stage and its top `fraction` of poses (near
scanned floor, outside unlabelled regions) are featurised with `features.features_at` and labelled from the
ground truth.

Trees: scikit-learn's HistGradientBoostingClassifier (already a dependency), positives up-weighted to a fixed
share, stored as node tables (`trees.TreeEnsemble`) so model files stay data and scoring needs neither
library. LightGBM ranks as well and fits faster (docs/benchmarks.md;
benchmarks/studies/sklearn_or_lightgbm_for_the_second_stage.py).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..mapping.inference import best_poses, second_stage_rows
from ..mapping.maps import RULED_OUT
from ..mapping.pipeline import score_model
from .binning import fast_weighted_binning
from .examples import Room, RoomExamples, Task
from .fitted import Fitted
from .trees import TreeEnsemble


@dataclass(frozen=True)
class TreeSettings:
    """The second stage's boosting; chosen once on generated validation rooms, never on the real ones."""

    max_iter: int = 450  # fewer underfit the default training rooms (docs/accuracy.md, "More trees")
    learning_rate: float = 0.1
    max_leaf_nodes: int = 31
    max_depth: int = 8  # inference walks every tree to its depth: bounded, so rescoring stays cheap
    min_samples_leaf: int = 40
    l2_regularization: float = 1.0
    positive_share: float = 0.25  # positives weighted up until they carry this share of the total weight


def second_stage_examples(
    rooms: list[Room],
    task: Task,
    weights: np.ndarray,
    bias: float,
    fraction: float,
    rng: np.random.Generator,
    max_negatives: int = 4000,
    max_poses: int | None = None,
    local_detail: bool = False,
) -> RoomExamples:
    """The poses the trees will rescore at inference, with their features and labels, from every room."""
    from .model import AffordanceModel

    first = AffordanceModel(
        task.affordance, {}, "", weights, bias, 0.0, "first-stage", skeleton=task.skeleton_record()
    )
    Xs, ys, ws = [], [], []
    for room in rooms:
        fields = room.fields  # read once per room (rooms in a cache hold no fields) and let go after
        grid, scores = score_model(first, fields, task.layout, task.settings)
        _, truth = room.grid_and_truth(task.skeleton, task.settings, fields)
        flat = scores.ravel()
        # unlabelled poses are neither taught as positive nor as negative
        flat[truth.scored_mask().ravel() == 0] = RULED_OUT
        best = best_poses(flat, fraction, max_poses)
        if len(best) == 0:
            continue
        label = truth.pose_mask().ravel()[best]
        # every positive the first stage passes on, and a bounded sample of its negatives (weighted back)
        negatives = np.flatnonzero(~label)
        rate = min(1.0, max_negatives / max(1, len(negatives)))
        if rate < 1.0:
            negatives = rng.choice(negatives, max_negatives, replace=False)
        chosen = np.concatenate([np.flatnonzero(label), negatives])
        Xs.append(second_stage_rows(fields, task.skeleton, grid, task.layout, best[chosen], local_detail))
        ys.append(np.where(label[chosen], 1, -1).astype(np.int8))
        ws.append(np.where(label[chosen], 1.0, 1.0 / rate).astype(np.float32))
    return RoomExamples("second-stage", _joined_float64(Xs), np.concatenate(ys), np.concatenate(ws))


def _joined_float64(parts: list[np.ndarray]) -> np.ndarray:
    """The rooms' float32 feature rows as one float64 array, the dtype scikit-learn's boosted trees take (a
    float32 array they copy whole, beside it), each room's rows let go once copied (`parts` is emptied): the
    memory of the float64 array and not much more, where joining then converting held three copies at once."""
    if not parts:
        raise ValueError("no training room has a pose for the second stage")
    joined = np.empty((sum(len(p) for p in parts), *parts[0].shape[1:]), dtype=np.float64)
    offset = 0
    parts.reverse()  # pop from the end, in the rooms' order
    while parts:
        part = parts.pop()
        joined[offset : offset + len(part)] = part
        offset += len(part)
    return joined


def tree_sample_weights(y: np.ndarray, weights: np.ndarray, settings: TreeSettings) -> np.ndarray:
    """The examples' weights with the positives weighted up until they carry `positive_share` of the total."""
    positive = y > 0
    share = weights[positive].sum() / weights.sum()
    up = max(1.0, settings.positive_share * (1 - share) / max(share * (1 - settings.positive_share), 1e-12))
    return np.where(positive, up, 1.0) * weights


def tree_classifier(settings: TreeSettings, seed: int):
    """The unfitted scikit-learn model `fit_trees` fits."""
    from sklearn.ensemble import HistGradientBoostingClassifier

    return HistGradientBoostingClassifier(
        max_iter=settings.max_iter,
        learning_rate=settings.learning_rate,
        max_leaf_nodes=settings.max_leaf_nodes,
        max_depth=settings.max_depth,
        min_samples_leaf=settings.min_samples_leaf,
        l2_regularization=settings.l2_regularization,
        early_stopping=False,
        random_state=seed,
    )


def fit_trees(examples: RoomExamples, settings: TreeSettings, seed: int) -> TreeEnsemble:
    model = tree_classifier(settings, seed)
    weights = tree_sample_weights(examples.y, examples.weights, settings)
    with fast_weighted_binning():  # the same trees; the weighted binning no longer sorts per percentile
        model.fit(examples.X, (examples.y > 0).astype(int), sample_weight=weights)
    return TreeEnsemble.from_sklearn(model)


def fit_cascade(
    train: RoomExamples, validation: RoomExamples, params: dict, rng, fit_first: Callable[..., Fitted]
) -> Fitted:
    """`fit_first`: the first stage's fit (the learner named by params ``first``, default ``linear-tuned``).
    params: ``fraction`` and ``max_poses`` (default `learn.rescore_fraction`, `learn.rescore_max_poses`),
    ``first_params``, and any `TreeSettings` field."""
    task = train.task
    if task is None or not train.rooms:
        raise ValueError("the cascade learns from rooms: train it with `afford train` / `train.train`")
    first_name = params.get("first", "linear-tuned")
    first = fit_first(train, validation, params.get("first_params", {}), rng)
    fraction = float(params.get("fraction", task.settings.learn.rescore_fraction))
    max_poses = int(params.get("max_poses", task.settings.learn.rescore_max_poses))
    trees_settings = TreeSettings(
        **{k: v for k, v in params.items() if k in TreeSettings.__dataclass_fields__}
    )
    local_detail = bool(params.get("local_detail", task.settings.learn.local_detail))
    examples = second_stage_examples(
        train.rooms, task, first.weights, first.bias, fraction, rng, max_poses=max_poses,
        local_detail=local_detail,
    )  # fmt: skip
    trees = fit_trees(examples, trees_settings, int(rng.integers(2**31)))
    return Fitted(
        first.weights,
        first.bias,
        0.0,
        {
            "first": first_name,
            "second_stage_rows": len(examples.y),
            "second_stage_positives": examples.positives,
            **{k: v for k, v in first.report.items() if k not in ("train_f1", "validation_f1")},
        },
        rescorer={
            "fraction": fraction,
            "max_poses": max_poses,
            **({"local_detail": True} if local_detail else {}),
            "trees": trees.to_dict(),
        },
    )
