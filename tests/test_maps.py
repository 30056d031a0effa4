"""Affordance maps from scores: positives above the threshold, the best over theta and z, one skeleton per
place."""

from __future__ import annotations

import numpy as np
import pytest

from affordcore.geometry.grid import PoseGrid
from affordcore.geometry.skeleton import get_skeleton
from affordcore.mapping.maps import build_map


def _grid() -> PoseGrid:
    return PoseGrid(
        np.arange(20) * 0.1 + 0.05, np.arange(10) * 0.1 + 0.05, np.array([0.5, 0.6]), np.arange(8) * np.pi / 4
    )


def _bump(grid: PoseGrid, x: float, y: float, iz: int, it: int, height: float) -> np.ndarray:
    """Scores peaking at (x, y) in slab (iz, it), falling by 1 per 0.1 m."""
    xx, yy = np.meshgrid(grid.x, grid.y, indexing="ij")
    scores = np.full(grid.shape, -5.0)
    scores[iz, it] = height - np.hypot(xx - x, yy - y) / 0.1
    return scores


def test_one_skeleton_per_place_at_its_best_pose():
    grid, skeleton = _grid(), get_skeleton("sitting-relaxing")
    scores = np.maximum(_bump(grid, 0.45, 0.45, 1, 2, 3.0), _bump(grid, 1.55, 0.55, 0, 5, 2.0))
    result = build_map("sitting-relaxing", scores, grid, skeleton, threshold=0.0)
    assert len(result.skeletons) == 2  # two places, though dozens of poses score above the threshold
    assert len(result.positives) > 10 and np.all(np.diff(result.positives[:, 4]) <= 0)
    (x1, y1, z1, t1, s1), (x2, y2, z2, t2, s2) = result.skeletons
    assert (x1, y1, z1, t1, s1) == (0.45, 0.45, 0.6, np.pi / 2, 3.0)
    assert (x2, y2, z2) == (1.55, 0.55, 0.5) and np.isclose(t2, 5 * np.pi / 4) and np.isclose(s2, 2.0)
    assert result.joints.shape == (2, 15, 3)
    np.testing.assert_allclose(
        result.joints[0].mean(axis=0)[:2],
        [0.45, 0.45] + (skeleton.joints @ _rz(np.pi / 2).T).mean(axis=0)[:2],
        atol=1e-9,
    )
    # the confidence map is the best over theta and z, and remembers which theta
    assert (
        result.confidence.shape == (20, 10)
        and result.confidence[4, 4] == 3.0
        and result.best_theta[4, 4] == np.pi / 2
    )


def test_nothing_above_the_threshold_gives_empty_maps_and_valid_json():
    grid = _grid()
    result = build_map("x", np.full(grid.shape, -1.0), grid, get_skeleton("standing-working"), threshold=0.0)
    assert len(result.skeletons) == 0 and len(result.positives) == 0
    document = result.to_json("model-id", np.eye(4))
    assert (
        document["skeletons"] == []
        and document["positives"] == []
        and document["world_from_input"][3] == [0, 0, 0, 1]
    )


def test_json_holds_the_grid_and_every_positive():
    grid = _grid()
    result = build_map(
        "a", _bump(grid, 1.0, 0.5, 0, 0, 1.0), grid, get_skeleton("sitting-working"), threshold=0.0
    )
    document = result.to_json("m", np.eye(4))
    assert document["grid"]["nx"] == 20 and document["grid"]["n_theta"] == 8
    assert len(document["positives"]) == len(result.positives) and set(document["skeletons"][0]) == {
        "x",
        "y",
        "z",
        "theta",
        "score",
        "probability",
        "joints",
    }


def test_places_beat_the_place_threshold_and_positives_the_pose_threshold():
    """A room's cut (the place threshold) decides the skeletons; the pose threshold still decides positives,
    and the document carries both so a reader can tell why a skeleton is there."""
    grid = _grid()
    scores = np.maximum(_bump(grid, 0.45, 0.45, 0, 0, 1.0), _bump(grid, 1.55, 0.45, 0, 0, 3.0))
    low = build_map("a", scores, grid, get_skeleton("sitting-working"), threshold=0.5)
    high = build_map("a", scores, grid, get_skeleton("sitting-working"), threshold=0.5, place_threshold=2.0)
    assert len(low.skeletons) == 2 and len(high.skeletons) == 1 and high.skeletons[0, 4] > 2.0
    np.testing.assert_array_equal(low.positives, high.positives)
    document = high.to_json("m", np.eye(4))
    assert document["threshold"] == 0.5 and document["place_threshold"] == 2.0


def _rz(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def test_cells_away_from_scanned_floor_hold_no_skeleton():
    grid, skeleton = _grid(), get_skeleton("sitting-relaxing")
    scores = np.maximum(_bump(grid, 0.45, 0.45, 1, 2, 3.0), _bump(grid, 1.55, 0.55, 0, 5, 2.0))
    allowed = np.ones((20, 10), dtype=bool)
    allowed[10:] = False  # the second place lies over floor nobody scanned
    result = build_map("sitting-relaxing", scores, grid, skeleton, threshold=0.0, allowed=allowed)
    assert len(result.skeletons) == 1 and result.skeletons[0][0] == 0.45
    assert np.all(result.positives[:, 0] < 1.0)


def test_observed_floor_is_the_scanned_floor_and_a_margin():
    from affordcore.geometry.fields import compute_fields, observed_floor
    from affordcore.settings import NormalSettings, VoxelSettings

    rng = np.random.default_rng(0)
    # x 0-2 scanned
    floor = np.column_stack([rng.uniform(0, 2, 20000), rng.uniform(0, 4, 20000), np.zeros(20000)])
    # x 2-4 not
    wall = np.column_stack([np.full(8000, 4.0), rng.uniform(0, 4, 8000), rng.uniform(0, 2.4, 8000)])
    fields = compute_fields(np.concatenate([floor, wall]), VoxelSettings(), NormalSettings())
    x, y = np.array([0.55, 1.85, 2.25, 2.55, 3.05]), np.array([2.05])
    np.testing.assert_array_equal(observed_floor(fields, x, y, 0.3)[:, 0], [True, True, True, False, False])
    np.testing.assert_array_equal(observed_floor(fields, x, y, 0.0)[:, 0], [True, True, False, False, False])


def test_a_plan_spans_the_outer_edges_of_the_grid_s_cells():
    from affordcore.mapping.plots import _extent

    # cell centres 0.05 .. 1.95 and 0.05 .. 0.95, 0.1 apart
    assert _extent(_grid()) == pytest.approx((0.0, 2.0, 0.0, 1.0))
