"""ROS 2 in: sensor_msgs/msg/PointCloud2 and Imu as CDR bytes made by rosbags (the library robots' bags are
read with), decoded by affordwire.ros; the assembler's subscriptions on rmw_zenoh's and
zenoh-plugin-ros2dds's keys; and, end to end, a ROS 2 robot's stream on rmw_zenoh keys becoming maps."""

from __future__ import annotations

import contextlib
import subprocess
import sys
import time

import numpy as np
import pytest

pytest.importorskip("rosbags")

from affordcore.settings import LimitSettings  # noqa: E402
from affordwire import ros  # noqa: E402
from affordwire.messages import MessageError  # noqa: E402

STORE = ros.typestore()
T = STORE.types
PointField = T["sensor_msgs/msg/PointField"]
G = ros.STANDARD_GRAVITY


def header(sec: int = 1_700_000_000, nanosec: int = 250_000_000, frame_id: str = "lidar"):
    return T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id=frame_id
    )


def cloud_message(
    points: np.ndarray,
    datatype: int = PointField.FLOAT32,
    bigendian: bool = False,
    point_pad: int = 0,
    row_pad: int = 0,
    order: str = "xyz",
    **header_args,
):
    """A PointCloud2 of `points` (H, W, 3) with x, y, z of `datatype` laid out in `order` after a 1-byte
    `intensity`-like lead field, `point_pad` spare bytes after each point and `row_pad` after each row."""
    height, width, _ = points.shape
    kind = np.dtype((">" if bigendian else "<") + ros.POINT_FIELD_TYPES[datatype])
    lead = 2  # a uint16 before the coordinates: offsets are not 0, 4, 8
    offsets = {name: lead + index * kind.itemsize for index, name in enumerate(order)}
    point_step = lead + 3 * kind.itemsize + point_pad
    row_step = width * point_step + row_pad
    buffer = np.full(height * row_step, 0xAB, dtype=np.uint8)  # padding is garbage, not zeros
    layout = np.dtype(
        {
            "names": list(offsets),
            "formats": [kind] * 3,
            "offsets": list(offsets.values()),
            "itemsize": point_step,
        }
    )
    view = np.ndarray((height, width), dtype=layout, buffer=buffer, strides=(row_step, point_step))
    for index, name in enumerate("xyz"):
        view[name] = points[..., index]
    fields = [PointField(name="ring", offset=0, datatype=PointField.UINT16, count=1)] + [
        PointField(name=name, offset=offsets[name], datatype=datatype, count=1) for name in order
    ]
    return T[ros.POINTCLOUD2](
        header=header(**header_args),
        height=height,
        width=width,
        fields=fields,
        is_bigendian=bigendian,
        point_step=point_step,
        row_step=row_step,
        data=buffer,
        is_dense=False,
    )


def cdr(message, typename: str = ros.POINTCLOUD2, little_endian: bool = True) -> bytes:
    return bytes(STORE.serialize_cdr(message, typename, little_endian=little_endian))


def grid_points(height: int = 3, width: int = 4, scale: float = 1.0) -> np.ndarray:
    rng = np.random.default_rng(7)
    return np.round(rng.uniform(-50, 50, (height, width, 3)) * scale)


# -- PointCloud2 ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("datatype", sorted(ros.POINT_FIELD_TYPES))
@pytest.mark.parametrize("bigendian", [False, True])
def test_every_point_field_datatype_in_either_byte_order_reads_back(datatype, bigendian):
    points = grid_points()  # whole numbers within every type's range (INT8 ... FLOAT64)
    if ros.POINT_FIELD_TYPES[datatype].startswith("u"):
        points = np.abs(points)
    cloud = ros.pointcloud2(cdr(cloud_message(points, datatype, bigendian)))
    assert cloud.points.dtype == np.float64
    np.testing.assert_array_equal(cloud.points, points.reshape(-1, 3))
    assert (cloud.stamp, cloud.frame_id, cloud.nonfinite, cloud.total) == (1_700_000_000.25, "lidar", 0, 12)


def test_big_endian_data_is_not_read_as_little_endian():
    """Swapped bytes of 1.5 read as little-endian would be a tiny denormal: the flag must be honoured."""
    points = np.full((1, 2, 3), 1.5)
    message = cloud_message(points, PointField.FLOAT32, bigendian=True)
    np.testing.assert_array_equal(ros.pointcloud2(cdr(message)).points, points.reshape(-1, 3))
    message.is_bigendian = False
    assert not np.allclose(ros.pointcloud2(cdr(message)).points, 1.5)


def test_a_big_endian_cdr_encapsulation_reads_too():
    points = grid_points()
    cloud = ros.pointcloud2(cdr(cloud_message(points, PointField.FLOAT64), little_endian=False))
    np.testing.assert_array_equal(cloud.points, points.reshape(-1, 3))


@pytest.mark.parametrize(("point_pad", "row_pad"), [(0, 0), (6, 0), (0, 13), (3, 64)])
def test_padding_within_points_and_after_rows_is_skipped(point_pad, row_pad):
    points = grid_points(5, 7, 0.01)
    message = cloud_message(points, PointField.FLOAT32, point_pad=point_pad, row_pad=row_pad, order="zxy")
    cloud = ros.pointcloud2(cdr(message))
    np.testing.assert_allclose(cloud.points, points.reshape(-1, 3), rtol=1e-6)


def test_a_last_row_without_its_padding_is_read():
    points = grid_points(3, 4)
    message = cloud_message(points, PointField.FLOAT32, row_pad=8)
    message.data = message.data[:-8]
    np.testing.assert_array_equal(ros.pointcloud2(cdr(message)).points, points.reshape(-1, 3))


def test_an_organised_cloud_drops_its_nan_returns_and_counts_them():
    points = grid_points(4, 5, 0.01)
    points[0, :, :] = np.nan  # a row without returns
    points[2, 3, 1] = np.inf
    points[3, 0, 2] = np.nan
    cloud = ros.pointcloud2(cdr(cloud_message(points)))
    keep = np.isfinite(points.reshape(-1, 3)).all(axis=1)
    assert (cloud.nonfinite, cloud.total, len(cloud.points)) == (7, 20, 13)
    np.testing.assert_allclose(cloud.points, points.reshape(-1, 3)[keep], rtol=1e-6)


