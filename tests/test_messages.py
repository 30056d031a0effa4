"""affordwire.messages: numpy arrays and library objects to the afford.v1 messages and back, and a
`MessageError` naming the problem for every message that cannot be used."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from affordcore.assembly.depth import back_project
from affordcore.geometry.grid import PoseGrid
from affordcore.geometry.skeleton import get_skeleton
from affordcore.mapping.maps import build_map
from affordwire import messages
from affordwire.messages import MessageError

FIELD = messages._Field


def back_project_message(frame, *args, **kwargs) -> np.ndarray:
    """A DepthFrame's points, as the assembler gets them: the checked image, back-projected."""
    return back_project(messages.depth_image(frame), *args, **kwargs)


def _wire(message):
    """The message as a receiver sees it: serialised and parsed again."""
    return messages.parse(type(message), message.SerializeToString())


def _scan(records: np.ndarray, types: dict[str, int]):
    """A Scan of structured `records` whose fields (name: NumericType) are laid out as in their dtype."""
    scan = messages.Scan(frame_id="lidar", point_stride=records.dtype.itemsize, data=records.tobytes())
    for name, (_, offset) in records.dtype.fields.items():
        scan.fields.add(name=name, offset=offset, type=types.get(name, FIELD.UINT8))
    return scan


# -- names and parsing ---------------------------------------------------------------------------------------


def test_schema_names_are_the_full_protobuf_names():
    assert messages.schema_name(messages.Scan) == "afford.v1.Scan"
    assert messages.schema_name(messages.AffordanceMapMessage()) == "afford.v1.AffordanceMap"


@pytest.mark.parametrize(
    "payload",
    [b"\xff", b"\x0a\x10abc", b"\x2a\x05\x01\x02", b"\x07"],
    ids=["truncated varint", "truncated bytes", "truncated data", "bad wire type"],
)
def test_parse_refuses_what_is_not_protobuf(payload):
    with pytest.raises(
        MessageError, match=rf"payload of {len(payload)} bytes is not a valid afford\.v1\.Scan"
    ):
        messages.parse(messages.Scan, payload)


def test_parse_reads_a_valid_payload():
    scan = messages.Scan(frame_id="lidar", point_stride=12, data=b"\x00" * 24)
    assert messages.parse(messages.Scan, scan.SerializeToString()) == scan
    assert messages.parse(messages.Scan, b"") == messages.Scan()  # the empty message is valid protobuf


# -- packed points -------------------------------------------------------------------------------------------


def test_points_and_times_round_trip_at_float32_precision():
    rng = np.random.default_rng(1)
    points = rng.normal(scale=20.0, size=(500, 3))
    times = rng.uniform(0, 0.1, 500)
    scan = messages.Scan(frame_id="lidar")
    messages.pack_points(scan, points, times)
    assert [(f.name, f.offset, f.type) for f in scan.fields] == [
        ("x", 0, FIELD.FLOAT32),
        ("y", 4, FIELD.FLOAT32),
        ("z", 8, FIELD.FLOAT32),
        ("t", 12, FIELD.FLOAT32),
    ]
    assert scan.point_stride == 16 and len(scan.data) == 500 * 16
    got, got_times = messages.unpack_points(_wire(scan))
    assert got.dtype == np.float64 and got.shape == (500, 3)
    np.testing.assert_array_equal(got, points.astype(np.float32))
    np.testing.assert_array_equal(got_times, times.astype(np.float32))
    assert np.all(np.abs(got - points) <= np.abs(points) * 2.0**-24)  # float32 rounding to nearest, not worse
    # without times: three fields, 12-byte points, no t back
    messages.pack_points(scan, points)
    assert [f.name for f in scan.fields] == ["x", "y", "z"] and scan.point_stride == 12
    got, got_times = messages.unpack_points(_wire(scan))
    assert got_times is None and np.array_equal(got, points.astype(np.float32))


def test_scan_with_extra_fields_a_larger_stride_and_float64_coordinates():
    rng = np.random.default_rng(2)
    # 8 bytes of padding at the end
    layout = np.dtype(
        {
            "names": ["intensity", "x", "y", "z", "ring", "t"],
            "formats": ["<u2", "<f8", "<f8", "<f8", "u1", "<f4"],
            "offsets": [0, 8, 16, 24, 32, 36],
            "itemsize": 48,
        }
    )
    records = np.zeros(300, dtype=layout)
    xyz = rng.normal(scale=30.0, size=(300, 3))
    records["x"], records["y"], records["z"] = xyz.T
    records["intensity"] = rng.integers(0, 65535, 300)
    records["ring"] = rng.integers(0, 64, 300)
    records["t"] = np.linspace(0, 0.1, 300)
    scan = _scan(
        records,
        {
            "intensity": FIELD.UINT16,
            "x": FIELD.FLOAT64,
            "y": FIELD.FLOAT64,
            "z": FIELD.FLOAT64,
            "ring": FIELD.UINT8,
            "t": FIELD.FLOAT32,
        },
    )
    fields = list(scan.fields)
    del scan.fields[:]
    scan.fields.extend(reversed(fields))  # the order of the fields does not matter, their offsets do
    points, times = messages.unpack_points(_wire(scan))
    np.testing.assert_array_equal(points, xyz)  # float64 travels exactly
    np.testing.assert_array_equal(times, records["t"].astype(np.float64))


