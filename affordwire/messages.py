"""Between numpy and the wire: the afford.v1 Protocol Buffers (schemas/afford/v1) and the arrays the library
works on. No transport here; the services move the bytes. The protobuf classes are named here as on the wire
(Scan, DepthFrame, Pose, Status, Error), with a `Message` suffix where the library has a class of the same
name (CloudMessage, SceneFieldsMessage, AffordanceMapMessage).

Every decoder checks what it is given and raises `MessageError` with a reason a person can act on (the
services answer it on their error key and keep running).
"""

from __future__ import annotations

import time

import numpy as np

from affordcore.assembly.depth import DepthImage
from affordcore.geometry.skeleton import JOINTS
from affordcore.settings import NORMAL_ESTIMATORS, STEEP_FACINGS, LimitSettings

from .proto import geometry_pb2, maps_pb2, sensing_pb2, service_pb2

Scan = sensing_pb2.Scan
DepthFrame = sensing_pb2.DepthFrame
CloudMessage = maps_pb2.Cloud
SceneFieldsMessage = maps_pb2.SceneFields
AffordanceMapMessage = maps_pb2.AffordanceMap
NextViewsMessage = maps_pb2.NextViews
Pose = geometry_pb2.Pose
Status = service_pb2.Status
Error = service_pb2.Error
Reset = service_pb2.Reset

WORLD = "world"
_Field = geometry_pb2.PackedElementField
_NUMPY_TYPES = {
    _Field.UINT8: "u1",
    _Field.INT8: "i1",
    _Field.UINT16: "<u2",
    _Field.INT16: "<i2",
    _Field.UINT32: "<u4",
    _Field.INT32: "<i4",
    _Field.FLOAT32: "<f4",
    _Field.FLOAT64: "<f8",
}


# every message class, by the schema name its encoding carries
MESSAGE_CLASSES = {
    cls.DESCRIPTOR.full_name: cls
    for cls in (
        Scan,
        DepthFrame,
        CloudMessage,
        Pose,
        SceneFieldsMessage,
        AffordanceMapMessage,
        NextViewsMessage,
        Status,
        Error,
        Reset,
    )
}


class MessageError(ValueError):
    """A message that cannot be used; the text says what is wrong with it."""


def schema_name(message_or_class) -> str:
    """The full protobuf name (afford.v1.Scan), carried as the schema of the zenoh encoding."""
    return message_or_class.DESCRIPTOR.full_name


def parse(message_class, payload: bytes):
    """Decode bytes as `message_class`, or raise `MessageError` naming the schema."""
    from google.protobuf.message import DecodeError

    message = message_class()
    try:
        message.ParseFromString(payload)
    except DecodeError as error:
        raise MessageError(
            f"payload of {len(payload)} bytes is not a valid {schema_name(message_class)}: {error}"
        ) from None
    return message


# -- time and poses ------------------------------------------------------------------------------------------


def stamp(message_timestamp, seconds: float | None = None) -> None:
    """Set a google.protobuf.Timestamp to `seconds` since the epoch (now by default)."""
    message_timestamp.FromNanoseconds(int(round((time.time() if seconds is None else seconds) * 1e9)))


def seconds(message_timestamp) -> float:
    return message_timestamp.ToNanoseconds() * 1e-9


def nanoseconds(message_timestamp) -> int:
    """A Timestamp as an exact integer, whatever it holds: protobuf's ToNanoseconds raises on nanos outside
    0 ... 1e9 (a hostile message's), and a comparison of stamps must never take a service down."""
    return message_timestamp.seconds * 1_000_000_000 + message_timestamp.nanos


def checked_seconds(message_timestamp, limits: LimitSettings, what: str = "timestamp") -> float:
    """Seconds since the epoch of a Timestamp, refused outside 0 (unset) ... `limits.latest_timestamp`: a
    time beyond it overflows the recordings' nanosecond clock and every later frame's ordering."""
    value = message_timestamp.seconds + message_timestamp.nanos * 1e-9
    if not 0 <= value <= limits.latest_timestamp or not 0 <= message_timestamp.nanos < 1_000_000_000:
        raise MessageError(
            f"{what} {value:.6g} s (nanos {message_timestamp.nanos}) is outside 0 ... "
            f"{limits.latest_timestamp:.0f} s since the epoch (AFFORD_LIMITS__LATEST_TIMESTAMP)"
        )
    return value


