"""The assembler's global map: per voxel, the running mean of every point that fell in it.

A Kinect-class depth measurement is off by a centimetre or two at a few metres, differently each time the
surface is seen; a map that keeps the first point per voxel (KISS-ICP's `VoxelHashMap` with one point per
voxel, as this map once did) keeps that first error for good, one noisy sample of each surface. The mean
of every observation is the surface the frames agree on, as the fused room of the offline path is
(docs/services.md has the measurements).

Voxels are keyed as `cells.cell_keys` keys (cells centred on multiples of the voxel, as `voxel_down_sample`'s
are). Each frame's points are reduced to its cells' sums and counts, kept aside, and merged into the sorted
store once they reach a quarter of it: each point is sorted a bounded number of times, not once per frame.
"""

from __future__ import annotations

import numpy as np

from ..geometry.cells import cell_sums

# points kept aside before a merge, at least: below this a merge is cheap whatever the store's size
_MIN_PENDING = 50_000


class VoxelMeans:
    """Running means of points per `voxel` cell; nothing is ever forgotten."""

    def __init__(self, voxel: float):
        self.voxel = float(voxel)
        self._keys = np.empty(0, np.int64)
        self._sums = np.empty((0, 3))
        self._counts = np.empty(0, np.int64)
        self._pending: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._pending_size = 0

    def add_points(self, points: np.ndarray, weights: np.ndarray | None = None) -> None:
        """Add points (n, 3); `weights` (n,) counts each as that many observations (a frame's cell means
        replayed from the journal carry the number of points each averaged)."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if not len(points):
            return
        batch = cell_sums(points, self.voxel, None if weights is None else np.asarray(weights, np.float64))
        self._pending.append(batch)
        self._pending_size += len(batch[0])
        if self._pending_size >= max(_MIN_PENDING, len(self._keys) // 4):
            self._merge()

    def _merge(self) -> None:
        if not self._pending:
            return
        keys = np.concatenate([self._keys, *(p[0] for p in self._pending)])
        unique, inverse = np.unique(keys, return_inverse=True)
        sums = np.concatenate([self._sums, *(p[1] for p in self._pending)])
        counts = np.concatenate([self._counts, *(p[2] for p in self._pending)])
        self._keys = unique
        self._sums = np.stack([np.bincount(inverse, sums[:, k], len(unique)) for k in range(3)], axis=1)
        self._counts = np.bincount(inverse, counts, len(unique)).astype(np.int64)
        self._pending, self._pending_size = [], 0

    def __len__(self) -> int:
        self._merge()
        return len(self._keys)

    def point_cloud(self) -> np.ndarray:
        """The mean point of every voxel, (n, 3), in key order."""
        self._merge()
        return self._sums / self._counts[:, None]

    def counts(self) -> np.ndarray:
        """How many points each voxel of `point_cloud` averages."""
        self._merge()
        return self._counts.copy()