@pytest.mark.parametrize(("height", "width", "row_pad"), [(1, 1000, 0), (25, 40, 13), (7, 143, 0)])
def test_a_dense_cloud_is_thinned_as_it_is_read_to_what_the_assembler_keeps(height, width, row_pad):
    """`keep`: every n-th point in the message's order (rows one after the other, padding skipped), n the
    ceiling of points / keep, exactly the points the assembler's own thinning (AFFORD_ASSEMBLER__
    MAX_FRAME_POINTS) takes from the whole cloud, so the poses do not change; NaN among them still dropped."""
    from affordcore.assembly.assembler import thinning_step

    points = np.random.default_rng(3).uniform(-5, 5, (height, width, 3)).astype(np.float32)
    points[1 % height, ::3, 2] = np.nan
    message = cdr(cloud_message(points, PointField.FLOAT32, row_pad=row_pad))
    whole = ros.pointcloud2(message)
    for keep in (300, 999, height * width, 10**6):
        thinned = ros.pointcloud2(message, keep=keep)
        step = -(-height * width // keep)
        every = points.reshape(-1, 3)[::step].astype(np.float64)
        finite = np.isfinite(every).all(axis=1)
        np.testing.assert_array_equal(thinned.points, every[finite])
        counts = (thinned.total, thinned.read, thinned.nonfinite)
        assert counts == (height * width, len(every), (~finite).sum())
        assert len(thinned.points) <= keep
        if keep >= height * width:
            np.testing.assert_array_equal(thinned.points, whole.points)
    dense = np.nan_to_num(points, nan=1.0)  # without NaN: the assembler's every n-th of the whole cloud
    whole = ros.pointcloud2(cdr(cloud_message(dense, PointField.FLOAT32, row_pad=row_pad))).points
    read = ros.pointcloud2(cdr(cloud_message(dense, PointField.FLOAT32, row_pad=row_pad)), keep=300).points
    np.testing.assert_array_equal(read, whole[:: thinning_step(len(whole), 300)])


def test_an_empty_cloud_is_no_points():
    cloud = ros.pointcloud2(cdr(cloud_message(np.zeros((0, 0, 3)))))
    assert cloud.points.shape == (0, 3) and cloud.total == 0


def _hostile(change) -> str:
    message = cloud_message(grid_points())
    payload = change(message)
    with pytest.raises(MessageError) as caught:
        ros.pointcloud2(cdr(message) if payload is None else payload, LimitSettings(max_points=1000))
    return str(caught.value)


def _field(message, name):
    return next(f for f in message.fields if f.name == name)


@pytest.mark.parametrize(
    ("change", "reason"),
    [
        (lambda m: b"", "at least its 4-byte header"),
        (lambda m: b"\x07\x07\x00\x00" + b"\x00" * 64, "not a CDR sensor_msgs/msg/PointCloud2"),
        (lambda m: cdr(m)[:40], "not a CDR sensor_msgs/msg/PointCloud2"),
        (lambda m: cdr(m) + b"\x00" * 64, "not a CDR"),  # trailing bytes
        (
            lambda m: setattr(m, "width", 100_000) or setattr(m, "height", 100_000),
            "AFFORD_LIMITS__MAX_POINTS",
        ),
        (lambda m: setattr(m, "fields", [f for f in m.fields if f.name != "y"]), "missing y"),
        (lambda m: setattr(m, "fields", [*m.fields, _field(m, "x")]), "two fields named x"),
        (lambda m: setattr(_field(m, "z"), "offset", 100), "runs past the"),
        (lambda m: setattr(_field(m, "z"), "datatype", 9), "datatype 9"),
        (lambda m: setattr(_field(m, "x"), "count", 0), "count 0"),
        (lambda m: setattr(m, "point_step", 0), "point_step is 0"),
        (lambda m: setattr(m, "row_step", 3), "row_step 3 is less"),
        (lambda m: setattr(m, "data", m.data[:-20]), "height x row_step"),
        (lambda m: setattr(m, "data", np.concatenate([m.data, m.data])), "height x row_step"),
        (lambda m: setattr(m, "height", 40), "height x row_step"),
        (lambda m: setattr(m.header.stamp, "sec", -5), "outside 0"),
        (lambda m: setattr(m.header.stamp, "nanosec", 2_000_000_000), "outside 0"),
        (lambda m: setattr(m.header, "frame_id", "f" * 5000), "frame_id"),
    ],
)
def test_hostile_clouds_are_refused_with_a_reason(change, reason):
    assert reason in _hostile(change)


def test_a_sequence_length_past_the_payload_is_refused_before_anything_is_allocated():
    payload = bytearray(cdr(cloud_message(grid_points())))
    # the data sequence's length is the 4 bytes before its bytes: claim 2 GB
    data_length = 3 * 4 * (2 + 3 * 4)
    at = len(payload) - data_length - 1 - 4  # is_dense (1 byte) follows the data
    assert int.from_bytes(payload[at : at + 4], "little") == data_length
    payload[at : at + 4] = (2**31).to_bytes(4, "little")
    with pytest.raises(MessageError, match="not a CDR"):
        ros.pointcloud2(bytes(payload))


# -- Imu -----------------------------------------------------------------------------------------------------


def imu_message(acceleration, covariance0: float = 0.01, **header_args):
    vector = T["geometry_msgs/msg/Vector3"]
    return T[ros.IMU](
        header=header(**({"frame_id": "imu"} | header_args)),
        orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=np.full(9, -1.0),  # no orientation estimate: only the acceleration is read
        angular_velocity=vector(x=0.0, y=0.0, z=0.0),
        angular_velocity_covariance=np.zeros(9),
        linear_acceleration=vector(*map(float, acceleration)),
        linear_acceleration_covariance=np.array([covariance0] + [0.0] * 8),
    )


def test_an_imu_at_rest_measures_up_so_gravity_is_its_opposite():
    """REP 145: a level IMU at rest reads +9.81 along z (up); gravity, the down the assembler wants, is -z."""
    reading = ros.imu(cdr(imu_message([0.0, 0.0, G]), ros.IMU))
    np.testing.assert_allclose(reading.down, [0, 0, -1])
    assert (reading.stamp, reading.frame_id) == (1_700_000_000.25, "imu")
    # a camera-frame IMU (x right, y down, z forward) held level: up is -y, so it reads -9.81 along y
    tilted = ros.imu(cdr(imu_message([0.3, -9.7, 1.2]), ros.IMU)).down
    np.testing.assert_allclose(tilted, np.array([-0.3, 9.7, -1.2]) / np.linalg.norm([0.3, 9.7, 1.2]))


@pytest.mark.parametrize(
    ("acceleration", "covariance0", "reason"),
    [
        ([0.0, 0.0, 1.0], 0.01, "not gravity at rest"),  # reported in g, not m/s^2
        ([0.0, 0.0, 40.0], 0.01, "not gravity at rest"),  # a shock
        ([np.nan, 0.0, 9.8], 0.01, "not gravity at rest"),
        ([0.0, 0.0, 9.8], -1.0, "no linear acceleration"),
    ],
)
def test_unusable_imu_readings_are_refused(acceleration, covariance0, reason):
    with pytest.raises(MessageError, match=reason):
        ros.imu(cdr(imu_message(acceleration, covariance0), ros.IMU))


def test_an_oversized_or_malformed_imu_is_refused_before_parsing():
    with pytest.raises(MessageError, match="at most"):
        ros.imu(b"\x00\x01\x00\x00" + b"\x00" * (ros.MAX_IMU_BYTES + 1))
    with pytest.raises(MessageError, match="not a CDR sensor_msgs/msg/Imu"):
        ros.imu(cdr(imu_message([0, 0, G]), ros.IMU)[:100])


def test_the_gravity_track_gives_the_reading_nearest_the_cloud_within_its_age():
    track = ros.GravityTrack(keep=3)
    for stamp in (10.0, 10.1, 10.2, 10.3):  # the first falls out
        track.add(stamp, np.array([0.0, 0.0, -stamp]))
    assert track.at(10.14, 0.5)[2] == -10.1
    assert track.at(10.0, 0.05) is None  # 10.0 was dropped; 10.1 is too far
    assert track.at(11.0, 0.5) is None
    assert len(track) == 3


def test_a_quaternion_turns_imu_readings_into_the_cloud_frame():
    # IMU frame turned 90 degrees about z from the cloud's: the IMU's x is the cloud's y
    rotation = ros.rotation_of([0, 0, np.sqrt(0.5), np.sqrt(0.5)])
    np.testing.assert_allclose(rotation @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    with pytest.raises(ValueError, match="unit quaternion"):
        ros.rotation_of([0, 0, 1, 1])


# -- Odometry ------------------------------------------------------------------------------------------------


def odometry_message(position, quaternion=(0.0, 0.0, 0.0, 1.0), child: str = "base_link", **header_args):
    vector = T["geometry_msgs/msg/Vector3"]
    pose = T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](*map(float, position)),
        orientation=T["geometry_msgs/msg/Quaternion"](*map(float, quaternion)),
    )
    twist = T["geometry_msgs/msg/Twist"](linear=vector(0.0, 0.0, 0.0), angular=vector(0.0, 0.0, 0.0))
    return T[ros.ODOMETRY](
        header=header(**({"frame_id": "odom"} | header_args)),
        child_frame_id=child,
        pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
        twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)),
    )


