"""Surface normals of a cloud without open3d: the axis of least spread of each point's nearest neighbours.

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

# points per neighbour query: bounds memory, and the chunk's arrays (12 MB of neighbours) are small enough for
# the allocator to reuse them chunk after chunk rather than map fresh pages (a third of the CPU in page
# faults at 65,536)
_CHUNK = 16_384


def pca_normals(
    points: np.ndarray, radius: float, max_neighbours: int, at: np.ndarray | None = None
) -> np.ndarray:
    """(n, 3) unit normals (unsigned) of a cloud at its points (or at the rows `at` of them): the axis of
    least spread of each point's `max_neighbours` nearest within `radius`."""
    from scipy.spatial import cKDTree

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
        normals[start:stop] = _smallest_axis(_covariances(padded, index.reshape(stop - start, -1)))

    # chunks side by side, one thread per core: the neighbour search and numpy's loops release the GIL, so
    # one chunk's covariances run while another's neighbours are searched (a search on every core for one
    # chunk at a time left the other cores idle during each chunk's covariances)
    starts = range(0, len(queries), _CHUNK)
    with ThreadPoolExecutor(min(len(starts), cores())) as pool:
        list(pool.map(chunk, starts))
    return normals


def _covariances(padded: np.ndarray, index: np.ndarray) -> np.ndarray:
    """(m, 3, 3) covariance of each row of neighbour indices (len(padded) - 1: none), from sums taken in the
    rows' order, nearest first; the identity where fewer than 3 neighbours (open3d's rule)."""
    count = (index < len(padded) - 1).sum(axis=1)
    neighbours = padded[index.T]  # (k, m, 3): one neighbour rank at a time, contiguous
    sums = np.zeros((9, len(index)))
    pairs = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
    for point in neighbours:  # a running sum, nearest neighbour first, as open3d adds them
        for axis in range(3):
            sums[axis] += point[:, axis]
        for k, (a, b) in enumerate(pairs):
            sums[3 + k] += point[:, a] * point[:, b]
    mean = sums / np.maximum(count, 1)
    covariance = np.empty((len(index), 3, 3))
    for k, (a, b) in enumerate(pairs):
        covariance[:, a, b] = covariance[:, b, a] = mean[3 + k] - mean[a] * mean[b]
    covariance[count < 3] = np.eye(3)
    return covariance


def _cross(a, b):
    return np.stack(
        [
            a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
            a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
            a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0],
        ],
        axis=-1,
    )


def _dot(a, b):
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _smallest_axis(cov: np.ndarray) -> np.ndarray:
    """Unit eigenvector of each symmetric 3x3's smallest eigenvalue, in closed form (D. Eberly, "A Robust
    Eigensolver for 3x3 Symmetric Matrices", the method open3d's `estimate_normals` uses, operation for
    operation, so the normals are open3d's to the last bit or nearly); (0, 0, 1) where the matrix is 0."""
    n = len(cov)
    scale = cov.reshape(n, 9).max(axis=1)
    a = cov / np.where(scale == 0, 1.0, scale)[:, None, None]
    a00, a01, a02, a11, a12, a22 = a[:, 0, 0], a[:, 0, 1], a[:, 0, 2], a[:, 1, 1], a[:, 1, 2], a[:, 2, 2]
    off = a01 * a01 + a02 * a02 + a12 * a12
    with np.errstate(invalid="ignore", divide="ignore"):  # diagonal rows are replaced below
        q = (a00 + a11 + a22) / 3
        b00, b11, b22 = a00 - q, a11 - q, a22 - q
        p = np.sqrt((b00 * b00 + b11 * b11 + b22 * b22 + off * 2) / 6)
        c00 = b11 * b22 - a12 * a12
        c01 = a01 * b22 - a12 * a02
        c02 = a01 * a12 - b11 * a02
        half = np.clip((b00 * c00 - a01 * c01 + a02 * c02) / (p * p * p) * 0.5, -1.0, 1.0)
        angle = np.arccos(half) / 3
        beta2 = np.cos(angle) * 2
        beta0 = np.cos(angle + 2.09439510239319549) * 2
        beta1 = -(beta0 + beta2)
        e0, e1, e2 = q + p * beta0, q + p * beta1, q + p * beta2
        upper = half >= 0
        # first the axis of the eigenvalue at the end of the spectrum that stands apart, then the middle
        # one's in the plane perpendicular to it, then the third as their cross product
        first = _end_axis(a00, a01, a02, a11, a12, a22, np.where(upper, e2, e0))
        second = _middle_axis(a00, a01, a02, a11, a12, a22, first, e1)
        third = np.where(upper[:, None], _cross(second, first), _cross(first, second))
        first_smallest = np.where(upper, (e2 < e0) & (e2 < e1), (e0 < e1) & (e0 < e2))
        second_smallest = (e1 < e0) & (e1 < e2)
        smallest = np.where(first_smallest[:, None], first, np.where(second_smallest[:, None], second, third))
    diagonal = np.where(
        ((a00 < a11) & (a00 < a22))[:, None],
        np.array([1.0, 0.0, 0.0]),
        np.where(((a11 < a00) & (a11 < a22))[:, None], np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])),
    )
    axis = np.where((off > 0)[:, None], smallest, diagonal)
    axis[scale == 0] = (0.0, 0.0, 1.0)
    return axis


