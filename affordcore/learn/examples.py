"""Training examples: every scored pose of every room of a data set, its features and its label.

A data set is a folder of ``<room>.ply`` clouds with ``<room>.labels.json`` beside them (`afford synth`
writes them; the real rooms in ../shared/data/rooms have the same layout). Clouds are taken as they are
(z-up, floor at 0: the labels are in the cloud's own frame). Poses inside unlabelled regions are left out.
Features stream room by room and chunk by chunk into one float32 matrix per room, so a room never holds more
than its own rows: 1.3 million poses x 222 features (25 cm cells) is 1.2 GB.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..features import FeatureLayout, iter_features
from ..labels import ground_truth, load_labels
from ..pipeline import prepare_scene
from ..scene import load_cloud
from ..settings import Settings
from ..skeleton import get_skeleton


@dataclass
class RoomExamples:
    room: str
    X: np.ndarray  # (n, n_features) float32
    y: np.ndarray  # (n,) int8 in {-1, +1}

    @property
    def positives(self) -> int:
        return int(np.sum(self.y > 0))


def data_set_rooms(folder: str | Path) -> list[tuple[str, Path, Path]]:
    """(room, cloud, labels) for every cloud with a label file beside it, sorted by name."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such data set folder")
    rooms = [(p.stem, p, p.with_name(p.stem + ".labels.json")) for p in sorted(folder.glob("*.ply"))]
    rooms = [r for r in rooms if r[2].exists()]
    if not rooms:
        raise FileNotFoundError(f"{folder}: no <room>.ply with a <room>.labels.json beside it")
    return rooms


def room_examples(
    cloud: Path,
    labels_path: Path,
    affordance: str,
    settings: Settings,
    layout: FeatureLayout,
    on_chunk: Callable[[int], None] | None = None,
) -> RoomExamples:
    skeleton = get_skeleton(affordance, settings.skeleton_dirs)
    labels = load_labels(labels_path)
    scene = prepare_scene(load_cloud(cloud), settings, "none")
    grid = scene.pose_grid(skeleton, settings)
    truth = ground_truth(labels, affordance, grid)
    scored = truth.scored_mask().ravel()
    positive = truth.pose_mask().ravel()
    X = np.empty((int(scored.sum()), layout.n_features), dtype=np.float32)
    row = 0
    for chunk in iter_features(
        scene.fields, skeleton, grid, layout, settings.features.chunk_mb, reuse_buffer=True
    ):
        keep = scored[chunk.start : chunk.stop]
        X[row : row + int(keep.sum())] = chunk.values[keep]
        row += int(keep.sum())
        if on_chunk:
            on_chunk(chunk.stop - chunk.start)
    y = np.where(positive[scored], 1, -1).astype(np.int8)
    return RoomExamples(cloud.stem, X, y)


def load_examples(
    folder: str | Path, affordance: str, settings: Settings | None = None, layout: FeatureLayout | None = None
) -> Iterator[RoomExamples]:
    settings = settings or Settings()
    layout = layout or FeatureLayout.from_settings(settings.features, settings.voxel)
    for _, cloud, labels in data_set_rooms(folder):
        yield room_examples(cloud, labels, affordance, settings, layout)