def test_an_odometry_reading_is_the_pose_of_its_child_frame_in_its_odometry_frame():
    half = np.radians(30) / 2  # 30 degrees about z
    reading = ros.odometry(
        cdr(odometry_message([1.0, 2.0, 0.1], [0, 0, np.sin(half), np.cos(half)]), ros.ODOMETRY)
    )
    assert (reading.stamp, reading.frame_id, reading.child_frame_id) == (
        1_700_000_000.25,
        "odom",
        "base_link",
    )
    np.testing.assert_allclose(reading.pose[:3, 3], [1.0, 2.0, 0.1])
    np.testing.assert_allclose(
        reading.pose[:3, :3] @ [1, 0, 0], [np.cos(2 * half), np.sin(2 * half), 0], atol=1e-12
    )


@pytest.mark.parametrize(
    ("position", "quaternion", "reason"),
    [
        ([np.nan, 0.0, 0.0], (0, 0, 0, 1), "not finite"),
        ([1e6, 0.0, 0.0], (0, 0, 0, 1), "MAX_EXTENT"),
        ([0.0, 0.0, 0.0], (0, 0, 0, 0), "unit quaternion"),
        ([0.0, 0.0, 0.0], (0, 0, 1, 1), "unit quaternion"),
    ],
)
def test_unusable_odometry_is_refused_with_a_reason(position, quaternion, reason):
    with pytest.raises(MessageError, match=reason):
        ros.odometry(cdr(odometry_message(position, quaternion), ros.ODOMETRY))


def test_an_oversized_or_malformed_odometry_is_refused_before_parsing():
    with pytest.raises(MessageError, match="at most"):
        ros.odometry(b"\x00\x01\x00\x00" + b"\x00" * (ros.MAX_IMU_BYTES + 1))
    with pytest.raises(MessageError, match="not a CDR nav_msgs/msg/Odometry"):
        ros.odometry(cdr(odometry_message([0, 0, 0]), ros.ODOMETRY)[:60])


def _pose_at(x: float, yaw_deg: float) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = ros.rotation_of([0, 0, np.sin(np.radians(yaw_deg) / 2), np.cos(np.radians(yaw_deg) / 2)])
    pose[0, 3] = x
    return pose


def test_the_pose_track_interpolates_between_the_readings_either_side_of_a_cloud():
    track = ros.PoseTrack()
    track.add(10.2, _pose_at(1.0, 20.0))  # out of order: the network does not promise order
    track.add(10.0, _pose_at(0.0, 0.0))
    between = track.at(10.05, 0.5)
    np.testing.assert_allclose(between, _pose_at(0.25, 5.0), atol=1e-9)  # a quarter of the way, turn too
    np.testing.assert_allclose(track.at(10.3, 0.2), _pose_at(1.0, 20.0))  # after the last: the nearest
    assert track.at(10.1, 0.05) is None  # none within its age
    np.testing.assert_allclose(track.at(10.01, 0.05), _pose_at(0.0, 0.0))  # only one side within its age


def test_waiting_for_a_reading_past_a_stamp_ends_when_one_comes_or_at_the_timeout():
    import threading

    track = ros.PoseTrack()
    track.add(1.0, np.eye(4))
    assert track.wait_past(1.0, 0.0)  # one at the stamp already
    start = time.monotonic()
    assert not track.wait_past(2.0, 0.2) and time.monotonic() - start >= 0.19
    timer = threading.Timer(0.1, track.add, (2.5, np.eye(4)))
    timer.start()
    assert track.wait_past(2.0, 30.0)  # woken by the reading, long before the timeout
    timer.join()


def test_a_sensor_mounted_ahead_of_the_base_moves_sideways_when_the_base_turns():
    from services.ros import pose_guess, sensor_mounting
    from services.settings import RosSettings

    settings = RosSettings(base_from_cloud=[0.5, 0, 0, 0, 0, 0, 1])
    track = ros.PoseTrack()
    track.add(1.0, _pose_at(0.0, 90.0))
    guess = pose_guess(track, 1.0, settings, sensor_mounting(settings))
    np.testing.assert_allclose(guess[:3, 3], [0.0, 0.5, 0.0], atol=1e-12)
    assert pose_guess(track, 5.0, settings, sensor_mounting(settings)) is None


# -- tf ------------------------------------------------------------------------------------------------------


def transform_stamped(parent: str, child: str, translation, yaw_deg: float = 0.0, quaternion=None, sec=1):
    q = quaternion or (0.0, 0.0, np.sin(np.radians(yaw_deg) / 2), np.cos(np.radians(yaw_deg) / 2))
    return T["geometry_msgs/msg/TransformStamped"](
        header=header(sec=sec, nanosec=0, frame_id=parent),
        child_frame_id=child,
        transform=T["geometry_msgs/msg/Transform"](
            translation=T["geometry_msgs/msg/Vector3"](*map(float, translation)),
            rotation=T["geometry_msgs/msg/Quaternion"](*map(float, q)),
        ),
    )


def tf_payload(*transforms) -> bytes:
    return cdr(T[ros.TFMESSAGE](transforms=list(transforms)), ros.TFMESSAGE)


def _rigid(translation, yaw_deg: float = 0.0) -> np.ndarray:
    pose = _pose_at(0.0, yaw_deg)
    pose[:3, 3] = translation
    return pose


