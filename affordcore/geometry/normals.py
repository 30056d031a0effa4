"""Surface normals of a cloud without open3d: the axis of least spread of the points around each point.

Two estimators (`NormalSettings.estimator`), one eigensolver:

* `cube_normals`: the points in the cube of side `radius` centred on the lattice vertex (spacing radius / 2)
  nearest the point. Per-cell sums and eight lookups per vertex, no neighbour search, and a normal changes
  only where the points of its cube do. A point's cube reaches 3/4 of `radius` from it along each axis.
* `pca_normals`: the point's `max_neighbours` nearest within `radius`, as open3d computes them, below.

What open3d's `PointCloud.estimate_normals(KDTreeSearchParamHybrid(radius, max_nn))` computes, step for step,
since the shipped models were trained on its normals: a point's neighbours are its `max_neighbours` nearest
within `radius` (itself included; fewer than 3 give the normal (0, 0, 1)), their covariance comes from
running sums taken nearest first (E[p p^T] - E[p] E[p]^T), and its smallest eigenvalue's axis from the
closed form open3d uses (D. Eberly, "A Robust Eigensolver for 3x3 Symmetric Matrices"). On the benchmark
room 98 % of the normals are open3d's to the bit and the rest within 2e-15 (the order of equal-distance
neighbours, and the last bit of acos and cos); the fields built from them are the same float32s
(tests/test_normals.py, benchmarks/bench_map.py compares the maps).

Why not open3d: importing it costs 0.65 s of a 3 s `afford map`, and its neighbour search ran on one core;
scipy's k-d tree queries on every core. Normals are unsigned: callers use n n^T or |n . up|.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..parallel import cores
from .cells import cell_keys, cells_of_keys

# points per neighbour query: bounds memory, and the chunk's arrays (12 MB of neighbours) are small enough for
# the allocator to reuse them chunk after chunk rather than map fresh pages (a third of the CPU in page
# faults at 65,536)
_CHUNK = 16_384
# the order of the products in `smallest_axes`' sums
_PAIRS = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def pca_normals(
    points: np.ndarray, radius: float, max_neighbours: int, at: np.ndarray | None = None
) -> np.ndarray:
    """(n, 3) unit normals (unsigned) of a cloud at its points (or at the rows `at` of them): the axis of
    least spread of each point's `max_neighbours` nearest within `radius`."""
    from scipy.spatial import cKDTree

    from .smallest_axes import smallest_axes

    points = np.ascontiguousarray(points, dtype=np.float64)
    queries = points if at is None else points[at]
    normals = np.empty((len(queries), 3))
    if len(queries) == 0:
        return normals
    tree = cKDTree(points, balanced_tree=False, compact_nodes=False)  # 15 % less CPU here, same neighbours
    padded = np.vstack([points, np.zeros((1, 3))])  # scipy's index for "no neighbour" reads a zero point

    def chunk(start: int) -> None:
        stop = min(start + _CHUNK, len(queries))
        _, index = tree.query(queries[start:stop], k=max_neighbours, distance_upper_bound=radius)
        normals[start:stop] = smallest_axes(_neighbour_sums(padded, index.reshape(stop - start, -1)))

    # chunks side by side, one thread per core: the neighbour search and numpy's loops release the GIL, so
    # one chunk's covariances run while another's neighbours are searched (a search on every core for one
    # chunk at a time left the other cores idle during each chunk's covariances)
    starts = range(0, len(queries), _CHUNK)
    with ThreadPoolExecutor(min(len(starts), cores())) as pool:
        list(pool.map(chunk, starts))
    return normals


def cube_normals(points: np.ndarray, side: float, at: np.ndarray | None = None) -> np.ndarray:
    """(n, 3) unit normals (unsigned) of a cloud at its points (or at the rows `at` of them): the axis of
    least spread of the points in the cube of `side` around the vertex of a world-anchored lattice (spacing
    side / 2) nearest each point; (0, 0, 1) where the cube holds fewer than 3 points (open3d's rule)."""
    from .smallest_axes import smallest_axes

    points = np.asarray(points, dtype=np.float64)
    queries = points if at is None else points[at]
    if len(queries) == 0:
        return np.empty((0, 3))
    cell = side / 2
    keys, inverse = np.unique(cell_keys(np.floor(points / cell).astype(np.int64)), return_inverse=True)
    cell_sums = moment_sums(points, inverse, len(keys))
    # the cube around vertex v holds the cells v - 1 and v along each axis
    vertices, of_query = np.unique(
        cell_keys(np.floor(queries / cell + 0.5).astype(np.int64)), return_inverse=True
    )
    corner = cells_of_keys(vertices) - 1
    sums = np.zeros((10, len(vertices)))
    for offset in np.ndindex(2, 2, 2):
        wanted = cell_keys(corner + offset)
        position = np.minimum(np.searchsorted(keys, wanted), len(keys) - 1)
        present = keys[position] == wanted
        sums[:, present] += cell_sums[:, position[present]]
    return smallest_axes(sums)[of_query.ravel()]


def _neighbour_sums(padded: np.ndarray, index: np.ndarray) -> np.ndarray:
    """`smallest_axes` sums (10, m) of each row of neighbour indices (len(padded) - 1: none), taken in the
    rows' order, nearest first, as open3d adds them."""
    sums = np.zeros((10, len(index)))
    sums[0] = (index < len(padded) - 1).sum(axis=1)
    for point in padded[index.T]:  # (m, 3) per neighbour rank, contiguous
        for axis in range(3):
            sums[1 + axis] += point[:, axis]
        for k, (a, b) in enumerate(_PAIRS):
            sums[4 + k] += point[:, a] * point[:, b]
    return sums


def moment_sums(points: np.ndarray, group: np.ndarray, n_groups: int) -> np.ndarray:
    """(10, n_groups) `smallest_axes.smallest_axes` sums of the points by group (each point's group index)."""
    sums = np.empty((10, n_groups))
    sums[0] = np.bincount(group, minlength=n_groups)
    for axis in range(3):
        sums[1 + axis] = np.bincount(group, points[:, axis], minlength=n_groups)
    for k, (a, b) in enumerate(_PAIRS):
        sums[4 + k] = np.bincount(group, points[:, a] * points[:, b], minlength=n_groups)
    return sums