def set_pose(pose, matrix: np.ndarray, frame_id: str, child_frame_id: str, at: float | None = None) -> None:
    """Fill a Pose from a 4 x 4 rigid transform (parent_from_child)."""
    from scipy.spatial.transform import Rotation

    matrix = np.asarray(matrix, dtype=np.float64)
    stamp(pose.timestamp, at)
    pose.frame_id, pose.child_frame_id = frame_id, child_frame_id
    pose.position.x, pose.position.y, pose.position.z = (float(v) for v in matrix[:3, 3])
    x, y, z, w = Rotation.from_matrix(matrix[:3, :3]).as_quat()
    pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = (
        float(x),
        float(y),
        float(z),
        float(w),
    )


def pose_matrix(pose) -> np.ndarray:
    """The 4 x 4 transform of a Pose; an unset Pose is the identity."""
    from scipy.spatial.transform import Rotation

    q = pose.orientation
    quaternion = np.array([q.x, q.y, q.z, q.w])
    matrix = np.eye(4)
    if not np.any(quaternion):
        quaternion = np.array([0.0, 0.0, 0.0, 1.0])
    norm = np.linalg.norm(quaternion)
    if not np.isfinite(norm) or abs(norm - 1) > 1e-3:
        raise MessageError(f"pose orientation is not a unit quaternion (norm {norm:.4g})")
    matrix[:3, :3] = Rotation.from_quat(quaternion / norm).as_matrix()
    matrix[:3, 3] = pose.position.x, pose.position.y, pose.position.z
    if not np.isfinite(matrix).all():
        raise MessageError("pose position is not finite")
    return matrix


def set_vector(vector, values) -> None:
    vector.x, vector.y, vector.z = (float(v) for v in values)


def gravity_of(message) -> np.ndarray | None:
    """The unit gravity direction a Scan or DepthFrame carries, or None."""
    if not message.HasField("gravity"):
        return None
    g = np.array([message.gravity.x, message.gravity.y, message.gravity.z])
    norm = np.linalg.norm(g)
    if not np.isfinite(norm) or norm < 1e-6:
        raise MessageError(f"gravity {g.tolist()} is not a direction")
    return g / norm


# -- packed points -------------------------------------------------------------------------------------------


def pack_points(message, points: np.ndarray, times: np.ndarray | None = None) -> None:
    """Fill the fields/point_stride/data of a Scan or Cloud with float32 x, y, z (and t)."""
    columns = [np.asarray(points, dtype="<f4")]
    names = ["x", "y", "z"]
    if times is not None:
        columns.append(np.asarray(times, dtype="<f4").reshape(-1, 1))
        names.append("t")
    del message.fields[:]
    for index, name in enumerate(names):
        message.fields.add(name=name, offset=4 * index, type=_Field.FLOAT32)
    message.point_stride = 4 * len(names)
    message.data = np.ascontiguousarray(np.hstack(columns), dtype="<f4").tobytes()