def test_a_tf_message_is_each_child_s_pose_in_its_parent():
    mount, imu = ros.tf_message(
        tf_payload(
            transform_stamped("/base_link", "lidar", [0.2, 0.0, 0.5], 90.0),
            transform_stamped("base_link", "imu_link", [0.0, 0.1, 0.2]),
        )
    )
    assert (mount.parent, mount.child, imu.parent, imu.child) == (
        "base_link",
        "lidar",
        "base_link",
        "imu_link",
    )
    np.testing.assert_allclose(mount.transform, _rigid([0.2, 0.0, 0.5], 90.0), atol=1e-12)
    np.testing.assert_allclose(mount.transform[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-12)  # lidar x = base y


@pytest.mark.parametrize(
    ("change", "reason"),
    [
        ({"parent": ""}, "both frames must be named"),
        ({"child": "base_link"}, "both frames must be named, and differ"),
        ({"translation": [np.nan, 0, 0]}, "not finite"),
        ({"translation": [0, 0, 1e6]}, "MAX_EXTENT"),
        ({"quaternion": (0.0, 0.0, 1.0, 1.0)}, "unit quaternion"),
        ({"child": "x" * (ros.MAX_FRAME_ID + 1)}, "characters"),
    ],
)
def test_a_tf_message_with_one_unusable_transform_is_refused_whole(change, reason):
    arguments = {"parent": "base_link", "child": "lidar", "translation": [0.2, 0, 0.5]} | change
    quaternion = arguments.pop("quaternion", None)
    bad = transform_stamped(
        arguments["parent"], arguments["child"], arguments["translation"], quaternion=quaternion
    )
    good = transform_stamped("base_link", "imu_link", [0, 0, 0.1])
    with pytest.raises(MessageError, match=reason):
        ros.tf_message(tf_payload(good, bad))


def test_an_oversized_or_malformed_tf_message_is_refused_before_parsing():
    with pytest.raises(MessageError, match="at most"):
        ros.tf_message(b"\x00\x01\x00\x00" + b"\x00" * (ros.MAX_TF_BYTES + 1))
    with pytest.raises(MessageError, match="not a CDR tf2_msgs/msg/TFMessage"):
        ros.tf_message(tf_payload(transform_stamped("base_link", "lidar", [0, 0, 0]))[:30])


def _tree(*transforms) -> ros.TransformTree:
    tree = ros.TransformTree()
    tree.add(ros.tf_message(tf_payload(*transforms)))
    return tree


def test_the_transform_tree_chains_frames_through_their_nearest_common_ancestor():
    tree = _tree(
        transform_stamped("odom", "base_link", [1.0, 0.0, 0.0], 90.0),
        transform_stamped("base_link", "mast", [0.0, 0.0, 1.0]),
        transform_stamped("mast", "lidar", [0.1, 0.0, 0.0], 180.0),
        transform_stamped("base_link", "imu_link", [0.0, 0.2, 0.0], -90.0),
    )
    base_from_lidar = tree.lookup("base_link", "lidar")
    np.testing.assert_allclose(base_from_lidar, _rigid([0, 0, 1]) @ _rigid([0.1, 0, 0], 180.0), atol=1e-12)
    np.testing.assert_allclose(base_from_lidar @ [0, 0, 0, 1], [0.1, 0.0, 1.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(tree.lookup("lidar", "base_link"), np.linalg.inv(base_from_lidar), atol=1e-12)
    # siblings under base_link: the IMU in the lidar's frame, and a point through both ways round
    lidar_from_imu = tree.lookup("/lidar", "imu_link")
    point = np.array([0.3, -0.2, 0.4, 1.0])
    np.testing.assert_allclose(
        base_from_lidar @ lidar_from_imu @ point, tree.lookup("base_link", "imu_link") @ point
    )
    np.testing.assert_allclose(
        tree.lookup("odom", "lidar"), tree.lookup("odom", "base_link") @ base_from_lidar
    )
    assert tree.lookup("lidar", "camera") is None and tree.lookup("map", "odom") is None
    np.testing.assert_allclose(tree.lookup("lidar", "lidar"), np.eye(4))


def test_the_newest_transform_of_a_frame_holds_and_a_cycle_ends_the_walk():
    tree = _tree(transform_stamped("base_link", "lidar", [0.1, 0, 0]))
    tree.add(ros.tf_message(tf_payload(transform_stamped("base_link", "lidar", [0.3, 0, 0], sec=2))))
    np.testing.assert_allclose(tree.lookup("base_link", "lidar")[:3, 3], [0.3, 0, 0])
    tree.add(ros.tf_message(tf_payload(transform_stamped("lidar", "base_link", [0, 0, 1]))))  # a cycle
    assert tree.lookup("base_link", "camera") is None  # returns, whatever it finds


def test_the_transform_tree_keeps_a_bounded_number_of_frames():
    tree = ros.TransformTree(max_frames=3)
    tree.add(ros.tf_message(tf_payload(*(transform_stamped("base", f"f{i}", [0, 0, i]) for i in range(3)))))
    with pytest.raises(MessageError, match="at most 3"):
        tree.add(
            ros.tf_message(
                tf_payload(
                    transform_stamped("base", "f1", [0, 0, 5]), transform_stamped("base", "f9", [0, 0, 0])
                )
            )
        )
    np.testing.assert_allclose(tree.lookup("base", "f1")[:3, 3], [0, 0, 1])  # nothing of the refused one kept
    tree.add(
        ros.tf_message(tf_payload(transform_stamped("base", "f1", [0, 0, 7])))
    )  # known frames still move
    assert len(tree) == 3 and tree.lookup("base", "f1")[2, 3] == 7


@pytest.mark.parametrize("pose", ["[0, 0, 0, 0, 0, 1, 1]", "[0, 0, 0, 0, 0, 1]", "[NaN, 0, 0, 0, 0, 0, 1]"])
def test_a_sensor_mounting_that_is_no_pose_is_refused_before_the_service_starts(pose, monkeypatch):
    from pydantic import ValidationError

    from services.settings import ServiceSettings

    monkeypatch.setenv("AFFORD_ROS__BASE_FROM_CLOUD", pose)
    with pytest.raises(ValidationError, match="base_from_cloud"):
        ServiceSettings()


def test_without_rosbags_the_error_names_the_extra(tmp_path):
    """The core installs without rosbags; a ROS message then says what to install (a subprocess, as the
    library is already imported here)."""
    blocker = tmp_path / "sitecustomize.py"
    blocker.write_text(
        "import sys\nclass Block:\n    def find_spec(self, name, *_):\n"
        "        if name == 'rosbags' or name.startswith('rosbags.'):\n"
        "            raise ImportError('blocked for the test')\nsys.meta_path.insert(0, Block())\n"
    )
    code = (
        "from affordwire import ros\n"
        "try:\n    ros.pointcloud2(b'1234')\nexcept ros.RosUnavailable as e:\n    print('ERR', e)\n"
    )
    env = {"PYTHONPATH": f"{tmp_path}:{'.'}"}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=60)
    assert "ERR" in done.stdout and "pip install 'affordmap[ros]'" in done.stdout, done.stderr


# -- the assembler's ROS 2 keys ------------------------------------------------------------------------------


def test_keys_follow_rmw_zenoh_and_the_ros2dds_bridge():
    from services.ros import dds_type, topic_keys
    from services.settings import RosSettings

    settings = RosSettings(points="/robot1/points", domain_id=3)
    assert dds_type(ros.POINTCLOUD2) == "sensor_msgs::msg::dds_::PointCloud2_"
    assert topic_keys(settings.points, ros.POINTCLOUD2, settings) == [
        "3/robot1/points/sensor_msgs::msg::dds_::PointCloud2_/*",
        "robot1/points",
    ]
    only = RosSettings(imu="imu/data", key_formats=["rmw_zenoh"])
    assert topic_keys(only.imu, ros.IMU, only) == ["0/imu/data/sensor_msgs::msg::dds_::Imu_/*"]


@pytest.mark.parametrize("topic", ["/points/*", "a b", "/a//b", "**", "pts$"])
def test_a_topic_with_wildcards_is_refused_before_the_service_starts(topic, monkeypatch):
    from pydantic import ValidationError

    from services.settings import ServiceSettings

    monkeypatch.setenv("AFFORD_ROS__POINTS", topic)
    with pytest.raises(ValidationError, match="not a ROS 2 name"):
        ServiceSettings()


@pytest.mark.parametrize("quaternion", ["[0, 0, 1, 1]", "[0, 0, 1]", "[NaN, 0, 0, 1]"])
def test_a_cloud_from_imu_that_is_no_rotation_is_refused_before_the_service_starts(quaternion, monkeypatch):
    from pydantic import ValidationError

    from services.settings import ServiceSettings

    monkeypatch.setenv("AFFORD_ROS__CLOUD_FROM_IMU", quaternion)
    with pytest.raises(ValidationError, match="not a unit quaternion"):
        ServiceSettings()


def test_environment_variables_configure_the_ros_input(monkeypatch):
    from services.settings import ServiceSettings

    monkeypatch.setenv("AFFORD_ROS__POINTS", "/camera/depth/points")
    monkeypatch.setenv("AFFORD_ROS__CLOUD_FROM_IMU", "[0, 0, 0.7071068, 0.7071068]")
    monkeypatch.setenv("AFFORD_ROS__KEY_FORMATS", '["ros2dds"]')
    settings = ServiceSettings().ros
    assert settings.points == "/camera/depth/points" and settings.key_formats == ["ros2dds"]
    assert settings.cloud_from_imu == pytest.approx([0, 0, 0.7071068, 0.7071068])


def _zenoh_ok():
    try:
        import zenoh  # noqa: F401
    except ImportError:
        return False
    return True


def rmw_zenoh_key(topic: str, typename: str, domain: int = 0) -> str:
    """The key rmw_zenoh puts a message on: type in DDS form and the type's RIHS01 hash (rosbags computes
    it from the definition, as rosidl does)."""
    from services.ros import dds_type

    return f"{domain}/{topic.strip('/')}/{dds_type(typename)}/{STORE.hash_rihs01(typename)}"


@pytest.fixture
def ros_network(monkeypatch):
    """(a router's endpoint, the robot's session on it), the assembler's ROS topics /robot1/points,
    /robot1/imu and /robot1/odom set."""
    from services.launch import free_port
    from services.transport import open_session

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_session([], mode="router", listen=[endpoint])
    monkeypatch.setenv("AFFORD_ROS__POINTS", "/robot1/points")
    monkeypatch.setenv("AFFORD_ROS__IMU", "/robot1/imu")
    monkeypatch.setenv("AFFORD_ROS__ODOMETRY", "/robot1/odom")
    monkeypatch.setenv("AFFORD_SERVICE__MAX_LAG", "600")
    client = open_session([endpoint])
    try:
        yield endpoint, client
    finally:
        client.close()
        router.close()


@contextlib.contextmanager
def running_assembler(endpoint: str, tmp_path):
    """The assembler service in a thread, stopped on leaving."""
    import threading

    from services.assembler import AssemblerService
    from services.node import Node
    from services.settings import ServiceSettings

    node = Node("assembler", "robot1", [endpoint], ServiceSettings(), rrd=tmp_path / "a.rrd")
    service = AssemblerService(node)
    thread = threading.Thread(target=service.run, daemon=True)
    thread.start()
    try:
        yield service
    finally:
        node.stop_event.set()
        thread.join(30)


@pytest.fixture
def ros_assembler(ros_network, tmp_path):
    """An assembler (in a thread) and the robot's session."""
    endpoint, client = ros_network
    with running_assembler(endpoint, tmp_path) as service:
        yield service, client


def _answers(client) -> tuple[list, list, list]:
    """(the assembler's error payloads, its pose payloads, the subscribers collecting them) for robot1."""
    from services.transport import Keys

    errors, poses, keys = [], [], Keys("robot1")
    subscribers = [
        client.declare_subscriber(keys.error("assembler"), lambda s: errors.append(s.payload.to_bytes())),
        client.declare_subscriber(keys.pose, lambda s: poses.append(s.payload.to_bytes())),
    ]
    return errors, poses, subscribers


def _camera_floor(seed: int) -> np.ndarray:
    """An organised cloud (60, 80, 3) of a floor as a depth camera (x right, y down, z ahead) sees it."""
    u = np.random.default_rng(seed).uniform(-1, 1, (60, 80, 2))
    return np.stack([u[..., 0] * 2, np.full(u.shape[:2], 1.2), 2 + u[..., 1] * 1.5], axis=-1)


@pytest.mark.skipif(not _zenoh_ok(), reason="zenoh is not installed")
def test_the_assembler_takes_clouds_and_imu_on_both_key_formats_and_answers_bad_ones(ros_assembler):
    from conftest import eventually

    from affordwire import messages

    service, client = ros_assembler
    errors, poses, subscribers = _answers(client)
    floor = _camera_floor(1)
    floor[::7, ::5] = np.nan  # missing returns
    import zenoh

    publishers = {}

    def put(key: str, payload: bytes) -> None:
        """Once the assembler's subscription has reached this session, with BLOCK (zenoh's default, DROP,
        loses samples under load)."""
        if key not in publishers:
            block = zenoh.CongestionControl.BLOCK
            publishers[key] = client.declare_publisher(key, congestion_control=block)
            assert eventually_matched(publishers[key]), key
        publishers[key].put(payload)

    base = time.time()
    put(
        rmw_zenoh_key("/robot1/imu", ros.IMU),
        cdr(imu_message([0.0, -G, 0.0], sec=int(base), nanosec=0, frame_id="lidar"), ros.IMU),
    )
    put("robot1/imu", cdr(imu_message([0.0, 0.0, 1.0], sec=int(base), nanosec=0), ros.IMU))  # in g
    # the clouds must find the good reading held and the bad one refused: wait until both are answered
    taken = eventually(lambda: service.ros.counts.imu == 1 and len(errors) == 1, timeout=20, poll=0.02)
    assert taken, (service.ros.counts.imu, errors)
    for k, key in enumerate([rmw_zenoh_key("/robot1/points", ros.POINTCLOUD2), "robot1/points"]):
        message = cloud_message(floor, sec=int(base), nanosec=(k + 1) * 100_000_000, frame_id="lidar")
        put(key, cdr(message))
    put("robot1/points", b"\x00\x01\x00\x00garbage")
    assert eventually(lambda: len(poses) == 2 and len(errors) == 2, timeout=20), (len(poses), errors)
    imu_reason, cloud_reason = sorted(messages.parse(messages.Error, e).reason for e in errors)
    assert "not gravity at rest" in imu_reason and "not a CDR sensor_msgs/msg/PointCloud2" in cloud_reason
    pose = messages.parse(messages.Pose, poses[0])
    assert pose.child_frame_id == "lidar"
    assert service.ros.counts.clouds == 2 and service.ros.counts.with_gravity == 2
    assert service.ros.counts.nonfinite == 2 * len(range(0, 60, 7)) * len(range(0, 80, 5))
    # the Imu's gravity (down = +y of the camera) reached the assembler, in the odometry frame
    gravity_sum = service.assembler._gravity_sum
    np.testing.assert_allclose(gravity_sum / np.linalg.norm(gravity_sum), [0, 1, 0], atol=1e-6)
    for subscriber in subscribers:
        subscriber.undeclare()


@pytest.mark.skipif(not _zenoh_ok(), reason="zenoh is not installed")
def test_the_assembler_takes_each_cloud_s_pose_guess_from_the_odometry_and_answers_bad_readings(
    ros_assembler,
):
    from conftest import eventually

    from affordwire import messages

    service, client = ros_assembler
    errors, poses, subscribers = _answers(client)
    floor = _camera_floor(2)
    import zenoh

    publisher = client.declare_publisher("robot1/odom", congestion_control=zenoh.CongestionControl.BLOCK)
    clouds = client.declare_publisher("robot1/points", congestion_control=zenoh.CongestionControl.BLOCK)
    assert eventually_matched(publisher) and eventually_matched(clouds)
    base = int(time.time())
    for k in range(4):  # the base creeps along x, 1 cm every 0.1 s
        stamp = header(sec=base, nanosec=k * 100_000_000, frame_id="odom").stamp
        message = odometry_message([0.01 * k, 0.0, 0.0], sec=stamp.sec, nanosec=stamp.nanosec)
        publisher.put(cdr(message, ros.ODOMETRY))
    publisher.put(cdr(odometry_message([0, 0, 0], (0, 0, 0, 0), sec=base), ros.ODOMETRY))  # no rotation
    assert eventually(lambda: service.ros.counts.odometry == 4 and len(errors) == 1, timeout=20, poll=0.02)
    for k in (0, 1):  # clouds at 0.05 s and 0.25 s: between two readings each
        clouds.put(
            cdr(cloud_message(floor, sec=base, nanosec=50_000_000 + k * 200_000_000, frame_id="lidar"))
        )
    assert eventually(lambda: len(poses) == 2, timeout=20), (len(poses), errors)
    assert "unit quaternion" in messages.parse(messages.Error, errors[0]).reason
    assert service.ros.counts.with_odometry == 2
    # the last cloud's guess: the base at 0.25 s, interpolated (2.5 cm); the sensor is taken to sit on it
    np.testing.assert_allclose(service.assembler._last_guess[:3, 3], [0.025, 0.0, 0.0], atol=1e-9)
    for subscriber in subscribers:
        subscriber.undeclare()


@pytest.mark.skipif(not _zenoh_ok(), reason="zenoh is not installed")
def test_a_cloud_that_comes_before_its_odometry_waits_for_it(ros_network, tmp_path, monkeypatch):
    """The odometry at a cloud's stamp comes on its own topic, here 0.3 s after the cloud: the cloud waits
    for it (up to AFFORD_ROS__READING_WAIT after it arrived) and gets its pose guess from it."""
    import zenoh
    from conftest import eventually

    monkeypatch.setenv("AFFORD_ROS__IMU", "")
    monkeypatch.setenv("AFFORD_ROS__READING_WAIT", "30")
    endpoint, client = ros_network
    with running_assembler(endpoint, tmp_path) as service:
        errors, poses, subscribers = _answers(client)
        block = zenoh.CongestionControl.BLOCK
        odometry, clouds = (
            client.declare_publisher(key, congestion_control=block)
            for key in ("robot1/odom", "robot1/points")
        )
        assert eventually_matched(odometry) and eventually_matched(clouds)
        base = int(time.time())
        clouds.put(cdr(cloud_message(_camera_floor(2), sec=base, nanosec=50_000_000, frame_id="lidar")))
        time.sleep(0.3)
        assert service.ros.counts.clouds == 0  # not taken yet: waiting for its odometry
        odometry.put(cdr(odometry_message([0.5, 0.0, 0.0], sec=base, nanosec=100_000_000), ros.ODOMETRY))
        assert eventually(lambda: len(poses) == 1, timeout=20), errors
        assert service.ros.counts.with_odometry == 1
        np.testing.assert_allclose(service.assembler._last_guess[:3, 3], [0.5, 0.0, 0.0], atol=1e-9)
        for subscriber in subscribers:
            subscriber.undeclare()


@pytest.mark.skipif(not _zenoh_ok(), reason="zenoh is not installed")
def test_the_assembler_takes_the_mount_and_the_imu_s_rotation_from_the_robot_s_latched_tf(
    ros_network, tmp_path, capfd
):
    """The robot publishes its tree on /tf_static (TRANSIENT_LOCAL, as rmw_zenoh: a cached publisher) before
    the assembler starts: the lidar 0.5 m ahead of the base, the IMU rolled 90 degrees. The assembler fetches
    it, puts each cloud's pose guess at the lidar rather than the base, and turns the IMU's gravity into the
    lidar's frame; a bad TFMessage on /tf is answered on the error key."""
    import zenoh
    from conftest import eventually

    from affordwire import messages

    endpoint, client = ros_network
    roll = (np.sin(np.pi / 4), 0.0, 0.0, np.cos(np.pi / 4))  # imu y -> base z
    tree = tf_payload(
        transform_stamped("base_link", "lidar", [0.5, 0.0, 0.0]),
        transform_stamped("base_link", "imu_link", [0.0, 0.0, 0.2], quaternion=roll),
    )
    latched = zenoh.ext.declare_advanced_publisher(
        client,
        rmw_zenoh_key("/tf_static", ros.TFMESSAGE),
        cache=zenoh.ext.CacheConfig(1),
        publisher_detection=True,
        # as rmw_zenoh's TRANSIENT_LOCAL publisher: the cache sequenced by number (no timestamping needed)
        sample_miss_detection=zenoh.ext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=0.5),
    )
    latched.put(tree)
    with running_assembler(endpoint, tmp_path) as service:
        errors, poses, subscribers = _answers(client)
        assert eventually(lambda: service.ros.counts.transforms == 2, timeout=20, poll=0.02)
        block = zenoh.CongestionControl.BLOCK
        odometry, imu, clouds, tf = (
            client.declare_publisher(key, congestion_control=block)
            for key in ("robot1/odom", "robot1/imu", "robot1/points", "tf")
        )
        assert all(eventually_matched(p) for p in (odometry, imu, clouds, tf))
        base = int(time.time())
        for k in range(2):  # the base at the origin, turned 90 degrees
            stamp = dict(sec=base, nanosec=k * 100_000_000)
            odometry.put(
                cdr(
                    odometry_message([0, 0, 0], [0, 0, np.sin(np.pi / 4), np.cos(np.pi / 4)], **stamp),
                    ros.ODOMETRY,
                )
            )
            imu.put(
                cdr(imu_message([0.0, G, 0.0], frame_id="imu_link", **stamp), ros.IMU)
            )  # up: the IMU's +y
        tf.put(
            tf_payload(transform_stamped("base_link", "lidar", [0.5, 0, 0], quaternion=(0.0, 0.0, 0.0, 0.0)))
        )
        assert eventually(
            lambda: service.ros.counts.odometry == 2 and service.ros.counts.imu == 2 and len(errors) == 1,
            timeout=20,
            poll=0.02,
        )
        clouds.put(cdr(cloud_message(_camera_floor(3), sec=base, nanosec=50_000_000, frame_id="lidar")))
        assert eventually(lambda: len(poses) == 1, timeout=20), errors
        # the lidar sits 0.5 m ahead of the base, which faces +y: at (0, 0.5, 0)
        np.testing.assert_allclose(service.assembler._last_guess[:3, 3], [0.0, 0.5, 0.0], atol=1e-9)
        # the IMU's down (its -y) is the lidar's -z
        gravity = service.assembler._gravity_sum
        np.testing.assert_allclose(gravity / np.linalg.norm(gravity), [0, 0, -1], atol=1e-6)
        assert "unit quaternion" in messages.parse(messages.Error, errors[0]).reason
        assert service.ros.counts.transforms == 2  # the refused message kept nothing
        for subscriber in subscribers:
            subscriber.undeclare()
    latched.undeclare()
    said = capfd.readouterr().out
    assert "tf: 'lidar' sits at (0.500, 0.000, 0.000) m in 'base_link'" in said
    assert "no transform" not in said


@pytest.mark.skipif(not _zenoh_ok(), reason="zenoh is not installed")
def test_a_missing_transform_is_said_once_naming_the_frames(ros_assembler, capfd):
    import zenoh
    from conftest import eventually

    service, client = ros_assembler
    errors, poses, subscribers = _answers(client)
    block = zenoh.CongestionControl.BLOCK
    odometry, clouds = (
        client.declare_publisher(key, congestion_control=block) for key in ("robot1/odom", "robot1/points")
    )
    assert eventually_matched(odometry) and eventually_matched(clouds)
    base = int(time.time())
    odometry.put(cdr(odometry_message([0.2, 0, 0], sec=base, nanosec=0), ros.ODOMETRY))
    assert eventually(lambda: service.ros.counts.odometry == 1, timeout=20, poll=0.02)
    for k in range(3):
        clouds.put(
            cdr(cloud_message(_camera_floor(4 + k), sec=base, nanosec=10_000_000 * k, frame_id="lidar"))
        )
    assert eventually(lambda: len(poses) == 3, timeout=20), errors
    np.testing.assert_allclose(service.assembler._last_guess[:3, 3], [0.2, 0, 0], atol=1e-9)  # at the base
    said = capfd.readouterr().out
    assert said.count("no transform from 'lidar' to 'base_link' (tf has 0 frames)") == 1, said
    assert "AFFORD_ROS__BASE_FROM_CLOUD" in said
    for subscriber in subscribers:
        subscriber.undeclare()


@pytest.mark.skipif(not _zenoh_ok(), reason="zenoh is not installed")
def test_with_odometry_the_assembler_puts_afford_s_world_in_the_robot_s_tf(
    ros_network, tmp_path, monkeypatch
):
    """With the maps on ROS 2 and odometry, each map the assembler aligns puts the pose of `world` in the
    odometry's frame on /tf_static, latched (a subscriber that joins after it was sent gets it): a point of
    the map in world is where the robot's odometry saw it."""
    import zenoh
    from conftest import eventually

    from affordwire import messages
    from services.transport import Keys

    monkeypatch.setenv("AFFORD_ROS__MAPS", "true")
    endpoint, client = ros_network
    clouds = []
    on_cloud = client.declare_subscriber(Keys("robot1").cloud, lambda s: clouds.append(s.payload.to_bytes()))
    turned = (0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4))
    with running_assembler(endpoint, tmp_path) as service:
        block = zenoh.CongestionControl.BLOCK
        odometry, points = (
            client.declare_publisher(key, congestion_control=block)
            for key in ("robot1/odom", "robot1/points")
        )
        assert eventually_matched(odometry) and eventually_matched(points)
        base = int(time.time())
        for k in range(4):  # the robot stands at (1, 2) in odom, turned 90 degrees; its lidar is the base
            stamp = dict(sec=base, nanosec=k * 100_000_000)
            odometry.put(cdr(odometry_message([1.0, 2.0, 0.0], turned, child="lidar", **stamp), ros.ODOMETRY))
        assert eventually(lambda: service.ros.counts.odometry == 4, timeout=20, poll=0.02)
        for k in range(3):
            stamp = dict(sec=base, nanosec=50_000_000 + k * 100_000_000)
            points.put(cdr(cloud_message(_camera_floor(10 + k), frame_id="lidar", **stamp)))
        assert eventually(lambda: clouds and service.world_tf.published, timeout=30), service.node.no_output
        heard = []
        late = zenoh.ext.declare_advanced_subscriber(
            client,
            rmw_zenoh_key("/tf_static", ros.TFMESSAGE),
            lambda sample: heard.append(sample.payload.to_bytes()),
            history=zenoh.ext.HistoryConfig(detect_late_publishers=True),
        )
        assert eventually(lambda: heard, timeout=20)
        late.undeclare()
    on_cloud.undeclare()
    (transform,) = ros.tf_message(heard[-1])
    assert (transform.parent, transform.child) == ("odom", "world")
    world_from_assembler = messages.pose_matrix(
        messages.parse(messages.CloudMessage, clouds[-1]).world_from_input
    )
    # the first cloud's sensor origin (the assembler's odometry frame) is the robot's pose in odom
    odom_from_sensor = ros.rigid_of([1.0, 2.0, 0.0, *turned])
    np.testing.assert_allclose(transform.transform @ world_from_assembler, odom_from_sensor, atol=1e-4)


