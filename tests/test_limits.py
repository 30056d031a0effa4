"""Every limit the wire checks holds at its boundary: a message exactly at a limit is taken, one just past it
is refused, with the setting named (affordwire.messages, affordwire.ros). The hostile-input tests elsewhere
send values far past each limit; these pin the comparison itself, so a limit loosened by a factor, or a
`>` turned into `>=`, fails here."""

from __future__ import annotations

import numpy as np
import pytest

from affordcore.geometry.fields import compute_fields
from affordcore.settings import LimitSettings
from affordwire import messages
from affordwire.messages import MessageError

LIMITS = LimitSettings(
    max_points=1_000,
    max_depth_pixels=600,
    max_extent=10.0,
    max_sensor_origins=3,
    latest_timestamp=2_000_000_000.0,
)


def _cloud_spanning(extent: float, count: int = 200, at: float = 1.7e9, origins=None):
    """A map Cloud of `count` points whose x runs exactly from 0 to `extent` (the other axes 0-4 m)."""
    points = np.random.default_rng(4).uniform(0, 4, (count, 3))
    points[0, 0], points[1, 0] = 0.0, extent
    return messages.cloud_message(points, np.eye(4), "test", at=at, origins=origins)


def test_a_cloud_as_wide_as_the_extent_limit_is_taken_and_a_centimetre_wider_refused():
    assert np.ptp(messages.cloud_points(_cloud_spanning(10.0), LIMITS)[:, 0]) == pytest.approx(10.0)
    assert len(messages.cloud_points(_cloud_spanning(9.99), LIMITS)) == 200
    with pytest.raises(MessageError, match="MAX_EXTENT"):
        messages.cloud_points(_cloud_spanning(10.01), LIMITS)


def test_points_up_to_the_limit_are_taken_one_more_refused():
    assert len(messages.cloud_points(_cloud_spanning(5.0, count=1_000), LIMITS)) == 1_000
    with pytest.raises(MessageError, match="MAX_POINTS"):
        messages.cloud_points(_cloud_spanning(5.0, count=1_001), LIMITS)


def test_sensor_positions_up_to_the_count_and_within_the_extent_are_taken():
    inside = np.array([[1.0, 2.0, 1.5], [-10.0, 0.0, 1.0], [3.0, 10.0, 1.2]])  # |coordinate| == the limit
    np.testing.assert_allclose(messages.cloud_origins(_cloud_spanning(5.0, origins=inside), LIMITS), inside)
    with pytest.raises(MessageError, match="MAX_SENSOR_ORIGINS"):
        messages.cloud_origins(_cloud_spanning(5.0, origins=np.vstack([inside, inside[:1]])), LIMITS)
    beyond = inside.copy()
    beyond[1, 0] = -10.01
    with pytest.raises(MessageError, match="MAX_EXTENT"):
        messages.cloud_origins(_cloud_spanning(5.0, origins=beyond), LIMITS)


def test_timestamps_up_to_the_latest_are_taken():
    assert messages.cloud_points(_cloud_spanning(5.0, at=2_000_000_000.0), LIMITS) is not None
    with pytest.raises(MessageError, match="LATEST_TIMESTAMP"):
        messages.cloud_points(_cloud_spanning(5.0, at=2_000_000_001.0), LIMITS)


def test_depth_images_up_to_the_pixel_limit_are_taken():
    intrinsics = np.diag([500.0, 500.0, 1.0])
    at_limit = messages.depth_frame_message(np.zeros((20, 30), np.uint16), intrinsics)  # 600 pixels
    assert messages.depth_image(at_limit, LIMITS) is not None
    past = messages.depth_frame_message(np.zeros((1, 601), np.uint16), intrinsics)
    with pytest.raises(MessageError, match="MAX_DEPTH_PIXELS"):
        messages.depth_image(past, LIMITS)


@pytest.fixture(scope="module")
def fields_message():
    cloud = _cloud_spanning(3.0)
    return messages.fields_message(compute_fields(messages.cloud_points(cloud)), cloud, at=1.7e9)


def _reparsed(message):
    copy = messages.SceneFieldsMessage()
    copy.ParseFromString(message.SerializeToString())
    return copy


def test_fields_grids_up_to_the_voxel_limit_are_taken(fields_message):
    grid = fields_message.grid
    voxels = grid.nx * grid.ny * grid.nz
    assert messages.scene_fields(_reparsed(fields_message), LIMITS, max_voxels=voxels) is not None
    with pytest.raises(MessageError, match="MAX_VOXELS"):
        messages.scene_fields(_reparsed(fields_message), LIMITS, max_voxels=voxels - 1)


def _moved_to(message, origin_x: float):
    """The fields message with its grid (and the floor footprint and fine columns over it) moved along x to
    `origin_x`."""
    moved = _reparsed(message)
    shift = origin_x - moved.grid.origin.x
    moved.grid.origin.x = origin_x
    moved.x_min, moved.x_max = moved.x_min + shift, moved.x_max + shift
    moved.columns.x0 += shift
    return moved


def test_fields_whose_origin_lies_just_past_the_extent_are_refused(fields_message):
    assert messages.scene_fields(_moved_to(fields_message, -10.0), LIMITS).lattice.origin[0] == -10.0
    with pytest.raises(MessageError, match="origin"):
        messages.scene_fields(_moved_to(fields_message, -10.01), LIMITS)


# -- ROS 2 -------------------------------------------------------------------------------------------------


def test_ros_clouds_up_to_the_point_limit_are_taken():
    pytest.importorskip("rosbags")
    from test_ros import cdr, cloud_message, grid_points

    from affordwire import ros

    assert ros.pointcloud2(cdr(cloud_message(grid_points(25, 40))), LIMITS).total == 1_000
    with pytest.raises(MessageError, match="MAX_POINTS"):
        ros.pointcloud2(cdr(cloud_message(grid_points(7, 143))), LIMITS)  # 1,001 points


def test_ros_stamps_up_to_the_latest_and_odometry_within_the_extent_are_taken():
    pytest.importorskip("rosbags")
    from test_ros import cdr, cloud_message, grid_points, odometry_message

    from affordwire import ros

    latest = {"sec": 2_000_000_000, "nanosec": 0}
    assert ros.pointcloud2(cdr(cloud_message(grid_points(), **latest)), LIMITS).stamp == 2_000_000_000
    with pytest.raises(MessageError, match="LATEST_TIMESTAMP"):
        ros.pointcloud2(cdr(cloud_message(grid_points(), sec=2_000_000_000, nanosec=1_000)), LIMITS)
    assert ros.odometry(cdr(odometry_message([10.0, -10.0, 0.0]), ros.ODOMETRY), LIMITS) is not None
    with pytest.raises(MessageError, match="MAX_EXTENT"):
        ros.odometry(cdr(odometry_message([10.01, 0.0, 0.0]), ros.ODOMETRY), LIMITS)
