"""Training examples: a data set's rooms, and a bounded sample of each room's labelled poses with features.

A data set is a folder of ``<room>.ply`` clouds with ``<room>.labels.json`` beside them (`afford synth`
writes them; the real rooms in ../shared/data/rooms have the same layout). Clouds are taken as they are
(z-up, floor at 0: the labels are in the cloud's own frame). Poses inside unlabelled regions are left out.

Memory is bounded by design: a `Room` keeps only its voxel fields (a few MB), from which every pose can be
scored (`inference.score_poses`) or featurised (`features.features_at`) on demand; and a room's examples are
every positive pose plus a seeded random sample of `learn.negatives_per_room` negatives, each sampled
negative standing for ``weight`` of them. 100 rooms at the default 20,000 negatives and 25 cm cells are
1.8 GB of features, however fine the pose grid. Rooms are prepared in parallel processes.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from multiprocessing import get_context
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..geometry.features import FeatureLayout, features_at
from ..geometry.fields import SceneFields
from ..geometry.grid import PoseGrid
from ..geometry.scene import load_cloud
from ..geometry.skeleton import Skeleton, get_skeleton
from ..labels import GroundTruth, LabelSet, ground_truth, load_labels
from ..mapping.pipeline import pose_grid, prepare_scene
from ..settings import Settings


class RoomFiles(NamedTuple):
    name: str
    cloud: Path
    labels: Path


@dataclass
class Room:
    """One labelled room, ready to score: its voxel fields and its labels (the cloud itself is let go)."""

    name: str
    fields: SceneFields
    labels: LabelSet

    def grid_and_truth(self, skeleton: Skeleton, settings: Settings) -> tuple[PoseGrid, GroundTruth]:
        grid = pose_grid(self.fields, skeleton, settings)
        return grid, ground_truth(self.labels, skeleton.affordance, grid, torso_height=skeleton.torso_height)


@dataclass
class Task:
    """What a learner is fitting: one affordance's skeleton on one feature layout under these settings."""

    affordance: str
    settings: Settings
    layout: FeatureLayout

    @property
    def skeleton(self) -> Skeleton:
        return get_skeleton(self.affordance, self.settings.skeleton_dirs)

    def skeleton_record(self) -> dict:
        """The skeleton as a model file records it (maps place this one, whatever is installed later)."""
        skeleton = self.skeleton
        record = {
            "joints": skeleton.joints.round(4).tolist(),
            "torso_height": skeleton.torso_height,
            "source": skeleton.source,
        }
        if skeleton.torso_reach_above:  # the grid it was trained on has levels above the usual three
            record["torso_reach_above"] = skeleton.torso_reach_above
        return record


@dataclass
class RoomExamples:
    """Feature rows and labels (+1 / -1) of sampled poses, of one room or stacked over several. `weight` is
    how many poses each row stands for (1 for positives, the sampling's inverse rate for negatives);
    `rooms` and `task` let a learner go back to the rooms themselves (the cascade scores all their poses)."""

    room: str
    X: np.ndarray  # (n, n_features) float32
    y: np.ndarray  # (n,) int8 in {-1, +1}
    weight: np.ndarray | None = None  # (n,) float32; None: every row stands for itself
    rooms: list[Room] = field(default_factory=list)
    task: Task | None = None

    @property
    def positives(self) -> int:
        return int(np.sum(self.y > 0))

    @property
    def weights(self) -> np.ndarray:
        return np.ones(len(self.y), dtype=np.float32) if self.weight is None else self.weight


def data_set_rooms(folder: str | Path) -> list[RoomFiles]:
    """(room, cloud, labels) for every cloud with a label file beside it, sorted by name."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such data set folder")
    rooms = [RoomFiles(p.stem, p, p.with_name(p.stem + ".labels.json")) for p in sorted(folder.glob("*.ply"))]
    rooms = [r for r in rooms if r.labels.exists()]
    if not rooms:
        raise FileNotFoundError(f"{folder}: no <room>.ply with a <room>.labels.json beside it")
    return rooms


def load_room(files: RoomFiles, settings: Settings) -> Room:
    labels = load_labels(files.labels)  # a bad label file fails before the cloud is read
    scene = prepare_scene(load_cloud(files.cloud), settings, "none")
    return Room(files.name, scene.fields, labels)


def load_rooms(
    rooms: list[RoomFiles], settings: Settings, on_room: Callable[[str], None] | None = None
) -> list[Room]:
    """Every room's fields, computed in parallel processes (`learn.workers`), in the order given."""
    workers = min(len(rooms), settings.learn.workers or _cores())
    if workers <= 1:
        loaded = []
        for files in rooms:
            loaded.append(load_room(files, settings))
            _tell(on_room, files.name)
        return loaded
    # spawn, not fork: open3d and BLAS threads do not survive a fork
    with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as pool:
        futures = [pool.submit(load_room, files, settings) for files in rooms]
        loaded = []
        for files, future in zip(rooms, futures):
            loaded.append(future.result())
            _tell(on_room, files.name)
    return loaded