# -- end to end: a ROS 2 robot on rmw_zenoh keys -------------------------------------------------------------


def organised_cloud(sequence, index: int) -> np.ndarray:
    """A depth frame of an afford synth sequence as the organised cloud a ROS depth driver publishes
    (depth_image_proc's point_cloud_xyz): one point per 2 x 2 block at its mean measured depth, NaN where
    the block has none, in the camera's optical frame (x right, y down, z ahead). (H/2, W/2, 3)."""
    from affordcore.assembly.sequence import DEPTH_SCALE, INVALID_DEPTH

    depth = sequence.depth(index)
    rows, columns = depth.shape[0] // 2, depth.shape[1] // 2
    depth = depth[: rows * 2, : columns * 2]
    measured = (depth != 0) & (depth != INVALID_DEPTH)
    total = np.where(measured, depth, 0).reshape(rows, 2, columns, 2).sum(axis=(1, 3), dtype=np.float64)
    count = measured.reshape(rows, 2, columns, 2).sum(axis=(1, 3))
    z = np.divide(total, count, out=np.full(total.shape, np.nan), where=count > 0) * DEPTH_SCALE
    v, u = np.mgrid[0:rows, 0:columns] * 2 + 0.5
    k = sequence.intrinsics
    return np.stack([(u - k[0, 2]) / k[0, 0] * z, (v - k[1, 2]) / k[1, 1] * z, z], axis=-1)


