"""Integer lattice cells as single int64 keys, ordered as the cells are lexicographically: what sorting,
`np.unique` and `searchsorted` need to group points by cell (thinning, the cube normals, the assembler's voxel
map) without a hash table."""

from __future__ import annotations

import numpy as np

_KEY_BITS = 21  # per axis: +-2^20 cells, 26 km at 2.5 cm


def cell_keys(cells: np.ndarray) -> np.ndarray:
    """One int64 per integer cell (n, 3), ordered as the cells are lexicographically."""
    half = 1 << (_KEY_BITS - 1)
    if cells.size and (cells.min() < -half or cells.max() >= half):
        raise ValueError("cells beyond the key range (a cloud tens of kilometres across)")
    shifted = cells + half
    return (shifted[:, 0] << (2 * _KEY_BITS)) | (shifted[:, 1] << _KEY_BITS) | shifted[:, 2]


def cells_of_keys(keys: np.ndarray) -> np.ndarray:
    """The integer cells (n, 3) of `cell_keys`."""
    half, mask = 1 << (_KEY_BITS - 1), (1 << _KEY_BITS) - 1
    axes = [(keys >> (2 * _KEY_BITS)) & mask, (keys >> _KEY_BITS) & mask, keys & mask]
    return np.stack(axes, axis=1) - half


def cell_sums(
    points: np.ndarray, voxel: float, weights: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(sorted unique cell keys, (n, 3) sums of the points in each, counts) of `points` at `voxel`, each
    point counted `weights` times (default once)."""
    keys = cell_keys(np.floor(points / voxel + 0.5).astype(np.int64))
    unique, inverse = np.unique(keys, return_inverse=True)
    weighted = points if weights is None else points * weights[:, None]
    sums = np.stack([np.bincount(inverse, weighted[:, k], len(unique)) for k in range(3)], axis=1)
    counts = np.bincount(inverse, weights, len(unique)).round().astype(np.int64)
    return unique, sums, counts
