"""The fine columns the second stage may read: what each column holds, what a pose reads of them, and that the
fields carry them to the rows."""

from __future__ import annotations

import numpy as np
import pytest

from affordcore.geometry.columns import (
    ACROSS,
    EMPTY_LOW,
    FORWARD,
    N_FEATURES,
    column_reads,
    fine_columns,
)


def _slab(x0, x1, y0, y1, z, step=0.01):
    x, y = np.meshgrid(np.arange(x0, x1, step), np.arange(y0, y1, step), indexing="ij")
    return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])


@pytest.fixture(scope="module")
def chair_under_table():
    """A floor, a seat 0.45 m high at x 0.0-0.4, and a table top 0.74 m high at x 0.3-1.0 over its front."""
    return np.vstack(
        [
            _slab(-1.0, 2.0, -1.0, 1.0, 0.0),
            _slab(0.0, 0.4, -0.2, 0.2, 0.45),
            _slab(0.3, 1.0, -0.5, 0.5, 0.74),
            _slab(0.0, 0.4, -0.2, 0.2, 0.08),  # floor clutter below the band: not a surface a body meets
        ]
    )


def _column_at(columns, x, y):
    i, j = np.floor((np.array([x, y]) - columns.origin) / columns.resolution).astype(int)
    return columns.low[i, j], columns.high[i, j]


def test_a_column_holds_its_lowest_and_highest_surface_in_the_band(chair_under_table):
    columns = fine_columns(chair_under_table)
    low, high = _column_at(columns, 0.35, 0.0)  # seat under the table's edge: both show
    assert low == pytest.approx(0.45) and high == pytest.approx(0.74)
    low, high = _column_at(columns, 0.1, 0.0)  # the seat alone; the clutter below the band is not read
    assert low == pytest.approx(0.45) and high == pytest.approx(0.45)
    low, high = _column_at(columns, 1.5, 0.0)  # bare floor
    assert low == EMPTY_LOW and high == 0.0


def test_a_pose_reads_the_columns_in_its_own_frame(chair_under_table):
    columns = fine_columns(chair_under_table)
    lows = {}
    for theta in (0.0, np.pi / 2):
        # seated at the seat's centre facing +x; turned a quarter the table lies to its right instead
        rows = column_reads(columns, np.array([0.2]), np.array([0.0]), np.array([theta]), np.zeros(1))
        low = rows[0, : N_FEATURES // 2].reshape(len(FORWARD), len(ACROSS))
        lows[theta] = low
    at = lambda low, u, v: low[np.argmin(abs(FORWARD - u)), np.argmin(abs(ACROSS - v))]  # noqa: E731
    facing, turned = lows[0.0], lows[np.pi / 2]
    assert at(facing, 0.0, 0.0) == pytest.approx(0.45)  # the seat under it
    assert at(facing, 0.5, 0.0) == pytest.approx(0.74)  # the table top ahead
    assert at(turned, 0.5, 0.0) == EMPTY_LOW  # ahead of it now: bare floor at y = 0.7
    assert at(turned, 0.0, -0.3) == pytest.approx(0.74)  # the table at its right, x = 0.5


def test_heights_are_read_above_the_poses_feet_and_empty_columns_stay_empty(chair_under_table):
    columns = fine_columns(chair_under_table)
    poses = (np.array([0.2, 0.2]), np.array([0.0, 0.0]), np.zeros(2))
    rows = column_reads(columns, *poses, np.array([0.0, 0.1]))
    seated = N_FEATURES // 2 + len(ACROSS) * int(np.argmin(abs(FORWARD))) + len(ACROSS) // 2  # high, under
    assert rows[1, seated] == pytest.approx(rows[0, seated] - 0.1)
    empty = rows[0] == EMPTY_LOW
    assert empty.any() and (rows[1][empty] == EMPTY_LOW).all()
    far = column_reads(columns, np.array([50.0]), np.array([50.0]), np.zeros(1), np.zeros(1))
    assert (far[0, : N_FEATURES // 2] == EMPTY_LOW).all() and (far[0, N_FEATURES // 2 :] == 0).all()


def test_the_second_stage_reads_the_columns_only_when_its_model_asks(chair_under_table, tmp_path):
    from dataclasses import replace

    from affordcore.geometry.features import FeatureLayout
    from affordcore.geometry.fields import compute_fields
    from affordcore.geometry.skeleton import get_skeleton
    from affordcore.learn.cache import load_fields, save_fields
    from affordcore.mapping.inference import second_stage_rows
    from affordcore.mapping.pipeline import pose_grid
    from affordcore.settings import Settings

    settings = Settings()
    fields = compute_fields(chair_under_table)
    save_fields(tmp_path / "f.npz", fields)
    loaded = load_fields(tmp_path / "f.npz")
    np.testing.assert_array_equal(loaded.columns.low, fields.columns.low)
    np.testing.assert_array_equal(loaded.columns.origin, fields.columns.origin)
    skeleton = get_skeleton("sitting-working")
    grid = pose_grid(fields, skeleton, settings)
    layout = FeatureLayout.from_settings(settings)
    index = np.arange(0, grid.size, max(1, grid.size // 50))
    plain = second_stage_rows(loaded, skeleton, grid, layout, index)
    detailed = second_stage_rows(loaded, skeleton, grid, layout, index, local_detail=True)
    assert plain.shape == (len(index), layout.n_features)
    assert detailed.shape == (len(index), layout.n_features + N_FEATURES)
    np.testing.assert_array_equal(detailed[:, : layout.n_features], plain)
    with pytest.raises(ValueError, match="fine columns"):
        second_stage_rows(replace(loaded, columns=None), skeleton, grid, layout, index, local_detail=True)