def test_integer_and_mixed_coordinate_types_decode_to_their_values():
    layout = np.dtype(
        {"names": ["x", "y", "z"], "formats": ["<i2", "<f4", "<f8"], "offsets": [0, 2, 8], "itemsize": 16}
    )
    records = np.zeros(3, dtype=layout)
    records["x"], records["y"], records["z"] = [-3, 2, 7], [0.5, -1.25, 4.0], [1e-3, 2.0, -8.5]
    scan = _scan(records, {"x": FIELD.INT16, "y": FIELD.FLOAT32, "z": FIELD.FLOAT64})
    points, times = messages.unpack_points(scan)
    assert times is None
    np.testing.assert_array_equal(points, [[-3, 0.5, 1e-3], [2, -1.25, 2.0], [7, 4.0, -8.5]])


def test_points_with_a_non_finite_coordinate_are_dropped_with_their_times():
    points = np.arange(30, dtype=np.float64).reshape(10, 3)
    points[2, 0] = np.nan
    points[5, 2] = np.inf
    points[7] = np.nan  # an organised cloud's missing return
    times = np.arange(10) * 0.01
    scan = messages.Scan()
    messages.pack_points(scan, points, times)
    got, got_times = messages.unpack_points(scan)
    keep = [0, 1, 3, 4, 6, 8, 9]
    np.testing.assert_array_equal(got, points[keep])
    np.testing.assert_array_equal(got_times, times[keep].astype(np.float32))


def test_an_empty_scan_has_no_points():
    scan = messages.Scan()
    messages.pack_points(scan, np.empty((0, 3)))
    points, times = messages.unpack_points(_wire(scan))
    assert points.shape == (0, 3) and times is None


def _valid_scan():
    scan = messages.Scan()
    messages.pack_points(scan, np.ones((4, 3)), np.zeros(4))
    return scan


def _without_z(scan):
    fields = [f for f in scan.fields if f.name != "z"]
    del scan.fields[:]
    scan.fields.extend(fields)


def _field(scan, name):
    return next(f for f in scan.fields if f.name == name)


@pytest.mark.parametrize(
    ("spoil", "reason"),
    [
        (_without_z, r"need fields x, y, z; missing z \(has x, y, t\)"),
        (lambda s: s.ClearField("fields"), r"missing x, y, z \(has none\)"),
        (lambda s: setattr(s, "point_stride", 0), r"point_stride is 0"),
        (
            lambda s: setattr(s, "data", s.data + b"\x00\x00\x00"),
            r"data is 67 bytes, not a whole number of 16-byte points",
        ),
        (
            lambda s: setattr(_field(s, "t"), "offset", 13),
            r"field t \(offset 13, 4 bytes\) runs past the 16-byte point",
        ),
        (lambda s: setattr(_field(s, "x"), "type", FIELD.UNKNOWN), r"field x has no numeric type"),
    ],
    ids=["missing z", "no fields", "stride 0", "ragged data", "t past the stride", "untyped x"],
)
def test_bad_point_layouts_are_refused(spoil, reason):
    scan = _valid_scan()
    spoil(scan)
    with pytest.raises(MessageError, match=reason):
        messages.unpack_points(_wire(scan))


def test_a_field_past_a_shorter_stride_is_refused():
    scan = messages.Scan()
    messages.pack_points(scan, np.ones((4, 3)))
    scan.point_stride = 8
    scan.data = scan.data[: 4 * 8]
    with pytest.raises(MessageError, match=r"field z \(offset 8, 4 bytes\) runs past the 8-byte point"):
        messages.unpack_points(scan)


# -- poses and time ------------------------------------------------------------------------------------------


def test_a_random_rigid_transform_round_trips_through_a_pose():
    rng = np.random.default_rng(3)
    for _ in range(5):
        matrix = np.eye(4)
        matrix[:3, :3] = Rotation.random(random_state=rng).as_matrix()
        matrix[:3, 3] = rng.uniform(-50, 50, 3)
        pose = messages.Pose()
        messages.set_pose(pose, matrix, "world", "camera", at=1_700_000_000.25)
        pose = _wire(pose)
        assert (pose.frame_id, pose.child_frame_id) == ("world", "camera")
        assert messages.seconds(pose.timestamp) == pytest.approx(1_700_000_000.25, abs=1e-6)
        q = pose.orientation
        assert np.linalg.norm([q.x, q.y, q.z, q.w]) == pytest.approx(1.0, abs=1e-12)
        back = messages.pose_matrix(pose)
        np.testing.assert_allclose(back, matrix, atol=1e-12)
        np.testing.assert_array_equal(back[3], [0, 0, 0, 1])


def test_an_unset_pose_is_the_identity():
    np.testing.assert_array_equal(messages.pose_matrix(messages.Pose()), np.eye(4))


@pytest.mark.parametrize(
    ("quaternion", "reason"),
    [
        ((0.0, 0.0, 0.0, 2.0), r"not a unit quaternion \(norm 2\)"),
        ((0.5, 0.5, 0.0, 0.5), r"not a unit quaternion \(norm 0\.866"),
        ((0.0, 0.0, np.nan, 1.0), r"not a unit quaternion"),
    ],
)
def test_a_non_unit_quaternion_is_refused(quaternion, reason):
    pose = messages.Pose()
    pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = quaternion
    with pytest.raises(MessageError, match=reason):
        messages.pose_matrix(pose)