def ros_stream(sequence, indices, start: float, period: float, frame_id: str = "camera_depth_optical_frame"):
    """(stamp, PointCloud2 CDR, Imu CDR) per frame: the clouds of `organised_cloud` and what a level IMU on
    the camera reads (the specific force: g up, i.e. -g times gravity's direction in the camera frame),
    stamped `period` apart from `start`."""
    for k, index in enumerate(indices):
        stamp = start + k * period
        sec, nanosec = int(stamp), int(round((stamp - int(stamp)) * 1e9)) % 1_000_000_000
        cloud = cloud_message(organised_cloud(sequence, index), sec=sec, nanosec=nanosec, frame_id=frame_id)
        yield stamp, cdr(cloud), imu_reading(sequence, index, stamp, frame_id)


def imu_reading(sequence, index: int, stamp: float, frame_id: str = "camera_depth_optical_frame") -> bytes:
    """What a level IMU on the camera reads at the frame (the specific force: g up, i.e. -g times gravity's
    direction in the camera frame), as an Imu CDR stamped `stamp`."""
    sec, nanosec = int(stamp), int(round((stamp - int(stamp)) * 1e9)) % 1_000_000_000
    return cdr(
        imu_message(-G * sequence.gravity(index), sec=sec, nanosec=nanosec, frame_id=frame_id), ros.IMU
    )