def room_examples(
    room: Room, task: Task, negatives: int | None = None, rng: np.random.Generator | None = None
) -> RoomExamples:
    """Every positive pose of the room and `negatives` of its negatives (default `learn.negatives_per_room`;
    0 or more than there are: all), drawn with `rng` (default: seeded by the room's name)."""
    negatives = task.settings.learn.negatives_per_room if negatives is None else negatives
    rng = rng or np.random.default_rng(list(room.name.encode()))
    skeleton = task.skeleton
    grid, truth = room.grid_and_truth(skeleton, task.settings)
    scored, positive = truth.scored_mask().ravel(), truth.pose_mask().ravel()
    wanted_positives = np.flatnonzero(scored & positive)
    wanted_negatives = np.flatnonzero(scored & ~positive)
    weight = 1.0
    if 0 < negatives < len(wanted_negatives):
        weight = len(wanted_negatives) / negatives
        wanted_negatives = np.sort(rng.choice(wanted_negatives, negatives, replace=False))
    index = np.concatenate([wanted_positives, wanted_negatives])
    X = features_at(room.fields, skeleton, grid, task.layout, index)
    y = np.repeat(np.array([1, -1], dtype=np.int8), [len(wanted_positives), len(wanted_negatives)])
    weights = np.where(y > 0, 1.0, weight).astype(np.float32)
    return RoomExamples(room.name, X, y, weights, [room], task)


def split_examples(
    rooms: dict[str, Room], train_names: list[str], validation_names: list[str], task: Task
) -> dict[str, RoomExamples]:
    """The examples of the training and validation rooms. Training keeps at most `learn.max_negatives`
    negatives in all (`stack`), so a training room gives at most 1.5 times its share of them: 20,000 from each
    of 120 rooms, to keep 500,000, would hold 2.4 million feature rows in memory for nothing."""
    share = int(np.ceil(1.5 * task.settings.learn.max_negatives / max(1, len(train_names))))
    per_room = min(task.settings.learn.negatives_per_room, share)
    return {
        name: room_examples(rooms[name], task, per_room if name in train_names else None)
        for name in [*train_names, *validation_names]
    }


def stack(
    examples: dict[str, RoomExamples],
    names: list[str],
    max_negatives: int | None = None,
    rng: np.random.Generator | None = None,
) -> RoomExamples:
    """The rooms' examples as one set. With `max_negatives`, at most that many negatives in all: a uniform
    random share of them (drawn with `rng`), weighted up by the inverse share so they still stand for every
    negative of the rooms; only the kept rows are ever copied."""
    chosen = [examples[n] for n in names]
    rows = [slice(None)] * len(chosen)
    scale = 1.0
    negatives = [np.flatnonzero(e.y <= 0) for e in chosen]
    total = sum(len(n) for n in negatives)
    if max_negatives is not None and total > max_negatives:
        rng = rng or np.random.default_rng(0)
        pick = np.zeros(total, bool)
        pick[rng.choice(total, max_negatives, replace=False)] = True
        picks = np.split(pick, np.cumsum([len(n) for n in negatives])[:-1])
        rows = [
            np.sort(np.concatenate([np.flatnonzero(e.y > 0), n[p]]))
            for e, n, p in zip(chosen, negatives, picks)
        ]
        scale = total / max_negatives
    weights = [
        e.weights[r] * np.where(e.y[r] > 0, 1.0, scale).astype(np.float32) for e, r in zip(chosen, rows)
    ]
    return RoomExamples(
        "+".join(names),
        np.concatenate([e.X[r] for e, r in zip(chosen, rows)]),
        np.concatenate([e.y[r] for e, r in zip(chosen, rows)]),
        np.concatenate(weights),
        [room for e in chosen for room in e.rooms],
        chosen[0].task if chosen else None,
    )


def _cores() -> int:
    import os

    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def _tell(on_room: Callable[[str], None] | None, name: str) -> None:
    if on_room:
        on_room(name)