def test_a_pose_with_a_non_finite_position_is_refused():
    pose = messages.Pose()
    messages.set_pose(pose, np.eye(4), "world", "camera")
    pose.position.y = np.inf
    with pytest.raises(MessageError, match="position is not finite"):
        messages.pose_matrix(pose)


# -- depth frames --------------------------------------------------------------------------------------------

K = np.array([[500.0, 0.0, 2.2], [0.0, 400.0, 1.7], [0.0, 0.0, 1.0]])


def test_depth_frame_message_holds_the_image_and_the_pinhole():
    depth = np.arange(12, dtype=np.uint16).reshape(3, 4) * 1000
    frame = _wire(messages.depth_frame_message(depth, K, frame_id="kinect", at=12.5))
    assert (frame.width, frame.height, frame.frame_id, frame.depth_scale, frame.invalid_value) == (
        4,
        3,
        "kinect",
        0.001,
        65535,
    )
    np.testing.assert_array_equal(np.frombuffer(frame.depth, dtype="<u2").reshape(3, 4), depth)
    assert (frame.intrinsics.fx, frame.intrinsics.fy, frame.intrinsics.cx, frame.intrinsics.cy) == (
        500.0,
        400.0,
        2.2,
        1.7,
    )
    assert messages.seconds(frame.timestamp) == pytest.approx(12.5)


@pytest.mark.parametrize(
    "image",
    [
        np.zeros((3, 4), dtype=np.float32),
        np.zeros((3, 4), dtype=np.int32),
        np.zeros((2, 3, 4), dtype=np.uint16),
    ],
    ids=["float", "int32", "3-D"],
)
def test_depth_frame_message_wants_a_2d_uint16_image(image):
    with pytest.raises(MessageError, match="must be 2-D uint16"):
        messages.depth_frame_message(image, K)


def test_a_known_pixel_back_projects_through_the_pinhole():
    depth = np.zeros((4, 5), dtype=np.uint16)
    depth[1, 3] = 1500  # v = 1, u = 3, 1.5 m
    depth[2, 0] = 65535  # no measurement (7-Scenes)
    frame = messages.depth_frame_message(depth, K)
    assert frame.frame_id == "camera"  # unnamed, a depth image is in the camera's own frame
    points = back_project_message(_wire(frame))
    # x = (u - cx) / fx * d = (3 - 2.2) / 500 * 1.5; y = (v - cy) / fy * d = (1 - 1.7) / 400 * 1.5
    np.testing.assert_allclose(points, [[0.0024, -0.002625, 1.5]], atol=1e-12)


def test_every_valid_pixel_back_projects_to_its_own_ray():
    rng = np.random.default_rng(4)
    depth = rng.integers(300, 6000, size=(6, 7)).astype(np.uint16)
    depth[0, 0], depth[3, 4], depth[5, 6] = 0, 65535, 0
    points = back_project_message(messages.depth_frame_message(depth, K))
    assert len(points) == 6 * 7 - 3
    u = points[:, 0] / points[:, 2] * K[0, 0] + K[0, 2]
    v = points[:, 1] / points[:, 2] * K[1, 1] + K[1, 2]
    np.testing.assert_allclose(u, np.rint(u), atol=1e-9)
    np.testing.assert_allclose(v, np.rint(v), atol=1e-9)
    ui, vi = np.rint(u).astype(int), np.rint(v).astype(int)
    np.testing.assert_allclose(points[:, 2], depth[vi, ui] * 0.001)
    # 2 x 2 blocks: one point per whole block (the last column is left out), at the mean of its measured
    # depths
    half = back_project_message(messages.depth_frame_message(depth, K), pixel_step=2)
    u2 = half[:, 0] / half[:, 2] * K[0, 0] + K[0, 2]
    v2 = half[:, 1] / half[:, 2] * K[1, 1] + K[1, 2]
    assert len(half) == 3 * 3
    np.testing.assert_allclose(u2 % 2, 0.5, atol=1e-9)  # on the ray through the block's centre
    np.testing.assert_allclose(v2 % 2, 0.5, atol=1e-9)
    block = depth[:6, :6].reshape(3, 2, 3, 2).astype(float)
    measured = block != 0
    measured &= block != 65535
    means = (block * measured).sum(axis=(1, 3)) / measured.sum(axis=(1, 3))
    rows, columns = np.floor(v2 / 2).astype(int), np.floor(u2 / 2).astype(int)
    np.testing.assert_allclose(half[:, 2], means[rows, columns] * 0.001)


def test_depth_scale_and_range_limits():
    depth = np.array([[500, 1000, 3000, 8000]], dtype=np.uint16)
    frame = messages.depth_frame_message(depth, K)
    np.testing.assert_allclose(back_project_message(frame)[:, 2], [0.5, 1.0, 3.0, 8.0])
    np.testing.assert_allclose(back_project_message(frame, min_range=0.8, max_range=4.0)[:, 2], [1.0, 3.0])
    # inclusive
    np.testing.assert_allclose(back_project_message(frame, min_range=1.0, max_range=3.0)[:, 2], [1.0, 3.0])
    assert back_project_message(frame, min_range=9.0).shape == (0, 3)
    frame.depth_scale = 0.0002  # e.g. a sensor counting fifths of a millimetre
    np.testing.assert_allclose(back_project_message(frame)[:, 2], [0.1, 0.2, 0.6, 1.6])


