"""Normals without open3d (`geometry/normals.py`) are open3d's `estimate_normals`, which the shipped models
were trained on: to 1e-12 on a noisy room (most to the bit), the same float32 fields, and the same answer
where the neighbourhood is degenerate (too few points, a line, an axis-aligned plane, one point repeated)."""

from __future__ import annotations

import numpy as np
import pytest

from affordcore.geometry.normals import pca_normals

o3d = pytest.importorskip("open3d")


def open3d_normals(points: np.ndarray, radius: float, max_nn: int) -> np.ndarray:
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
    ours = fields.compute_fields(points)
    monkeypatch.setattr(
        fields, "normals_at", lambda p, settings: open3d_normals(p, settings.radius, settings.max_neighbours)
    )
    theirs = fields.compute_fields(points)
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