def _end_axis(a00, a01, a02, a11, a12, a22, value):
    """The eigenvector of `value`: the longest cross product of two rows of A - value I."""
    r0 = np.stack([a00 - value, a01, a02], axis=1)
    r1 = np.stack([a01, a11 - value, a12], axis=1)
    r2 = np.stack([a02, a12, a22 - value], axis=1)
    crosses = np.stack([_cross(r0, r1), _cross(r0, r2), _cross(r1, r2)], axis=1)
    lengths = _dot(crosses, crosses)
    d0, d1, d2 = lengths[:, 0], lengths[:, 1], lengths[:, 2]
    pick = np.where(d1 > d0, 1, 0)
    pick = np.where(d2 > np.where(d1 > d0, d1, d0), 2, pick)
    chosen = np.take_along_axis(crosses, pick[:, None, None], axis=1)[:, 0]
    return chosen / np.sqrt(np.take_along_axis(lengths, pick[:, None], axis=1))


def _middle_axis(a00, a01, a02, a11, a12, a22, first, value):
    """The eigenvector of `value` perpendicular to `first`: from the 2x2 problem in a basis U, V of the plane
    perpendicular to it."""
    x, y, z = first[:, 0], first[:, 1], first[:, 2]
    zero = np.zeros_like(x)
    inv_xz = 1 / np.sqrt(x * x + z * z)
    inv_yz = 1 / np.sqrt(y * y + z * z)
    u = np.where(
        (np.abs(x) > np.abs(y))[:, None],
        np.stack([-z * inv_xz, zero, x * inv_xz], axis=1),
        np.stack([zero, z * inv_yz, -y * inv_yz], axis=1),
    )
    v = _cross(first, u)
    rows = (
        np.stack([a00, a01, a02], axis=1),
        np.stack([a01, a11, a12], axis=1),
        np.stack([a02, a12, a22], axis=1),
    )
    au = np.stack([_dot(row, u) for row in rows], axis=1)
    av = np.stack([_dot(row, v) for row in rows], axis=1)
    m00, m01, m11 = _dot(u, au) - value, _dot(u, av), _dot(v, av) - value
    abs00, abs01, abs11 = np.abs(m00), np.abs(m01), np.abs(m11)
    # normalise the 2x2's larger row (by its larger entry) and rotate U, V by it
    by00 = abs00 >= abs11
    big, other = np.where(by00, m00, m11), m01
    big_abs = np.where(by00, abs00, abs11)
    degenerate = np.maximum(big_abs, abs01) <= 0
    on_big = big_abs >= abs01
    ratio = np.where(on_big, other / big, big / other)
    norm = 1 / np.sqrt(1 + ratio * ratio)
    # on_big: other' = ratio * norm, big' = norm; else: big' = ratio * norm', other' = norm'
    big2 = np.where(on_big, norm, ratio * norm)
    other2 = np.where(on_big, ratio * norm, norm)
    # m00 row: m01 * U - m00 * V; m11 row: m11 * U - m01 * V
    coef_u = np.where(by00, other2, big2)
    coef_v = np.where(by00, big2, other2)
    axis = coef_u[:, None] * u - coef_v[:, None] * v
    return np.where(degenerate[:, None], u, axis)