def odometry_reading(sequence, index: int, stamp: float, child: str = "camera_depth_optical_frame") -> bytes:
    """The frame's pose by the robot's wheel odometry (`afford synth --sequences`) as a nav_msgs/Odometry
    of the camera's frame, stamped as its cloud."""
    from scipy.spatial.transform import Rotation

    pose = sequence.odometry(index)
    sec, nanosec = int(stamp), int(round((stamp - int(stamp)) * 1e9)) % 1_000_000_000
    quaternion = Rotation.from_matrix(pose[:3, :3]).as_quat()
    return cdr(odometry_message(pose[:3, 3], quaternion, child, sec=sec, nanosec=nanosec), ros.ODOMETRY)


def _angle_deg(a, b) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


@pytest.mark.slow
def test_a_ros2_robot_on_rmw_zenoh_keys_gets_affordance_maps(generated_sequence, generated_room, tmp_path):
    """PointCloud2, Imu and Odometry as rmw_zenoh publishes them (CDR on <domain>/<topic>/<DDS type>/<RIHS01
    hash>), through the three services, to the maps `afford watch` writes; the IMU's up-pointing
    acceleration must come out as a map whose up is the room's, and the odometry must reach the assembler."""
    import zenoh
    from test_end_to_end import (
        EVERY_FRAME,
        _assert_same_as_afford_map,
        _check_maps,
        _latest_cloud,
        assert_a_place_on_a_label,
    )

    from affordcore.assembly.sequence import read_sequence
    from services.launch import Stack
    from services.transport import Keys

    sequence = read_sequence(generated_sequence)
    indices = list(range(0, 120, 3))  # 40 frames, as the depth-frame end-to-end test
    env = {
        **EVERY_FRAME,
        "AFFORD_ROS__POINTS": "/robot1/camera/points",
        "AFFORD_ROS__IMU": "/robot1/imu",
        "AFFORD_ROS__ODOMETRY": "/robot1/odom",
        "AFFORD_SERVICE__RECORDING_ID": "e2e-ros",
    }
    stack = Stack(tmp_path / "run", env=env).start()
    try:
        watch = watching(stack, tmp_path / "maps", frames=40)
        session = stack.session()
        try:
            block = zenoh.CongestionControl.BLOCK
            points = session.declare_publisher(
                rmw_zenoh_key("/robot1/camera/points", ros.POINTCLOUD2), congestion_control=block
            )
            imu = session.declare_publisher(rmw_zenoh_key("/robot1/imu", ros.IMU), congestion_control=block)
            odom = session.declare_publisher(
                rmw_zenoh_key("/robot1/odom", ros.ODOMETRY), congestion_control=block
            )
            assert eventually_matched(points) and eventually_matched(imu) and eventually_matched(odom), (
                stack.logs()
            )
            start, began = time.time(), time.monotonic()
            stamps = [start + k / 30 for k in range(len(indices))]
            # The IMU and the odometry lead the camera by a frame, as a 200 Hz IMU and a 50 Hz odometry do
            # beside a driver's clouds: zenoh keeps no order between keys, so a reading put just before its
            # cloud may reach the assembler after it (the first cloud then has no gravity at all).
            readings = [
                (imu_reading(sequence, i, s), odometry_reading(sequence, i, s))
                for i, s in zip(indices, stamps)
            ]
            imu.put(readings[0][0])
            odom.put(readings[0][1])
            time.sleep(1 / 30)
            for k, (_, cloud, _) in enumerate(ros_stream(sequence, indices, start, 1 / 30)):
                if k + 1 < len(readings):
                    imu.put(readings[k + 1][0])
                    odom.put(readings[k + 1][1])
                points.put(cloud)
                time.sleep(max(0.0, began + (k + 2) / 30 - time.monotonic()))  # a 30 Hz camera
            list(session.get(Keys(stack.robot).key("status", "*"), timeout=10.0))  # behind the samples
        finally:
            session.close()
        watched, _ = watch.communicate(timeout=300)
        assert watch.returncode == 0, watched[-3000:] + stack.logs()
        cloud = _latest_cloud(stack)
    finally:
        codes = stack.stop()
    assert codes == {"assembler": 0, "features": 0, "inference": 0, "router": 0}, stack.logs()
    assert cloud.frames == 40
    documents = _check_maps(tmp_path / "maps", 40, watched)
    _assert_same_as_afford_map(cloud, documents)
    assert_a_place_on_a_label(documents, generated_room, sequence)
    log = (tmp_path / "run" / "assembler.log").read_text()
    assert "0 rejected" in log and "40 clouds" in log and "40 with an Imu gravity" in log, log[-3000:]
    assert "40 with the odometry's pose" in log, log[-3000:]
    assert "NaN or infinite and dropped" in log
    # the map's up, in the odometry frame (the first camera's), is the room's: -gravity of frame 0, to within
    # the registration's drift (KISS-ICP turned 7 degrees off over this walk without odometry; with it as a
    # prior, under one), and the IMU's gravity is averaged through those poses. An IMU read with the wrong
    # sign would turn the map upside down: 170-180 degrees
    from affordwire import messages

    world_from_odom = messages.pose_matrix(cloud.world_from_input)
    assert _angle_deg(world_from_odom[:3, :3].T @ [0, 0, 1], -sequence.gravity(0)) < 3.0