def test_zero_and_the_invalid_value_mean_no_measurement():
    depth = np.array([[0, 65535, 1000], [4000, 0, 65535]], dtype=np.uint16)
    frame = messages.depth_frame_message(depth, K)
    np.testing.assert_allclose(back_project_message(frame)[:, 2], [1.0, 4.0])
    frame.invalid_value = 4000  # another sensor's marker: now 65535 is a (far) reading and 4000 is not
    np.testing.assert_allclose(back_project_message(frame)[:, 2], [65.535, 1.0, 65.535])


def _frame(**changes):
    frame = messages.depth_frame_message(np.full((3, 4), 1000, dtype=np.uint16), K)
    for name, value in changes.items():
        if name in ("fx", "fy", "cx", "cy"):
            setattr(frame.intrinsics, name, value)
        else:
            setattr(frame, name, value)
    return frame


@pytest.mark.parametrize(
    ("changes", "reason"),
    [
        ({"depth": b"\x00" * 23}, r"depth holds 23 bytes; a 4 x 3 16-bit image needs 24"),
        ({"width": 5}, r"depth holds 24 bytes; a 5 x 3 16-bit image needs 30"),
        ({"height": 0}, r"depth image is 4 x 0"),
        ({"fx": 0.0}, r"fx=0\.0, fy=400\.0 must be positive focal lengths"),
        ({"fx": -500.0}, r"fx=-500\.0"),
        ({"fy": -1.0}, r"fy=-1\.0 must be positive"),
        ({"cx": np.nan}, r"must be positive focal lengths"),
        ({"depth_scale": 0.0}, r"depth_scale must be positive metres per unit below 1, got 0\.0"),
        ({"depth_scale": -0.001}, r"depth_scale must be positive"),
    ],
    ids=[
        "depth bytes short",
        "width too big",
        "height 0",
        "fx 0",
        "fx negative",
        "fy negative",
        "cx nan",
        "scale 0",
        "scale negative",
    ],
)
def test_unusable_depth_frames_are_refused(changes, reason):
    with pytest.raises(MessageError, match=reason):
        back_project_message(_wire(_frame(**changes)))


# -- clouds --------------------------------------------------------------------------------------------------


