"""Training examples: a data set's rooms, and a bounded sample of each room's labelled poses with features.

A data set is a folder of ``<room>.ply`` clouds with ``<room>.labels.json`` beside them (`afford synth`
writes them; the real rooms in ../shared/data/rooms have the same layout). Clouds are taken as they are
(z-up, floor at 0: the labels are in the cloud's own frame). Poses inside unlabelled regions are left out.

Memory is bounded by design: a room's examples are every positive pose plus a seeded random sample of
`learn.negatives_per_room` negatives, each sampled negative standing for ``weight`` of them. With a room
cache (`cache.RoomCache`, what `afford train`, `afford evaluate` and the benchmarks use), a `Room` holds
only its labels and reads its voxel fields from the cache each time it is scored, and an `ExampleSet` holds
each room's labels and weights and reads its feature rows when asked: every loop over rooms holds one
room's fields and rows at a time, and `stack` copies only the rows it keeps. Without a cache, rooms and
examples are held in memory. Rooms and examples are prepared in parallel processes (`learn.workers`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
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
from ..parallel import map_in_processes, workers_for
from ..settings import Settings
from .cache import (
    RoomCache,
    digest_of,
    file_digest,
    load_example_labels,
    load_example_rows,
    load_fields,
    save_examples,
    save_fields,
)


class RoomFiles(NamedTuple):
    name: str
    cloud: Path
    labels: Path


@dataclass
class Room:
    """One labelled room, ready to score: its labels and its voxel fields (the cloud itself is let go), the
    fields either held (`held_fields`) or read from the room cache at `fields_path` each time `fields` is
    asked for and let go after, so that a list of cached rooms costs their labels alone."""

    name: str
    held_fields: SceneFields | None
    labels: LabelSet
    fields_path: Path | None = None
    key: str = ""  # a digest of the cloud, the settings and the labels: what the room's examples key on

    @property
    def fields(self) -> SceneFields:
        if self.held_fields is not None:
            return self.held_fields
        if self.fields_path is None:
            raise ValueError(f"room {self.name} has neither fields nor a cached copy of them")
        return load_fields(self.fields_path)

    def grid_and_truth(
        self, skeleton: Skeleton, settings: Settings, fields: SceneFields | None = None
    ) -> tuple[PoseGrid, GroundTruth]:
        """The room's pose grid and its ground truth (`fields`: the room's, when the caller has them)."""
        grid = pose_grid(fields or self.fields, skeleton, settings)
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
            "source": skeleton.portable_source,
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


def labelled_rooms(folders: list[Path]) -> list[RoomFiles]:
    """Every label file `<room>.labels.json` in the folders with its cloud `<room>.ply`, beside it or in any
    other of the folders (a cloud rebuilt apart from its labels, as ScanNet's terms require), sorted by name;
    labels whose cloud is nowhere are left out (`missing_clouds` names them)."""
    rooms = []
    for labels in sorted(p for folder in folders for p in Path(folder).glob("*.labels.json")):
        cloud = _cloud_of(labels, folders)
        if cloud is not None:
            rooms.append(RoomFiles(labels.name.removesuffix(".labels.json"), cloud, labels))
    return sorted(rooms)


def missing_clouds(folders: list[Path]) -> list[str]:
    """The rooms of label files in the folders whose cloud is in none of them."""
    labels = (p for folder in folders for p in Path(folder).glob("*.labels.json"))
    return sorted(p.name.removesuffix(".labels.json") for p in labels if _cloud_of(p, folders) is None)


def _cloud_of(labels: Path, folders: list[Path]) -> Path | None:
    stem = labels.name.removesuffix(".labels.json")
    return next(
        (
            c
            for c in [labels.with_name(f"{stem}.ply"), *(Path(f) / f"{stem}.ply" for f in folders)]
            if c.exists()
        ),
        None,
    )


def load_room(files: RoomFiles, settings: Settings, cache: RoomCache | None = None) -> Room:
    """The room with its fields held, or (with `cache`) read from the cache, computed and written first
    when missing."""
    labels = load_labels(files.labels)  # a bad label file fails before the cloud is read
    if cache is None:
        return Room(files.name, _compute_fields(files, settings), labels)
    room = _cached_room(files, labels, settings, cache)
    _write_fields(files, room, settings)
    return room


def _write_fields(files: RoomFiles, room: Room, settings: Settings) -> None:
    """The room's fields into the cache, at the path its caller keyed (unless they are there)."""
    if not room.fields_path.exists():
        save_fields(room.fields_path, _compute_fields(files, settings))


def _compute_fields(files: RoomFiles, settings: Settings) -> SceneFields:
    return prepare_scene(load_cloud(files.cloud), settings, "none").fields


def _cached_room(files: RoomFiles, labels: LabelSet, settings: Settings, cache: RoomCache) -> Room:
    """The room as the cache keys it, whether or not its fields are there yet."""
    key = cache.fields_key(files.cloud, settings)
    return Room(
        files.name,
        None,
        labels,
        cache.fields_path(files.name, key),
        digest_of(key, file_digest(files.labels)),
    )


def load_rooms(
    rooms: list[RoomFiles],
    settings: Settings,
    on_room: Callable[[str], None] | None = None,
    cache: RoomCache | None = None,
) -> list[Room]:
    """Every room, in the order given: fields held, or (with `cache`) in the cache, the missing ones
    computed there in parallel processes (`learn.workers`) and never sent back whole."""
    if cache is None:
        return list(_map_rooms(load_room, [(f, settings) for f in rooms], settings, on_room))
    cached = [_cached_room(f, load_labels(f.labels), settings, cache) for f in rooms]
    ready = [room.fields_path.exists() for room in cached]
    for room in (room for room, done in zip(cached, ready) if done):
        _tell(on_room, room.name)
    missing = [(f, room, settings) for f, room, done in zip(rooms, cached, ready) if not done]
    for _ in _map_rooms(_write_fields, missing, settings, on_room):
        pass
    return cached


def _map_rooms(function: Callable, jobs: list[tuple], settings: Settings, on_room) -> Iterator:
    """`function(*job)` for every job (whose first item names a room) in parallel processes, in order;
    `on_room` hears each room as it is done."""
    results = map_in_processes(function, jobs, workers_for(len(jobs), settings))
    for job, result in zip(jobs, results):
        _tell(on_room, job[0].name)
        yield result


def room_examples(
    room: Room, task: Task, negatives: int | None = None, rng: np.random.Generator | None = None
) -> RoomExamples:
    """Every positive pose of the room and `negatives` of its negatives (default `learn.negatives_per_room`;
    0 or more than there are: all), drawn with `rng` (default: seeded by the room's name)."""
    negatives = task.settings.learn.negatives_per_room if negatives is None else negatives
    rng = rng or np.random.default_rng(list(room.name.encode()))
    skeleton = task.skeleton
    fields = room.fields
    grid, truth = room.grid_and_truth(skeleton, task.settings, fields)
    scored, positive = truth.scored_mask().ravel(), truth.pose_mask().ravel()
    wanted_positives = np.flatnonzero(scored & positive)
    wanted_negatives = np.flatnonzero(scored & ~positive)
    weight = 1.0
    if 0 < negatives < len(wanted_negatives):
        weight = len(wanted_negatives) / negatives
        wanted_negatives = np.sort(rng.choice(wanted_negatives, negatives, replace=False))
    index = np.concatenate([wanted_positives, wanted_negatives])
    X = features_at(fields, skeleton, grid, task.layout, index)
    y = np.repeat(np.array([1, -1], dtype=np.int8), [len(wanted_positives), len(wanted_negatives)])
    weights = np.where(y > 0, 1.0, weight).astype(np.float32)
    return RoomExamples(room.name, X, y, weights, [room], task)


class ExampleSet(Mapping[str, RoomExamples]):
    """Rooms' examples by room name, in the order added. A stored room's feature rows stay in the cache until
    the room is asked for (and are let go with what was returned); labels and weights, a few bytes a row,
    stay here, so the rows to keep can be chosen before any is read (`stack`)."""

    def __init__(self, task: Task | None = None):
        self.task = task
        self._held: dict[str, RoomExamples] = {}
        self._stored: dict[str, tuple[Room, Path]] = {}
        self._labels: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    @classmethod
    def of(cls, examples: Mapping[str, RoomExamples]) -> ExampleSet:
        if isinstance(examples, ExampleSet):
            return examples
        held = cls()
        for e in examples.values():
            held.hold(e)
        return held

    def hold(self, examples: RoomExamples) -> None:
        self.task = self.task or examples.task
        self._held[examples.room] = examples
        self._labels[examples.room] = (examples.y, examples.weights)

    def store(self, room: Room, path: Path) -> None:
        self._stored[room.name] = (room, path)
        self._labels[room.name] = load_example_labels(path)

    def __getitem__(self, name: str) -> RoomExamples:
        if name in self._held:
            return self._held[name]
        room, path = self._stored[name]
        y, weight = self._labels[name]
        return RoomExamples(name, load_example_rows(path), y, weight, [room], self.task)

    def __iter__(self) -> Iterator[str]:
        return iter(self._labels)

    def __len__(self) -> int:
        return len(self._labels)

    def labels(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(y, weights) of the room's examples, without its feature rows."""
        return self._labels[name]

    def positives(self, name: str) -> int:
        return int(np.sum(self._labels[name][0] > 0))

    def rooms_of(self, name: str) -> list[Room]:
        """The rooms the examples came from (one; none for rows made up without a room)."""
        return list(self._held[name].rooms) if name in self._held else [self._stored[name][0]]

    def room(self, name: str) -> Room:
        (room,) = self.rooms_of(name)
        return room


def example_set(
    rooms: list[Room],
    task: Task,
    negatives: Mapping[str, int | None] | None = None,
    cache: RoomCache | None = None,
    on_room: Callable[[str], None] | None = None,
) -> ExampleSet:
    """Every room's examples (`room_examples`, `negatives[room]` of its negatives: default
    `learn.negatives_per_room`): held, or (with `cache`) in the cache, the missing ones featurised there in
    parallel processes."""
    negatives = negatives or {}
    examples = ExampleSet(task)
    if cache is None:
        for room in rooms:
            examples.hold(room_examples(room, task, negatives.get(room.name)))
            _tell(on_room, room.name)
        return examples
    paths = [
        cache.examples_path(room.name, examples_key(room, task, negatives.get(room.name))) for room in rooms
    ]
    ready = [path.exists() for path in paths]
    for room in (room for room, done in zip(rooms, ready) if done):
        _tell(on_room, room.name)
    missing = [
        (room, task, negatives.get(room.name), path)
        for room, path, done in zip(rooms, paths, ready)
        if not done
    ]
    for _ in _map_rooms(_store_examples, missing, task.settings, on_room):
        pass
    for room, path in zip(rooms, paths):
        examples.store(room, path)
    return examples


def examples_key(room: Room, task: Task, negatives: int | None) -> str:
    """What a room's stored examples depend on beyond its own key (the sampling's seed is the room's name)."""
    negatives = task.settings.learn.negatives_per_room if negatives is None else negatives
    layout = task.layout
    return digest_of(
        room.key, task.affordance, task.skeleton_record(), layout.fingerprint, layout.describe(), negatives
    )


def _store_examples(room: Room, task: Task, negatives: int | None, path: Path) -> None:
    examples = room_examples(room, task, negatives)
    save_examples(path, examples.X, examples.y, examples.weights)


def split_examples(
    rooms: dict[str, Room],
    train_names: list[str],
    validation_names: list[str],
    task: Task,
    cache: RoomCache | None = None,
    on_room: Callable[[str], None] | None = None,
) -> ExampleSet:
    """The examples of the training and validation rooms. Training keeps at most `learn.max_negatives`
    negatives in all (`stack`), so a training room gives at most 1.5 times its share of them: 20,000 from each
    of 120 rooms, to keep 500,000, would hold 2.4 million feature rows in memory for nothing."""
    share = int(np.ceil(1.5 * task.settings.learn.max_negatives / max(1, len(train_names))))
    per_room = min(task.settings.learn.negatives_per_room, share)
    names = [*train_names, *validation_names]
    negatives = {name: per_room if name in train_names else None for name in names}
    return example_set([rooms[name] for name in names], task, negatives, cache, on_room)


def stack(
    examples: Mapping[str, RoomExamples],
    names: list[str],
    max_negatives: int | None = None,
    rng: np.random.Generator | None = None,
    max_positives: int | None = None,
) -> RoomExamples:
    """The rooms' examples as one set. With `max_negatives` (`max_positives`), at most that many negatives
    (positives) in all: a uniform random share of them (drawn with `rng`), weighted up by the inverse share so
    they still stand for every example of the rooms. The rows to keep are chosen from the labels alone, then
    each room's rows are read in turn and only the kept ones copied: memory holds the result and one room."""
    examples = ExampleSet.of(examples)
    labels = [examples.labels(n) for n in names]
    rng = rng or np.random.default_rng(0)
    # negatives first, then positives: a set with positives under their cap draws what it drew before
    negatives, negative_scale = _share([np.flatnonzero(y <= 0) for y, _ in labels], max_negatives, rng)
    positives, positive_scale = _share([np.flatnonzero(y > 0) for y, _ in labels], max_positives, rng)
    rows: list = (
        [np.sort(np.concatenate(kept)) for kept in zip(positives, negatives)]
        if max(negative_scale, positive_scale) > 1
        else [slice(None)] * len(names)
    )
    weights = [
        w[r] * np.where(y[r] > 0, positive_scale, negative_scale).astype(np.float32)
        for (y, w), r in zip(labels, rows)
    ]
    ys = [y[r] for (y, _), r in zip(labels, rows)]
    return RoomExamples(
        "+".join(names),
        _stacked_rows(examples, names, rows, sum(len(y) for y in ys)),
        np.concatenate(ys),
        np.concatenate(weights),
        [room for n in names for room in examples.rooms_of(n)],
        examples.task,
    )


def _share(rows: list[np.ndarray], limit: int | None, rng: np.random.Generator) -> tuple[list, float]:
    """Each room's rows of one class kept when the rooms together may keep `limit` (None: no limit) of them,
    and the weight a kept row takes on to stand for the rest (1 when every row is kept)."""
    total = sum(len(r) for r in rows)
    if limit is None or total <= limit:
        return rows, 1.0
    pick = np.zeros(total, bool)
    pick[rng.choice(total, limit, replace=False)] = True
    picks = np.split(pick, np.cumsum([len(r) for r in rows])[:-1])
    return [r[p] for r, p in zip(rows, picks)], total / limit


def _stacked_rows(examples: ExampleSet, names: list[str], rows: list, total: int) -> np.ndarray:
    """The chosen rows of every room, one room read at a time into one array."""
    X = None
    offset = 0
    for name, r in zip(names, rows):
        part = examples[name].X[r]
        if X is None:
            X = np.empty((total, *part.shape[1:]), part.dtype)
        X[offset : offset + len(part)] = part
        offset += len(part)
    return np.empty((0, 0), np.float32) if X is None else X


def _tell(on_room: Callable[[str], None] | None, name: str) -> None:
    if on_room:
        on_room(name)