def watching(stack, out, frames: int) -> subprocess.Popen:
    """`afford watch` of the stack's robot into `out` until maps cover `frames` scans (240 s at most), its
    output kept for the test to read."""
    from test_end_to_end import AFFORD

    command = ["watch", "--connect", stack.endpoint, "--robot", stack.robot, "--frames", str(frames)]
    return subprocess.Popen(
        AFFORD + command + ["--timeout", "240", "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def eventually_matched(publisher, timeout: float = 20.0) -> bool:
    deadline = time.monotonic() + timeout
    while not publisher.matching_status.matching:
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


def test_the_dds_bridge_s_forwarder_never_holds_rclpy_up_keeps_order_and_counts_what_it_drops():
    """A put that waits on a full Zenoh queue holds back only its own topic: offering returns at once, the
    messages go out in order, past the queue's depth the oldest waiting is dropped and counted, and a close
    sends what still waits."""
    import threading

    import zenoh

    from services.dds import _Forwarder

    class Congested:  # a session whose queue is full until `free` is set
        def __init__(self):
            self.free, self.sent, self.calls = threading.Event(), [], threading.Event()

        def put(self, key, payload, **options):
            self.calls.set()
            self.free.wait()
            self.sent.append((key, payload, options["congestion_control"]))

    session = Congested()
    forwarder = _Forwarder(session, "robot1/odom", depth=3)
    forwarder.offer(b"0")
    assert session.calls.wait(5)  # the thread waits in its put of b"0"
    start = time.monotonic()
    for payload in (b"1", b"2", b"3", b"4"):
        forwarder.offer(payload)
    assert time.monotonic() - start < 0.5  # never waited on the congested put
    assert forwarder.dropped == 1  # b"1", the oldest of the four waiting behind a queue of three
    session.free.set()
    forwarder.close()
    block = zenoh.CongestionControl.BLOCK
    assert session.sent == [("robot1/odom", p, block) for p in (b"0", b"2", b"3", b"4")]
    assert forwarder.sent == 4


def test_a_dds_bridge_forwarder_whose_put_fails_loses_that_message_alone_and_says_so(capsys):
    """A put that raises (a closing session, a refused key) must not end the topic's thread: later messages
    still go out, the failure is counted and its error said once."""
    from services.dds import _Forwarder

    class Refusing:
        def __init__(self):
            self.sent = []

        def put(self, key, payload, **options):
            if payload.startswith(b"bad"):
                raise RuntimeError("refused")
            self.sent.append(payload)

    session = Refusing()
    forwarder = _Forwarder(session, "robot1/odom", depth=8)
    for payload in (b"bad0", b"1", b"bad2", b"3"):
        forwarder.offer(payload)
    forwarder.close()
    assert session.sent == [b"1", b"3"]
    assert (forwarder.sent, forwarder.failed, forwarder.error) == (2, 2, "refused")
    assert capsys.readouterr().out.count("robot1/odom: a message was not put on Zenoh: refused") == 1