def _rigid(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    matrix[:3, 3] = rng.uniform(-2, 2, 3)
    return matrix


def test_a_cloud_round_trips_with_its_frame_and_source():
    points = np.random.default_rng(5).uniform(0, 4, (250, 3))
    transform = _rigid(5)
    cloud = _wire(messages.cloud_message(points, transform, "room.ply", frames=7, at=100.0))
    assert (cloud.frame_id, cloud.source, cloud.frames) == ("world", "room.ply", 7)
    assert (cloud.world_from_input.frame_id, cloud.world_from_input.child_frame_id) == ("world", "input")
    assert messages.seconds(cloud.timestamp) == pytest.approx(100.0)
    np.testing.assert_array_equal(messages.cloud_points(cloud), points.astype(np.float32))
    np.testing.assert_allclose(messages.pose_matrix(cloud.world_from_input), transform, atol=1e-12)


@pytest.mark.parametrize("frame, levelled", [("world", True), ("camera", False), ("", False)])
def test_a_cloud_in_any_frame_is_read_and_only_a_world_one_counts_as_levelled(frame, levelled):
    points = np.random.default_rng(4).uniform(0, 4, (200, 3))
    cloud = messages.cloud_message(points, np.eye(4), "scan")
    cloud.frame_id = frame
    np.testing.assert_allclose(messages.cloud_points(_wire(cloud)), points, atol=1e-6)
    assert messages.is_levelled(cloud) is levelled


def test_fields_carry_the_world_from_input_they_are_given_else_the_clouds():
    cloud = messages.cloud_message(np.zeros((200, 3)), _rigid(8), "scan", at=40.0)
    fields = SimpleNamespace(
        lattice=SimpleNamespace(origin=np.zeros(3), resolution=0.1, shape=(2, 2, 2)),
        occupancy=np.zeros((2, 2, 2)),
        distance=np.zeros((2, 2, 2)),
        normals=np.zeros((2, 2, 2, 3)),
        footprint=(0.0, 0.0, 0.1, 0.1),
        steep_facing="centre",
        visibility=None,
        soft_occupancy=None,
        normal_estimator="nearest",
        columns=None,
    )
    levelling = _rigid(9)
    given = _wire(messages.fields_message(fields, cloud, levelling))
    np.testing.assert_allclose(messages.pose_matrix(given.world_from_input), levelling, atol=1e-9)
    assert given.cloud_timestamp == cloud.timestamp  # what ties the answer to the cloud
    kept = _wire(messages.fields_message(fields, cloud))
    np.testing.assert_allclose(messages.pose_matrix(kept.world_from_input), _rigid(8), atol=1e-9)


def test_a_cloud_carries_where_the_sensor_stood_checked():
    from affordcore.settings import LimitSettings

    points = np.random.default_rng(3).uniform(0, 4, (200, 3))
    assert messages.cloud_origins(_wire(messages.cloud_message(points, np.eye(4), "x"))) is None
    origins = np.array([[1.0, 2.0, 1.5], [2.5, 2.0, 1.4]])
    cloud = _wire(messages.cloud_message(points, np.eye(4), "x", origins=origins))
    np.testing.assert_allclose(messages.cloud_origins(cloud), origins)
    with pytest.raises(MessageError, match=r"carries 2 sensor positions; at most 1 .*MAX_SENSOR_ORIGINS"):
        messages.cloud_origins(cloud, LimitSettings(max_sensor_origins=1))
    cloud.sensor_origins[1].y = float("nan")
    with pytest.raises(MessageError, match="sensor positions are not finite"):
        messages.cloud_origins(cloud)
    cloud.sensor_origins[1].y = 1e6
    with pytest.raises(MessageError, match="beyond AFFORD_LIMITS__MAX_EXTENT"):
        messages.cloud_origins(cloud)


def test_a_cloud_needs_a_hundred_finite_points():
    points = np.random.default_rng(6).uniform(0, 4, (150, 3))
    assert len(messages.cloud_points(messages.cloud_message(points[:100], np.eye(4), "x"))) == 100
    with pytest.raises(MessageError, match=r"the map has 99 finite points; at least 100 are needed"):
        messages.cloud_points(messages.cloud_message(points[:99], np.eye(4), "x"))
    points[:60, 1] = np.nan  # 150 points, 90 of them finite
    with pytest.raises(MessageError, match=r"the map has 90 finite points"):
        messages.cloud_points(messages.cloud_message(points, np.eye(4), "x"))


# -- scene fields --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def small_fields():
    """Fields of a small synthetic room corner (a floor and a wall), normals given so no estimation runs."""
    from affordcore.geometry.fields import compute_fields

    rng = np.random.default_rng(7)
    floor = np.column_stack([rng.uniform(0, 1.5, 3000), rng.uniform(0, 1.0, 3000), np.zeros(3000)])
    wall = np.column_stack([np.zeros(1500), rng.uniform(0, 1.0, 1500), rng.uniform(0, 1.2, 1500)])
    points = np.concatenate([floor, wall])
    normals = np.concatenate([np.tile([0.0, 0.0, 1.0], (3000, 1)), np.tile([1.0, 0.0, 0.0], (1500, 1))])
    return compute_fields(points, normals=normals)


def test_scene_fields_round_trip_with_what_the_cloud_carried(small_fields):
    transform = _rigid(8)
    cloud = messages.cloud_message(np.zeros((100, 3)), transform, "assembler", frames=12, at=50.0)
    message = _wire(messages.fields_message(small_fields, cloud, at=51.0))
    assert message.frame_id == "world" and message.frames == 12
    assert message.cloud_timestamp == cloud.timestamp and messages.seconds(
        message.timestamp
    ) == pytest.approx(51.0)
    assert message.world_from_input == cloud.world_from_input
    np.testing.assert_allclose(messages.pose_matrix(message.world_from_input), transform, atol=1e-12)

    back = messages.scene_fields(message)
    lattice = small_fields.lattice
    assert back.lattice.shape == lattice.shape and back.lattice.resolution == lattice.resolution
    np.testing.assert_array_equal(back.lattice.origin, lattice.origin)
    assert back.occupancy.dtype == np.float32 and back.occupancy.sum() > 0
    np.testing.assert_array_equal(back.occupancy, small_fields.occupancy)
    np.testing.assert_array_equal(back.distance, small_fields.distance)
    np.testing.assert_array_equal(back.normals, small_fields.normals)
    assert back.footprint == small_fields.footprint
    assert message.steep_facing == "centre" and back.steep_facing == "centre"
    message.ClearField("steep_facing")  # a client that does not set it means the default
    assert messages.scene_fields(message).steep_facing == "centre"
    assert message.normal_estimator == back.normal_estimator == small_fields.normal_estimator
    message.normal_estimator = "cube"
    assert messages.scene_fields(message).normal_estimator == "cube"
    message.ClearField("normal_estimator")  # unset: the nearest neighbours', as before the field
    assert messages.scene_fields(message).normal_estimator == "nearest"
    # the voxel order is the one the schema states: voxel (i, j, k) is element (i * ny + j) * nz + k
    nx, ny, nz = lattice.shape
    occupied = np.argwhere(small_fields.occupancy > 0)
    i, j, k = occupied[len(occupied) // 2]
    assert message.occupancy[(i * ny + j) * nz + k] == 1
    distance = np.frombuffer(message.distance, dtype="<f4")
    assert distance[(i * ny + j) * nz + k] == small_fields.distance[i, j, k]
    assert back.visibility is None and not message.visibility  # no sensor positions, no states


@pytest.fixture(scope="module")
def soft_fields():
    """`small_fields`' room with soft fields."""
    from affordcore.geometry.fields import compute_fields
    from affordcore.settings import VoxelSettings

    rng = np.random.default_rng(7)
    points = rng.uniform([0, 0, 0], [1.5, 1.0, 1.2], (2000, 3))
    return compute_fields(points, VoxelSettings(fields="soft"), normals=np.tile([0.0, 0.0, 1.0], (2000, 1)))


def test_soft_fields_round_trip_and_binary_ones_carry_none(small_fields, soft_fields):
    cloud = messages.cloud_message(np.zeros((100, 3)), np.eye(4), "x")
    back = messages.scene_fields(_wire(messages.fields_message(soft_fields, cloud)))
    assert 0 < back.soft_occupancy.mean() < 1
    np.testing.assert_array_equal(back.soft_occupancy, soft_fields.soft_occupancy)
    np.testing.assert_array_equal(back.collision, soft_fields.soft_occupancy)
    np.testing.assert_array_equal(back.occupancy, soft_fields.occupancy)
    np.testing.assert_array_equal(back.distance, soft_fields.distance)
    binary = _wire(messages.fields_message(small_fields, cloud))
    assert not binary.soft_occupancy and messages.scene_fields(binary).soft_occupancy is None


@pytest.mark.parametrize(
    ("spoil", "reason"),
    [
        (lambda m: setattr(m, "soft_occupancy", m.soft_occupancy[:-4]), r"soft_occupancy holds \d+ bytes"),
        (
            lambda m: setattr(m, "soft_occupancy", b"\x00\x00\xc0\x7f" + m.soft_occupancy[4:]),
            r"outside \[0, 1\]",
        ),
        (
            lambda m: setattr(m, "soft_occupancy", b"\x00\x00\x00\x40" + m.soft_occupancy[4:]),
            r"outside \[0, 1\]",
        ),
    ],
    ids=["short", "NaN", "2.0"],
)
def test_unusable_soft_occupancy_is_refused(soft_fields, spoil, reason):
    message = messages.fields_message(soft_fields, messages.cloud_message(np.zeros((100, 3)), np.eye(4), "x"))
    spoil(message)
    with pytest.raises(MessageError, match=reason):
        messages.scene_fields(_wire(message))


def test_scene_fields_carry_the_fine_columns_and_fields_without_them_carry_none(soft_fields):
    from dataclasses import replace

    cloud = messages.cloud_message(np.zeros((100, 3)), np.eye(4), "x")
    message = _wire(messages.fields_message(soft_fields, cloud))
    back = messages.scene_fields(message)
    assert (back.columns.low < 2.0).any() and (back.columns.high > 0).any()
    for name in ("low", "high", "origin"):
        np.testing.assert_array_equal(getattr(back.columns, name), getattr(soft_fields.columns, name))
    # cell (i, j) is element i * ny + j, as the schema says
    i, j = np.argwhere(soft_fields.columns.low < 2.0)[0]
    ny = soft_fields.columns.low.shape[1]
    assert np.frombuffer(message.columns.low, "<f4")[i * ny + j] == soft_fields.columns.low[i, j]
    bare = _wire(messages.fields_message(replace(soft_fields, columns=None), cloud))
    assert not bare.HasField("columns") and messages.scene_fields(bare).columns is None


def _nan_first(data: bytes) -> bytes:
    return b"\x00\x00\xc0\x7f" + data[4:]


@pytest.mark.parametrize(
    ("spoil", "reason"),
    [
        (lambda c: setattr(c, "resolution", 0.1), r"columns at 0.1 m; the models read 0.05 m"),
        (lambda c: setattr(c, "resolution", float("nan")), r"columns at nan m; the models read 0.05 m"),
        (lambda c: setattr(c, "low", c.low[:-4]), r"columns.low holds \d+ bytes; \d+ x \d+ columns need"),
        (lambda c: setattr(c, "low", _nan_first(c.low)), r"columns.low holds heights outside"),
        (lambda c: setattr(c, "high", np.float32(3.0).tobytes() + c.high[4:]), r"columns.high holds heights"),
        (lambda c: setattr(c, "x0", c.x0 - 2.0), r"reach more than 1.5 m beyond the voxel grid"),
        (lambda c: setattr(c, "nx", c.nx * 100), r"reach more than 1.5 m beyond the voxel grid"),
        (lambda c: setattr(c, "ny", 0), r"columns are empty"),
    ],
    ids=["resolution", "NaN-resolution", "short", "NaN", "too-high", "far", "huge", "empty"],
)
def test_unusable_fine_columns_are_refused(soft_fields, spoil, reason):
    message = messages.fields_message(soft_fields, messages.cloud_message(np.zeros((100, 3)), np.eye(4), "x"))
    spoil(message.columns)
    with pytest.raises(MessageError, match=reason):
        messages.scene_fields(_wire(message))


def _seen(fields):
    """The fields with their voxel states, seen from one position in front of the wall."""
    from affordcore.geometry.visibility import voxel_states

    states = voxel_states(fields.occupancy, fields.lattice, np.array([[1.0, 0.5, 1.0]]))
    return SimpleNamespace(**{**vars(fields), "visibility": states})


def test_scene_fields_carry_the_voxel_states(small_fields):
    seen = _seen(small_fields)
    cloud = messages.cloud_message(np.zeros((100, 3)), np.eye(4), "x")
    back = messages.scene_fields(_wire(messages.fields_message(seen, cloud)))
    np.testing.assert_array_equal(back.visibility, seen.visibility)
    assert {0, 1, 2} == set(np.unique(back.visibility))


@pytest.mark.parametrize(
    ("spoil", "reason"),
    [
        (
            lambda m: setattr(m, "visibility", m.visibility[:-1]),
            r"visibility holds \d+ bytes; a .* grid needs",
        ),
        (lambda m: setattr(m, "visibility", b"\x03" + m.visibility[1:]), r"values other than 0 \(unknown\)"),
        (
            lambda m: setattr(m, "visibility", bytes(len(m.visibility))),  # all unknown: occupied voxels too
            r"visibility says occupied where the occupancy does not",
        ),
    ],
    ids=["short", "a fourth state", "occupied unknown"],
)
def test_unusable_voxel_states_are_refused(small_fields, spoil, reason):
    message = messages.fields_message(
        _seen(small_fields), messages.cloud_message(np.zeros((100, 3)), np.eye(4), "x")
    )
    spoil(message)
    with pytest.raises(MessageError, match=reason):
        messages.scene_fields(_wire(message))


@pytest.mark.parametrize(
    ("spoil", "reason"),
    [
        (
            lambda m: setattr(m, "occupancy", m.occupancy[:-1]),
            r"occupancy holds \d+ bytes; a \(\d+, \d+, \d+\) grid needs",
        ),
        (lambda m: setattr(m, "distance", m.distance + b"\x00" * 4), r"distance holds \d+ bytes"),
        (lambda m: setattr(m, "normals", m.normals[:-12]), r"normals holds \d+ bytes"),
        (lambda m: setattr(m.grid, "nz", m.grid.nz + 1), r"occupancy holds \d+ bytes"),
        (lambda m: setattr(m.grid, "resolution", 0.0), r"at resolution 0\.0 is empty"),
        (lambda m: setattr(m.grid, "nx", 0), r"voxel grid \(0, \d+, \d+\) .* is empty"),
        (lambda m: setattr(m, "x_max", m.x_min - 1), r"empty floor footprint"),
        (lambda m: setattr(m, "y_max", m.y_max + 60), r"floor footprint .* reaches beyond the voxel grid"),
        (lambda m: setattr(m, "steep_facing", "sideways"), r"steep_facing 'sideways' is not one of"),
        (lambda m: setattr(m, "normal_estimator", "guess"), r"normal_estimator 'guess' is not one of"),
    ],
    ids=[
        "occupancy short",
        "distance long",
        "normals short",
        "grid bigger",
        "resolution 0",
        "nx 0",
        "footprint",
        "footprint beyond the grid",
        "unknown facing",
        "unknown normals",
    ],
)
def test_unusable_scene_fields_are_refused(small_fields, spoil, reason):
    message = messages.fields_message(
        small_fields, messages.cloud_message(np.zeros((100, 3)), np.eye(4), "x")
    )
    spoil(message)
    with pytest.raises(MessageError, match=reason):
        messages.scene_fields(_wire(message))


# -- affordance maps -----------------------------------------------------------------------------------------


def _assert_documents_match(got, expected, path="document"):
    """Same structure and keys; numbers within 1e-3 (positives and joints travel as float32)."""
    if isinstance(expected, dict):
        assert isinstance(got, dict) and list(got) == list(expected), path
        for key in expected:
            _assert_documents_match(got[key], expected[key], f"{path}.{key}")
    elif isinstance(expected, list):
        assert isinstance(got, list) and len(got) == len(expected), path
        for index, (a, b) in enumerate(zip(got, expected)):
            _assert_documents_match(a, b, f"{path}[{index}]")
    elif isinstance(expected, (int, float)) and not isinstance(expected, bool):
        assert isinstance(got, (int, float)) and abs(got - expected) <= 1e-3, f"{path}: {got} != {expected}"
    else:
        assert got == expected, path


@pytest.fixture(scope="module")
def real_map():
    """A real map of the built-in example room (thinly sampled to be quick) by the shipped sitting-relaxing
    model."""
    from affordcore.example import example_room
    from affordcore.learn.model import choose_models
    from affordcore.mapping.pipeline import map_affordances, prepare_scene
    from affordcore.settings import Settings

    settings = Settings()
    scene = prepare_scene(example_room(points_per_m2=300), settings)
    models = choose_models([], ["sitting-relaxing"], scene.layout)
    amap = map_affordances(scene.fields, scene.layout, models, settings)["sitting-relaxing"]
    return scene, models[0].id, amap


def test_a_real_map_message_gives_the_document_afford_map_writes(real_map):
    scene, model_id, amap = real_map
    assert len(amap.skeletons) > 0 and len(amap.positives) > 0  # something to carry
    world_from_input = scene.alignment.world_from_input
    cloud = messages.cloud_message(
        scene.cloud.points, world_from_input, "example room", frames=3, at=10.0, scans_received=5
    )
    fields = _wire(messages.fields_message(scene.fields, cloud, at=11.0))
    message = _wire(messages.map_message(amap, model_id, fields, at=12.0))
    assert (message.affordance, message.model, message.frame_id) == ("sitting-relaxing", model_id, "world")
    # 3 scans fused of the 5 received: the map covers all 5 (afford watch --frames 5 takes it)
    assert (fields.frames, fields.scans_received, message.frames, message.scans_received) == (3, 5, 3, 5)
    assert message.cloud_timestamp == cloud.timestamp and message.world_from_input == cloud.world_from_input
    assert messages.seconds(message.timestamp) == pytest.approx(12.0)

    expected = amap.to_json(model_id, world_from_input)
    document = messages.map_document_of(message)
    _assert_documents_match(document, expected)
    assert document["positives"] and document["skeletons"] and len(document["skeletons"][0]["joints"]) == 15

    arrays = messages.map_arrays(message)
    np.testing.assert_array_equal(arrays["confidence"], amap.confidence.astype(np.float32))
    np.testing.assert_array_equal(arrays["positives"], amap.positives.astype(np.float32))
    np.testing.assert_array_equal(arrays["skeletons"], amap.skeletons)  # doubles travel exactly
    np.testing.assert_allclose(arrays["joints"], amap.joints, atol=1e-5)
    grid = messages.map_grid(message)
    assert grid.shape == amap.grid.shape
    for axis in ("x", "y", "z", "theta"):
        np.testing.assert_allclose(getattr(grid, axis), getattr(amap.grid, axis), atol=1e-9)


def _small_grid(nx: int = 20, ny: int = 10) -> PoseGrid:
    return PoseGrid(
        np.arange(nx) * 0.1 + 0.05, np.arange(ny) * 0.1 + 0.05, np.array([0.5, 0.6]), np.arange(8) * np.pi / 4
    )


def _fields_message():
    cloud = messages.cloud_message(np.zeros((100, 3)), _rigid(9), "x", frames=1)
    message = messages.SceneFieldsMessage()
    messages._carry_source(message, cloud.world_from_input, cloud, None)
    return message


def test_a_map_from_random_scores_round_trips():
    grid = _small_grid()
    scores = np.random.default_rng(10).normal(size=grid.shape)
    amap = build_map(
        "sitting-working", scores, grid, get_skeleton("sitting-working"), threshold=1.5, place_threshold=2.0
    )
    fields = _fields_message()
    message = _wire(messages.map_message(amap, "m-1", fields))
    _assert_documents_match(
        messages.map_document_of(message), amap.to_json("m-1", messages.pose_matrix(fields.world_from_input))
    )
    np.testing.assert_array_equal(
        messages.map_arrays(message)["confidence"], amap.confidence.astype(np.float32)
    )


def test_an_empty_map_round_trips():
    """Nothing above the threshold is a common map; a receiver (afford watch) must still read it."""
    grid = _small_grid()
    amap = build_map(
        "standing-working", np.full(grid.shape, -1.0), grid, get_skeleton("standing-working"), threshold=0.0
    )
    message = _wire(messages.map_message(amap, "m-2", _fields_message()))
    arrays = messages.map_arrays(message)
    assert arrays["skeletons"].shape == (0, 5) and arrays["positives"].shape == (0, 5)
    document = messages.map_document_of(message)
    assert document["skeletons"] == [] and document["positives"] == []


def test_a_single_position_map_keeps_its_position():
    grid = PoseGrid([0.35], [0.45], [0.5], np.arange(4) * 0.5)
    amap = build_map(
        "sitting-working", np.ones(grid.shape), grid, get_skeleton("sitting-working"), threshold=0.0
    )
    message = _wire(messages.map_message(amap, "m-3", _fields_message()))
    back = messages.map_grid(message)
    np.testing.assert_allclose(back.x, [0.35])
    np.testing.assert_allclose(back.y, [0.45])


def _map_message():
    grid = _small_grid()
    scores = np.random.default_rng(11).normal(size=grid.shape)
    amap = build_map("sitting-working", scores, grid, get_skeleton("sitting-working"), threshold=1.0)
    return messages.map_message(amap, "m", _fields_message())


def _truncate_joints(message):
    del message.skeletons[0].joints[-1]


def _drop_a_joint(message):
    del message.skeletons[0].joints[-3:]  # whole triples, but 14 joints


@pytest.mark.parametrize(
    ("spoil", "reason"),
    [
        (
            lambda m: setattr(m, "confidence", m.confidence[:-4]),
            r"confidence holds 796 bytes; a 20 x 10 grid needs 800",
        ),
        (lambda m: setattr(m.grid, "ny", 11), r"confidence holds 800 bytes; a 20 x 11 grid needs 880"),
        (
            lambda m: setattr(m, "positives", m.positives + b"\x00" * 4),
            r"positives hold \d+ bytes, not a whole number of 5-float rows",
        ),
        (_truncate_joints, r"a skeleton's joints are not 15 \(x, y, z\) triples"),
        (_drop_a_joint, r"a skeleton's joints are not 15 \(x, y, z\) triples"),
    ],
    ids=["confidence short", "grid bigger", "positives ragged", "joints ragged", "joint missing"],
)
def test_unusable_maps_are_refused(spoil, reason):
    message = _map_message()
    spoil(message)
    with pytest.raises(MessageError, match=reason):
        messages.map_document_of(_wire(message))


@pytest.mark.parametrize("seconds, nanos", [(5, 2147483647), (5, -5), (-3, 0), (10**11, 999_999_999)])
def test_any_timestamp_compares_as_exact_nanoseconds_without_raising(seconds, nanos):
    stamp = messages.Error().timestamp
    stamp.seconds, stamp.nanos = seconds, nanos  # what a hostile message may hold
    assert messages.nanoseconds(stamp) == seconds * 1_000_000_000 + nanos