def unpack_points(message, max_points: int | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """(points (N, 3) float64, per-point times t or None) of a Scan or Cloud, at most `max_points` of them;
    points with a non-finite coordinate are dropped (organised clouds mark missing returns with NaN)."""
    fields = {field.name: field for field in message.fields}
    missing = [name for name in "xyz" if name not in fields]
    if missing:
        raise MessageError(
            f"points need fields x, y, z; missing {', '.join(missing)} (has {', '.join(fields) or 'none'})"
        )
    stride = message.point_stride
    if stride == 0:
        raise MessageError("point_stride is 0")
    if len(message.data) % stride:
        raise MessageError(f"data is {len(message.data)} bytes, not a whole number of {stride}-byte points")
    if max_points is not None and len(message.data) // stride > max_points:
        raise MessageError(
            f"{len(message.data) // stride:,} points; at most {max_points:,} are taken "
            "(AFFORD_LIMITS__MAX_POINTS)"
        )
    dtype = {}
    for name in ("x", "y", "z", "t"):
        if name not in fields:
            continue
        field = fields[name]
        if field.type not in _NUMPY_TYPES:
            raise MessageError(f"field {name} has no numeric type")
        numpy_type = np.dtype(_NUMPY_TYPES[field.type])
        if field.offset + numpy_type.itemsize > stride:
            raise MessageError(
                f"field {name} (offset {field.offset}, {numpy_type.itemsize} bytes) runs past the "
                f"{stride}-byte point"
            )
        dtype[name] = (numpy_type, field.offset)
    records = np.frombuffer(
        message.data,
        dtype=np.dtype(
            {
                "names": list(dtype),
                "formats": [t for t, _ in dtype.values()],
                "offsets": [o for _, o in dtype.values()],
                "itemsize": stride,
            }
        ),
    )
    points = (
        np.column_stack([records[name].astype(np.float64) for name in "xyz"])
        if len(records)
        else np.empty((0, 3))
    )
    finite = finite_rows(points)
    times = records["t"].astype(np.float64)[finite] if "t" in dtype else None
    return points[finite], times


def finite_rows(points: np.ndarray) -> np.ndarray:
    """Which rows of (N, 3) points have three finite coordinates: column by column, since numpy's
    `isfinite(points).all(axis=1)` reduces along the short axis about 70x slower (18 ms for a 275k-point
    cloud, a sixth of a frame's budget at 8 Hz)."""
    return np.isfinite(points[:, 0]) & np.isfinite(points[:, 1]) & np.isfinite(points[:, 2])


# -- depth frames --------------------------------------------------------------------------------------------


def depth_frame_message(
    depth: np.ndarray,
    intrinsics: np.ndarray,
    depth_scale: float = 0.001,
    frame_id: str = "camera",
    invalid_value: int = 65535,
    at: float | None = None,
) -> DepthFrame:
    """A DepthFrame from a 16-bit depth image and a 3 x 3 pinhole matrix."""
    depth = np.asarray(depth)
    if depth.ndim != 2 or depth.dtype != np.uint16:
        raise MessageError(f"a depth image must be 2-D uint16, got {depth.dtype} of shape {depth.shape}")
    message = DepthFrame(
        frame_id=frame_id,
        width=depth.shape[1],
        height=depth.shape[0],
        depth=depth.astype("<u2").tobytes(),
        depth_scale=depth_scale,
        invalid_value=invalid_value,
    )
    message.intrinsics.fx, message.intrinsics.fy = float(intrinsics[0, 0]), float(intrinsics[1, 1])
    message.intrinsics.cx, message.intrinsics.cy = float(intrinsics[0, 2]), float(intrinsics[1, 2])
    stamp(message.timestamp, at)
    return message


def depth_image(message: DepthFrame, limits: LimitSettings | None = None) -> DepthImage:
    """The depth image a DepthFrame carries, checked (affordcore.assembly.depth.back_project turns it into
    points)."""
    limits = limits or LimitSettings()
    width, height = message.width, message.height
    if width == 0 or height == 0:
        raise MessageError(f"depth image is {width} x {height}")
    if width * height > limits.max_depth_pixels:
        raise MessageError(
            f"depth image is {width} x {height}; at most {limits.max_depth_pixels:,} pixels are taken "
            "(AFFORD_LIMITS__MAX_DEPTH_PIXELS)"
        )
    if len(message.depth) != 2 * width * height:
        raise MessageError(
            f"depth holds {len(message.depth)} bytes; a {width} x {height} 16-bit image needs "
            f"{2 * width * height}"
        )
    k = message.intrinsics
    if not (k.fx > 0 and k.fy > 0) or not np.isfinite([k.fx, k.fy, k.cx, k.cy]).all():
        raise MessageError(f"intrinsics fx={k.fx}, fy={k.fy} must be positive focal lengths in pixels")
    if not 0 < message.depth_scale < 1:
        raise MessageError(f"depth_scale must be positive metres per unit below 1, got {message.depth_scale}")
    intrinsics = np.array([[k.fx, 0, k.cx], [0, k.fy, k.cy], [0, 0, 1.0]])
    pixels = np.frombuffer(message.depth, dtype="<u2").reshape(height, width)
    return DepthImage(pixels, intrinsics, message.depth_scale, message.invalid_value)


# -- clouds, fields, maps ------------------------------------------------------------------------------------


def cloud_message(
    points: np.ndarray,
    world_from_input: np.ndarray,
    source: str,
    frames: int = 0,
    at: float | None = None,
    scans_received: int = 0,
    origins: np.ndarray | None = None,
) -> CloudMessage:
    """A map Cloud of `points`; `frames` scans fused into it out of the `scans_received` the assembler had
    received (the rest skipped to keep up or refused); `origins`: where the sensor stood, in the points'
    frame (None: not known)."""
    message = CloudMessage(frame_id=WORLD, frames=frames, source=source, scans_received=scans_received)
    pack_points(message, points)
    for origin in [] if origins is None else origins:
        set_vector(message.sensor_origins.add(), origin)
    set_pose(message.world_from_input, world_from_input, WORLD, "input", at)
    stamp(message.timestamp, at)
    return message


def cloud_points(message: CloudMessage, limits: LimitSettings | None = None) -> np.ndarray:
    """The points of a map Cloud in its own frame (`is_levelled` says whether that is the world frame),
    checked against `limits`: fewer than 100 points, or wider than `limits.max_extent`, is refused."""
    limits = limits or LimitSettings()
    checked_seconds(message.timestamp, limits)
    pose_matrix(message.world_from_input)
    points, _ = unpack_points(message, limits.max_points)
    if len(points) < 100:
        raise MessageError(f"the map has {len(points)} finite points; at least 100 are needed")
    extent = points.max(axis=0) - points.min(axis=0)
    if (extent > limits.max_extent).any():
        raise MessageError(
            f"the map spans {' x '.join(f'{v:.4g}' for v in extent)} m; at most {limits.max_extent:g} m "
            "along each axis is taken (AFFORD_LIMITS__MAX_EXTENT)"
        )
    return points


def cloud_origins(message: CloudMessage, limits: LimitSettings | None = None) -> np.ndarray | None:
    """The sensor positions a map Cloud carries ((M, 3) in its frame; None when it carries none), checked:
    at most `limits.max_sensor_origins`, finite, within `limits.max_extent` of the frame's origin."""
    limits = limits or LimitSettings()
    count = len(message.sensor_origins)
    if count == 0:
        return None
    if count > limits.max_sensor_origins:
        raise MessageError(
            f"the map carries {count:,} sensor positions; at most {limits.max_sensor_origins:,} are taken "
            "(AFFORD_LIMITS__MAX_SENSOR_ORIGINS)"
        )
    origins = np.array([(v.x, v.y, v.z) for v in message.sensor_origins], dtype=np.float64)
    if not np.isfinite(origins).all() or (np.abs(origins) > limits.max_extent).any():
        raise MessageError("sensor positions are not finite or beyond AFFORD_LIMITS__MAX_EXTENT")
    return origins


def is_levelled(message: CloudMessage) -> bool:
    """A Cloud in the world frame is levelled (z up, floor at 0) by its sender; any other is levelled by the
    features service."""
    return message.frame_id == WORLD


def fields_message(
    fields, cloud: CloudMessage, world_from_input: np.ndarray | None = None, at: float | None = None
) -> SceneFieldsMessage:
    """SceneFields of the map `cloud` (whose time and frame count it carries on), with `world_from_input`
    (default: the cloud's own, for a cloud that came levelled)."""
    lattice = fields.lattice
    message = SceneFieldsMessage(
        frame_id=WORLD,
        occupancy=(fields.occupancy > 0).astype(np.uint8).tobytes(),
        distance=np.ascontiguousarray(fields.distance, dtype="<f4").tobytes(),
        normals=np.ascontiguousarray(fields.normals, dtype="<f4").tobytes(),
        steep_facing=fields.steep_facing,
        normal_estimator=fields.normal_estimator,
    )
    if fields.visibility is not None:
        message.visibility = np.ascontiguousarray(fields.visibility, dtype=np.uint8).tobytes()
    if fields.soft_occupancy is not None:
        message.soft_occupancy = np.ascontiguousarray(fields.soft_occupancy, dtype="<f4").tobytes()
    if fields.columns is not None:
        _set_columns(message.columns, fields.columns)
    message.grid.origin.x, message.grid.origin.y, message.grid.origin.z = (float(v) for v in lattice.origin)
    message.grid.resolution = lattice.resolution
    message.grid.nx, message.grid.ny, message.grid.nz = lattice.shape
    message.x_min, message.y_min, message.x_max, message.y_max = fields.footprint
    pose = cloud.world_from_input
    if world_from_input is not None:
        pose = Pose()
        set_pose(pose, world_from_input, WORLD, "input", seconds(cloud.timestamp))
    _carry_source(message, pose, cloud, at)
    return message


def scene_fields(
    message: SceneFieldsMessage, limits: LimitSettings | None = None, max_voxels: int | None = None
):
    """The `SceneFields` a message carries (arrays are read-only views of the payload), checked: at most
    `max_voxels`, finite, and consistent with its grid."""
    from affordcore.geometry.fields import SceneFields, VoxelLattice

    limits = limits or LimitSettings()
    grid = message.grid
    shape = (grid.nx, grid.ny, grid.nz)
    n = int(np.prod(shape, dtype=object))  # exact: three uint32 can overflow int64
    if n == 0 or not grid.resolution > 0 or not np.isfinite(grid.resolution):
        raise MessageError(f"voxel grid {shape} at resolution {grid.resolution} is empty")
    if max_voxels is not None and n > max_voxels:
        raise MessageError(
            f"voxel grid {shape} has {n:,} voxels; at most {max_voxels:,} are taken "
            "(AFFORD_VOXEL__MAX_VOXELS)"
        )
    origin = np.array([grid.origin.x, grid.origin.y, grid.origin.z])
    if not np.isfinite(origin).all() or (np.abs(origin) > limits.max_extent).any():
        raise MessageError(f"grid origin {origin.tolist()} is not finite or beyond AFFORD_LIMITS__MAX_EXTENT")
    checked_seconds(message.timestamp, limits)
    checked_seconds(message.cloud_timestamp, limits, "cloud_timestamp")
    pose_matrix(message.world_from_input)
    for name, itemsize in (("occupancy", 1), ("distance", 4), ("normals", 12)):
        if len(getattr(message, name)) != n * itemsize:
            raise MessageError(
                f"{name} holds {len(getattr(message, name))} bytes; a {shape} grid needs {n * itemsize}"
            )
    lattice = VoxelLattice(origin, grid.resolution, shape)
    occupancy = np.frombuffer(message.occupancy, dtype=np.uint8).reshape(shape)
    distance = np.frombuffer(message.distance, dtype="<f4").reshape(shape)
    normals = np.frombuffer(message.normals, dtype="<f4").reshape(*shape, 3)
    if occupancy.max() > 1:
        raise MessageError("occupancy holds values other than 0 and 1")
    if not (np.isfinite(distance).all() and distance.min() >= 0):
        raise MessageError("distance holds NaN, infinite or negative values")
    lengths = np.einsum("...i,...i->...", normals, normals)  # NaN propagates: one check for both
    if not (lengths <= 1.0 + 1e-3).all():
        raise MessageError("normals hold NaN, infinite or longer-than-unit vectors")
    footprint = (message.x_min, message.y_min, message.x_max, message.y_max)
    if not (np.isfinite(footprint).all() and footprint[2] >= footprint[0] and footprint[3] >= footprint[1]):
        raise MessageError(f"empty floor footprint {footprint}")
    # the floor lies inside the fields computed around it: a footprint beyond them would only grow the pose
    # grid (the work of every affordance) over space the fields know nothing of
    low, high = origin[:2] - grid.resolution, origin[:2] + grid.resolution * (np.array(shape[:2]) + 1)
    if footprint[0] < low[0] or footprint[1] < low[1] or footprint[2] > high[0] or footprint[3] > high[1]:
        raise MessageError(
            f"floor footprint {tuple(round(v, 3) for v in footprint)} reaches beyond the voxel grid "
            f"({low[0] + grid.resolution:.3f}, {low[1] + grid.resolution:.3f}) ... "
            f"({high[0] - grid.resolution:.3f}, {high[1] - grid.resolution:.3f})"
        )
    facing = message.steep_facing or "centre"
    if facing not in STEEP_FACINGS:
        raise MessageError(f"steep_facing {message.steep_facing[:40]!r} is not one of {list(STEEP_FACINGS)}")
    estimator = message.normal_estimator or "nearest"
    if estimator not in NORMAL_ESTIMATORS:
        raise MessageError(
            f"normal_estimator {message.normal_estimator[:40]!r} is not one of {list(NORMAL_ESTIMATORS)}"
        )
    visibility = _visibility(message, occupancy)
    occupancy = occupancy.astype(np.float32)
    soft = _soft_occupancy(message, shape)
    columns = _columns(message, lattice)
    return SceneFields(
        lattice, occupancy, distance, normals, footprint, facing, visibility, soft, estimator, columns
    )


def _set_columns(out, columns) -> None:
    out.x0, out.y0 = (float(v) for v in columns.origin)
    out.resolution = columns.resolution
    out.nx, out.ny = columns.low.shape
    out.low = np.ascontiguousarray(columns.low, dtype="<f4").tobytes()
    out.high = np.ascontiguousarray(columns.high, dtype="<f4").tobytes()


# how far past the voxel grid's plan the fine columns may reach (they are made 1 m round the cloud)
_COLUMNS_REACH = 1.5


def _columns(message: SceneFieldsMessage, lattice):
    """The fine columns a SceneFields carries (None when it carries none), checked: at the resolution the
    models read, within reach of the voxel grid (which bounds their number), each height in the band or
    the empty column's."""
    from affordcore.geometry import columns as fine

    if not message.HasField("columns"):
        return None
    c = message.columns
    if not abs(c.resolution - fine.RESOLUTION) <= 1e-9:  # NaN fails too
        raise MessageError(f"columns at {c.resolution} m; the models read {fine.RESOLUTION} m columns")
    origin = np.array([c.x0, c.y0])
    end = origin + np.array([c.nx, c.ny]) * c.resolution
    low_bound, high_bound = lattice.origin[:2] - _COLUMNS_REACH, lattice.upper[:2] + _COLUMNS_REACH
    if not (np.isfinite(origin).all() and (origin >= low_bound).all() and (end <= high_bound).all()):
        raise MessageError(
            f"columns from {origin.round(3).tolist()} to {end.round(3).tolist()} reach more than "
            f"{_COLUMNS_REACH} m beyond the voxel grid"
        )
    if c.nx == 0 or c.ny == 0:
        raise MessageError("columns are empty (nx or ny is 0)")
    n = c.nx * c.ny
    for name in ("low", "high"):
        if len(getattr(c, name)) != 4 * n:
            size = len(getattr(c, name))
            raise MessageError(f"columns.{name} holds {size} bytes; {c.nx} x {c.ny} columns need {4 * n}")
    low = np.frombuffer(c.low, dtype="<f4").reshape(c.nx, c.ny)
    high = np.frombuffer(c.high, dtype="<f4").reshape(c.nx, c.ny)
    band = np.float32(fine.BAND[0]) - 1e-6, np.float32(fine.BAND[1]) + 1e-6
    if not (((low >= band[0]) & (low <= band[1])) | (low == fine.EMPTY_LOW)).all():
        raise MessageError(f"columns.low holds heights outside {fine.BAND} m that are not {fine.EMPTY_LOW}")
    if not (((high >= band[0]) & (high <= band[1])) | (high == 0)).all():
        raise MessageError(f"columns.high holds heights outside {fine.BAND} m that are not 0")
    return fine.FineColumns(origin, c.resolution, low, high)


def _soft_occupancy(message: SceneFieldsMessage, shape: tuple[int, int, int]) -> np.ndarray | None:
    """The soft occupancy a SceneFields carries (None for binary fields), checked: one float32 per voxel,
    each in [0, 1]."""
    if not message.soft_occupancy:
        return None
    n = int(np.prod(shape))
    if len(message.soft_occupancy) != 4 * n:
        raise MessageError(
            f"soft_occupancy holds {len(message.soft_occupancy)} bytes; a {shape} grid needs {4 * n}"
        )
    soft = np.frombuffer(message.soft_occupancy, dtype="<f4").reshape(shape)
    if not ((soft >= 0) & (soft <= 1)).all():  # NaN fails both
        raise MessageError("soft_occupancy holds values outside [0, 1] (or NaN)")
    return soft


def _visibility(message: SceneFieldsMessage, occupancy: np.ndarray) -> np.ndarray | None:
    """The voxel states a SceneFields carries (None when it carries none), checked: one per voxel, each
    unknown, free or occupied, and occupied exactly where the occupancy is."""
    from affordcore.geometry.visibility import OCCUPIED

    if not message.visibility:
        return None
    if len(message.visibility) != occupancy.size:
        raise MessageError(
            f"visibility holds {len(message.visibility)} bytes; a {occupancy.shape} grid needs "
            f"{occupancy.size}"
        )
    states = np.frombuffer(message.visibility, dtype=np.uint8).reshape(occupancy.shape)
    if states.max() > OCCUPIED:
        raise MessageError("visibility holds values other than 0 (unknown), 1 (free) and 2 (occupied)")
    if not np.array_equal(states == OCCUPIED, occupancy == 1):
        raise MessageError("visibility says occupied where the occupancy does not (or the other way)")
    return states


def map_message(
    amap, model_id: str, fields: SceneFieldsMessage, at: float | None = None
) -> AffordanceMapMessage:
    """An AffordanceMap message of a map computed from `fields` (whose frame, cloud time and count it carries
    on)."""
    grid = amap.grid.as_dict()
    message = AffordanceMapMessage(
        frame_id=WORLD,
        affordance=amap.affordance,
        model=model_id,
        threshold=amap.threshold,
        place_threshold=amap.place_threshold,
        place_probability=_finite_or_none(amap.place_probability),
        positives=np.ascontiguousarray(amap.positives, dtype="<f4").tobytes(),
        confidence=np.ascontiguousarray(amap.confidence, dtype="<f4").tobytes(),
    )
    spec = message.grid
    spec.x0, spec.y0, spec.step, spec.nx, spec.ny = (
        grid["x0"],
        grid["y0"],
        grid["step"],
        grid["nx"],
        grid["ny"],
    )
    spec.z.extend(grid["z"])
    spec.theta_step, spec.n_theta = grid["theta_step"], grid["n_theta"]
    for row, joints, probability in zip(amap.skeletons, amap.joints, amap.probabilities):
        message.skeletons.add(
            x=row[0],
            y=row[1],
            z=row[2],
            theta=row[3],
            score=row[4],
            joints=np.ravel(joints).tolist(),
            probability=_finite_or_none(probability),
        )
    _carry_source(message, fields.world_from_input, fields, at)
    return message


def next_views_message(
    views, camera, fields: SceneFieldsMessage, at: float | None = None
) -> NextViewsMessage:
    """A NextViews message of the views (`next_views.NextView`, best first) suggested for the maps of
    `fields`, for the camera of `camera` (NextViewSettings)."""
    message = NextViewsMessage(frame_id=WORLD)
    for view in views:
        out = message.views.add(heading=view.heading, gain=view.gain)
        set_pose(out.pose, view.pose(), WORLD, "next_view", at)
        for (x, y, probability), affordance in zip(view.looks_at, view.affordances):
            out.places.add(affordance=affordance, x=x, y=y, probability=probability)
    c = message.camera
    c.fov_horizontal, c.fov_vertical = np.radians([camera.fov_horizontal_deg, camera.fov_vertical_deg])
    c.pitch, c.min_range, c.max_range = np.radians(camera.pitch_deg), camera.min_range, camera.max_range
    _carry_source(message, fields.world_from_input, fields, at)
    return message


def _finite_or_none(value: float) -> float | None:
    """A NaN is left unset on the wire: an optional field says "none" by its absence."""
    return float(value) if np.isfinite(value) else None


def _carry_source(message, world_from_input, source, at: float | None) -> None:
    """What fields and maps say of the Cloud they answer, from that Cloud or from the fields that carry it."""
    message.world_from_input.CopyFrom(world_from_input)
    message.cloud_timestamp.CopyFrom(
        source.timestamp if isinstance(source, CloudMessage) else source.cloud_timestamp
    )
    message.frames, message.scans_received = source.frames, source.scans_received
    stamp(message.timestamp, at)


def map_grid(message: AffordanceMapMessage):
    """The PoseGrid a map message was scored on."""
    from affordcore.geometry.grid import PoseGrid

    spec = message.grid
    step = spec.step if np.isfinite(spec.step) else 0.0  # a single position has no step
    x = spec.x0 + step * np.arange(spec.nx)
    y = spec.y0 + step * np.arange(spec.ny)
    return PoseGrid(x, y, np.array(spec.z), spec.theta_step * np.arange(spec.n_theta))


def map_arrays(message: AffordanceMapMessage) -> dict[str, np.ndarray]:
    """skeletons (k, 5), joints (k, 15, 3), probabilities (k,), positives (n, 5) and confidence (nx, ny) of a
    map message."""
    spec = message.grid
    if len(message.confidence) != 4 * spec.nx * spec.ny:
        raise MessageError(
            f"confidence holds {len(message.confidence)} bytes; a {spec.nx} x {spec.ny} grid needs "
            f"{4 * spec.nx * spec.ny}"
        )
    if len(message.positives) % 20:
        raise MessageError(
            f"positives hold {len(message.positives)} bytes, not a whole number of 5-float rows"
        )
    rows = [(s.x, s.y, s.z, s.theta, s.score) for s in message.skeletons]
    joints = [np.array(s.joints, dtype=np.float64) for s in message.skeletons]
    if any(j.size != 3 * len(JOINTS) for j in joints):
        raise MessageError(f"a skeleton's joints are not {len(JOINTS)} (x, y, z) triples")
    return {
        "skeletons": np.array(rows, dtype=np.float64).reshape(-1, 5),
        "joints": np.array(joints).reshape(len(rows), len(JOINTS), 3),
        "probabilities": np.array(
            [s.probability if s.HasField("probability") else np.nan for s in message.skeletons], np.float64
        ),
        "positives": np.frombuffer(message.positives, dtype="<f4").reshape(-1, 5).astype(np.float64),
        "confidence": np.frombuffer(message.confidence, dtype="<f4").reshape(spec.nx, spec.ny),
    }


def map_document_of(message: AffordanceMapMessage) -> dict:
    """The affordance-map/1 JSON document of a map message: what `afford map` writes for the same map."""
    from affordcore.mapping.maps import map_document

    arrays = map_arrays(message)
    return map_document(
        message.affordance,
        message.model,
        message.threshold,
        map_grid(message).as_dict(),
        arrays["skeletons"],
        arrays["joints"],
        arrays["positives"],
        pose_matrix(message.world_from_input),
        message.place_threshold,
        arrays["probabilities"],
        message.place_probability if message.HasField("place_probability") else np.nan,
    )
