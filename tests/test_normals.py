"""Normals without open3d (`geometry/normals.py`). The nearest neighbours' are open3d's `estimate_normals`: to
1e-12 on a noisy room (most to the bit), the same float32 fields, and the same answer where the neighbourhood
is degenerate (too few points, a line, an axis-aligned plane, one point repeated). The cube's are the axis of
least spread of the points in the cube around each point's nearest lattice vertex, and no others."""

from __future__ import annotations

import numpy as np
import pytest

from affordcore.geometry.normals import cube_normals, pca_normals
from affordcore.settings import NormalSettings


def open3d_normals(points: np.ndarray, radius: float, max_nn: int) -> np.ndarray:
    o3d = pytest.importorskip("open3d")
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=max_nn))
    return np.asarray(cloud.normals)


def assert_same_axes(ours: np.ndarray, theirs: np.ndarray, tolerance: float = 1e-12) -> None:
    """Equal up to sign, row by row (normals are unsigned)."""
    sign = np.where(np.sum(ours * theirs, axis=1) < 0, -1.0, 1.0)
    np.testing.assert_allclose(ours * sign[:, None], theirs, rtol=0, atol=tolerance)


def noisy_room(rng: np.random.Generator, n: int = 20_000) -> np.ndarray:
    """A floor, two walls, a box and a cylinder, with sensor noise: planes, edges, corners and curvature."""
    floor = np.column_stack([rng.uniform(0, 3, n), rng.uniform(0, 3, n), np.zeros(n)])
    wall_x = np.column_stack([np.zeros(n // 2), rng.uniform(0, 3, n // 2), rng.uniform(0, 2, n // 2)])
    wall_y = np.column_stack([rng.uniform(0, 3, n // 2), np.full(n // 2, 3.0), rng.uniform(0, 2, n // 2)])
    angle, height = rng.uniform(0, 2 * np.pi, n // 2), rng.uniform(0, 1, n // 2)
    column = np.column_stack([2 + 0.2 * np.cos(angle), 1 + 0.2 * np.sin(angle), height])
    box = rng.uniform([0.5, 0.5, 0.0], [1.2, 1.0, 0.45], (n // 2, 3))
    box[:, 2] = np.where(rng.random(n // 2) < 0.5, 0.45, box[:, 2])  # a top and a filled body
    points = np.concatenate([floor, wall_x, wall_y, column, box])
    return points + rng.normal(scale=0.003, size=points.shape)


@pytest.mark.parametrize("radius, max_nn", [(0.1, 30), (0.12, 30), (0.05, 8)])
def test_normals_are_open3ds_on_a_noisy_room(radius, max_nn):
    points = noisy_room(np.random.default_rng(5))
    ours = pca_normals(points, radius, max_nn)
    theirs = open3d_normals(points, radius, max_nn)
    assert_same_axes(ours, theirs)
    assert np.mean(np.all(np.abs(ours) == np.abs(theirs), axis=1)) > 0.5  # most to the bit
    np.testing.assert_allclose(np.linalg.norm(ours, axis=1), 1.0, atol=1e-12)


def test_degenerate_neighbourhoods_as_open3d():
    rng = np.random.default_rng(1)
    lonely = np.array([[10.0, 10.0, 10.0], [20.0, 20.0, 20.0], [20.01, 20.0, 20.0]])  # 1 and 2 neighbours
    line = np.column_stack([np.linspace(0, 1, 50), np.full(50, 5.0), np.full(50, 5.0)])
    plane = np.column_stack([rng.uniform(0, 1, 300) + 30, rng.uniform(0, 1, 300), np.zeros(300)])
    repeated = np.tile([[40.0, 0.0, 0.0]], (5, 1))
    points = np.concatenate([lonely, line, plane, repeated])
    ours = pca_normals(points, 0.1, 30)
    theirs = open3d_normals(points, 0.1, 30)
    assert_same_axes(ours, theirs)
    np.testing.assert_array_equal(ours[:3], [[0.0, 0.0, 1.0]] * 3)  # fewer than 3 neighbours
    np.testing.assert_array_equal(np.abs(ours[-5:]), [[0.0, 0.0, 1.0]] * 5)  # no spread at all


def test_fields_from_these_normals_equal_open3ds(monkeypatch):
    """The fields the models read are float32: the normals' last bits do not reach them."""
    import affordcore.geometry.fields as fields

    points = noisy_room(np.random.default_rng(2))
    nearest = NormalSettings(estimator="nearest")
    ours = fields.compute_fields(points, normal_settings=nearest)
    monkeypatch.setattr(
        fields, "normals_at", lambda p, settings: open3d_normals(p, settings.radius, settings.max_neighbours)
    )
    theirs = fields.compute_fields(points, normal_settings=nearest)
    np.testing.assert_array_equal(ours.normals, theirs.normals)


def test_empty_and_chunked():
    assert pca_normals(np.empty((0, 3)), 0.1, 30).shape == (0, 3)
    import affordcore.geometry.normals as normals

    points = noisy_room(np.random.default_rng(3), 2_000)
    whole = pca_normals(points, 0.1, 30)
    normals_chunk, normals._CHUNK = normals._CHUNK, 777  # several chunks, the last one short
    try:
        np.testing.assert_array_equal(pca_normals(points, 0.1, 30), whole)
    finally:
        normals._CHUNK = normals_chunk


def eigh_axis(points: np.ndarray) -> np.ndarray:
    """The smallest eigenvalue's axis of the points' covariance, by LAPACK: an oracle that shares nothing with
    the closed form under test."""
    return np.linalg.eigh(np.cov(points.T, bias=True))[1][:, 0]


def test_cube_normals_are_the_axes_of_the_points_in_the_cube_around_the_nearest_vertex():
    points = noisy_room(np.random.default_rng(7), 4_000)
    side, cell = 0.1, 0.05
    ours = cube_normals(points, side)
    rng = np.random.default_rng(8)
    for i in rng.choice(len(points), 60, replace=False):
        vertex = np.round(points[i] / cell) * cell
        inside = np.all((points >= vertex - cell) & (points < vertex + cell), axis=1)
        if inside.sum() < 3:
            np.testing.assert_array_equal(ours[i], [0.0, 0.0, 1.0])
            continue
        expected = eigh_axis(points[inside])
        assert abs(ours[i] @ expected) > 1 - 1e-9, (i, ours[i], expected)


def test_cube_normals_of_tilted_planes_are_their_normals():
    rng = np.random.default_rng(2)
    for normal in ([0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.3, -0.5, 0.8]):
        normal = np.array(normal) / np.linalg.norm(normal)
        u = np.cross(normal, [0.0, 1.0, 0.0] if abs(normal[1]) < 0.9 else [1.0, 0.0, 0.0])
        u /= np.linalg.norm(u)
        v = np.cross(normal, u)
        a, b = rng.uniform(-1, 1, (2, 20_000))
        plane = 5.0 + a[:, None] * u + b[:, None] * v + rng.normal(scale=0.002, size=(20_000, 1)) * normal
        angle = np.degrees(np.arccos(np.minimum(np.abs(cube_normals(plane, 0.1) @ normal), 1.0)))
        # 2 mm of noise over a few dozen points a cube: a degree, a few at the plane's thin edges
        assert np.median(angle) < 1.0 and np.percentile(angle, 99) < 3.0 and angle.max() < 10.0


def test_a_cube_normal_changes_only_with_the_points_of_its_cube():
    """A point's cube reaches 3/4 of the side from it along each axis: points added beyond that leave its
    normal as it was, to the bit; `at` gives the rows of the whole cloud's."""
    points = noisy_room(np.random.default_rng(4), 3_000)
    before = cube_normals(points, 0.1)
    far = np.random.default_rng(5).uniform(-1, 4, (3_000, 3))
    after = cube_normals(np.concatenate([points, far]), 0.1)[: len(points)]
    reach = np.abs(points[:, None, :] - far[None, :, :]).max(axis=2).min(axis=1)
    untouched = reach > 0.075
    assert untouched.sum() > 0.3 * len(points) and (~untouched).sum() > 0
    np.testing.assert_array_equal(after[untouched], before[untouched])
    assert not np.array_equal(after[~untouched], before[~untouched])
    at = np.arange(0, len(points), 7)
    np.testing.assert_array_equal(cube_normals(points, 0.1, at), before[at])


def test_cube_normals_of_sparse_and_empty_clouds():
    assert cube_normals(np.empty((0, 3)), 0.1).shape == (0, 3)
    lonely = np.array([[10.0, 10.0, 10.0], [20.0, 20.0, 20.0], [20.01, 20.0, 20.0]])
    np.testing.assert_array_equal(cube_normals(lonely, 0.1), [[0.0, 0.0, 1.0]] * 3)
    repeated = np.tile([[40.0, 0.0, 0.0]], (5, 1))
    np.testing.assert_array_equal(np.abs(cube_normals(repeated, 0.1)), [[0.0, 0.0, 1.0]] * 5)


def test_cube_and_nearest_normals_mostly_agree():
    """Not the same estimate, but the same surfaces: on the noisy room most normals within 18 degrees."""
    points = noisy_room(np.random.default_rng(6))
    cosine = np.abs(np.sum(cube_normals(points, 0.1) * pca_normals(points, 0.1, 30), axis=1))
    assert np.mean(cosine > np.cos(np.radians(18))) > 0.85
