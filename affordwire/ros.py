"""ROS 2 sensor messages to arrays: `sensor_msgs/msg/PointCloud2` to points, `sensor_msgs/msg/Imu` to the
direction of gravity, `nav_msgs/msg/Odometry` to the robot's pose by its own odometry. Bytes in, numpy out,
no transport: the assembler's ROS 2 subscriptions (services/ros.py) and `afford publish`'s bag reader both
decode here.

The payload is what a ROS 2 publisher puts on the wire: CDR with its 4-byte encapsulation header (rmw_zenoh
and zenoh-plugin-ros2dds both forward it as is). It is parsed by `rosbags` (the `[ros]` extra, imported only
here and only when a ROS message arrives, so the core installs without it). Every message is hostile until
checked: anything unusable raises `MessageError` with the reason, before an array is allocated for it.

Conventions (docs/ros.md):

* PointCloud2: any `PointField` datatype (INT8 ... FLOAT64) for x, y and z, either byte order
  (`is_bigendian`), fields anywhere within `point_step`, rows padded to `row_step`; organised clouds mark
  missing returns with NaN, which are dropped and counted (`RosCloud.nonfinite`).
* Imu: `linear_acceleration` is the specific force (REP 145): at rest it points up, +9.81 m/s^2 along the
  up axis. Gravity, the down direction the assembler wants (`SensorFrame.gravity`), is therefore
  -a / |a|, in the IMU's frame.
* Odometry: `pose.pose` is the pose of `child_frame_id` (the robot's base) in `header.frame_id` (its
  odometry frame); the covariances and the twist are not used.
* TFMessage (`/tf`, `/tf_static`): each TransformStamped is the pose of `child_frame_id` in
  `header.frame_id`, its parent; a `TransformTree` keeps the newest of each child and chains them.
"""

from __future__ import annotations

import functools
import threading
from collections import deque
from dataclasses import dataclass

import numpy as np

from affordcore.assembly.assembler import thinning_step
from affordcore.settings import LimitSettings

from .messages import MessageError, finite_rows

POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
IMU = "sensor_msgs/msg/Imu"
ODOMETRY = "nav_msgs/msg/Odometry"
TFMESSAGE = "tf2_msgs/msg/TFMessage"
INSTALL = "pip install 'affordmap[ros]'"

# sensor_msgs/msg/PointField datatypes (INT8 = 1 ... FLOAT64 = 8) as numpy kinds; the byte order is the
# message's
POINT_FIELD_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
STANDARD_GRAVITY = 9.80665
# an Imu or Odometry message is a few hundred bytes; a larger one is refused before it is parsed on the
# network thread
MAX_IMU_BYTES = 64 * 1024
MAX_FRAME_ID = 1024  # characters of a header's frame_id (it goes into logs and the pose messages)
# a TFMessage of a robot's whole tree is a few kilobytes (about 100 bytes a transform); more is refused
# unparsed, and a tree keeps at most this many frames
MAX_TF_BYTES = 256 * 1024
MAX_TF_FRAMES = 4096


class RosUnavailable(ImportError, ValueError):
    """The `rosbags` library is not installed. A ValueError too, so the command line reports it as one line
    (exit 2) instead of a traceback."""


@functools.cache
def typestore():
    """rosbags' type store of ROS 2 messages. sensor_msgs' PointCloud2 and Imu have had one definition (and
    so one CDR layout) from Humble to the latest distribution, so one store reads every robot's."""
    try:
        from rosbags.typesys import Stores, get_typestore
    except ImportError as error:
        raise RosUnavailable(
            f"ROS 2 messages (PointCloud2, Imu, rosbag2, MCAP) need the rosbags library: {INSTALL} ({error})"
        ) from None
    return get_typestore(Stores.ROS2_JAZZY)


def deserialize(payload: bytes, typename: str):
    """The message of ROS type `typename` in CDR bytes, or `MessageError` saying why not."""
    store = typestore()
    if len(payload) < 4:
        raise MessageError(f"a CDR {typename} needs at least its 4-byte header; got {len(payload)} bytes")
    try:
        return store.deserialize_cdr(payload, typename)
    except Exception as error:  # SerdeError mostly; whatever a malformed payload provokes in the parser
        raise MessageError(
            f"payload of {len(payload):,} bytes is not a CDR {typename}: {type(error).__name__}: {error}"
        ) from None


def serialize(message, typename: str) -> bytes:
    """CDR bytes (little-endian, with the encapsulation header) of a rosbags message object."""
    return bytes(typestore().serialize_cdr(message, typename))


def _header(message, limits: LimitSettings, what: str) -> tuple[float, str]:
    """(seconds, frame_id) of a std_msgs/Header, checked as every timestamp is (0 ... latest_timestamp)."""
    stamp = message.header.stamp
    seconds = stamp.sec + stamp.nanosec * 1e-9
    if not (0 <= stamp.nanosec < 1_000_000_000 and 0 <= seconds <= limits.latest_timestamp):
        raise MessageError(
            f"{what} header stamp {stamp.sec} s {stamp.nanosec} ns is outside 0 ... "
            f"{limits.latest_timestamp:.0f} s since the epoch (AFFORD_LIMITS__LATEST_TIMESTAMP)"
        )
    frame_id = message.header.frame_id
    if len(frame_id) > MAX_FRAME_ID:
        raise MessageError(f"{what} frame_id is {len(frame_id):,} characters; at most {MAX_FRAME_ID}")
    return seconds, frame_id


# -- PointCloud2 ---------------------------------------------------------------------------------------------


@dataclass
class RosCloud:
    """The points of one PointCloud2: finite (N, 3) float64 in the message's frame, and what was dropped."""

    points: np.ndarray
    stamp: float  # header stamp, seconds since the epoch
    frame_id: str
    nonfinite: int  # points read with a NaN or infinite coordinate (an organised cloud's missing returns)
    total: int  # width x height
    read: int = 0  # points read: total, or fewer when thinned (`keep`)


def pointcloud2(payload: bytes, limits: LimitSettings | None = None, keep: int | None = None) -> RosCloud:
    """The points of a CDR sensor_msgs/msg/PointCloud2 (`keep`: as `cloud_of`)."""
    return cloud_of(deserialize(payload, POINTCLOUD2), limits, keep)


def cloud_of(message, limits: LimitSettings | None = None, keep: int | None = None) -> RosCloud:
    """The points of a PointCloud2 message object (from `deserialize`, or a bag reader's). The layout is
    checked first (sizes, fields, strides against the data's length); then x, y and z are read in place
    through one strided structured view: no loop over points, no copy of the rest of each point.

    With `keep`, a cloud of more points is thinned to every n-th point in the message's order (n = the
    ceiling of points / keep) before anything is converted: what the assembler would keep of it
    (AFFORD_ASSEMBLER__MAX_FRAME_POINTS), at a third of a dense cloud's decoding cost. Non-finite points
    among those are dropped as ever (`nonfinite` counts the ones among the points read)."""
    limits = limits or LimitSettings()
    stamp, frame_id = _header(message, limits, "PointCloud2")
    height, width = int(message.height), int(message.width)
    point_step, row_step = int(message.point_step), int(message.row_step)
    total = height * width
    if total > limits.max_points:
        raise MessageError(
            f"PointCloud2 of {width:,} x {height:,} = {total:,} points; at most {limits.max_points:,} are "
            "taken (AFFORD_LIMITS__MAX_POINTS)"
        )
    data = message.data
    if total == 0:
        return RosCloud(np.empty((0, 3)), stamp, frame_id, 0, 0, 0)
    if point_step == 0:
        raise MessageError("PointCloud2 point_step is 0")
    if row_step < width * point_step:
        raise MessageError(
            f"PointCloud2 row_step {row_step} is less than width x point_step ({width} x {point_step})"
        )
    needed, whole = (height - 1) * row_step + width * point_step, height * row_step
    if not needed <= len(data) <= whole:
        raise MessageError(
            f"PointCloud2 data is {len(data):,} bytes; height x row_step ({height} x {row_step}) is {whole:,}"
        )
    order = ">" if message.is_bigendian else "<"
    fields = _xyz_fields(message.fields, point_step, order)
    view = np.ndarray(
        shape=(height, width),
        dtype=np.dtype(
            {
                "names": list(fields),
                "formats": [kind for kind, _ in fields.values()],
                "offsets": [offset for _, offset in fields.values()],
                "itemsize": point_step,
            }
        ),
        buffer=np.frombuffer(data, dtype=np.uint8),
        strides=(row_step, point_step),
    )
    columns = [view[name] for name in "xyz"]  # (height, width) strided views into the data
    if keep is not None and total > keep:
        # every n-th point, rows one after the other: the assembler's thinning of the whole cloud
        step = thinning_step(total, keep)
        if height == 1 or row_step == width * point_step:  # rows back to back: one strided view
            columns = [column.reshape(-1)[::step] for column in columns]
        else:
            rows, within = np.divmod(np.arange(0, total, step), width)
            columns = [column[rows, within] for column in columns]
    points = np.stack([column.astype(np.float64).ravel() for column in columns], axis=1)
    finite = finite_rows(points)
    nonfinite = int(len(points) - np.count_nonzero(finite))
    return RosCloud(points[finite] if nonfinite else points, stamp, frame_id, nonfinite, total, len(points))


def _xyz_fields(point_fields, point_step: int, order: str) -> dict[str, tuple[str, int]]:
    """x, y, z as (numpy type, offset), each checked to lie within the point."""
    named: dict[str, object] = {}
    for field in point_fields:
        if field.name in ("x", "y", "z") and field.name in named:
            raise MessageError(f"PointCloud2 has two fields named {field.name}")
        named.setdefault(field.name, field)
    missing = [name for name in "xyz" if name not in named]
    if missing:
        raise MessageError(
            f"PointCloud2 needs fields x, y, z; missing {', '.join(missing)} "
            f"(has {', '.join(repr(name) for name in named) or 'none'})"
        )
    layout = {}
    for name in "xyz":
        field = named[name]
        kind = POINT_FIELD_TYPES.get(int(field.datatype))
        if kind is None:
            raise MessageError(
                f"PointCloud2 field {name} has datatype {field.datatype}; PointField's are 1 (INT8) ... "
                "8 (FLOAT64)"
            )
        if field.count < 1:
            raise MessageError(f"PointCloud2 field {name} has count {field.count}; a coordinate needs 1")
        numpy_type = np.dtype(order + kind)
        if field.offset + numpy_type.itemsize > point_step:
            raise MessageError(
                f"PointCloud2 field {name} (offset {field.offset}, {numpy_type.itemsize} bytes) runs past "
                f"the {point_step}-byte point_step"
            )
        layout[name] = (numpy_type.str, int(field.offset))
    return layout


# -- Imu -----------------------------------------------------------------------------------------------------


@dataclass
class RosGravity:
    """One Imu reading's gravity: the unit down direction in the IMU's frame, at the header's time."""

    down: np.ndarray
    stamp: float
    frame_id: str


def imu(payload: bytes, limits: LimitSettings | None = None) -> RosGravity:
    """The gravity a CDR sensor_msgs/msg/Imu measures."""
    return gravity_of(_small(payload, IMU, "Imu"), limits)


def _small(payload: bytes, typename: str, what: str):
    """A message of a few hundred bytes (Imu, Odometry) deserialized; a larger one is refused unparsed."""
    if len(payload) > MAX_IMU_BYTES:
        raise MessageError(f"an {what} of {len(payload):,} bytes; at most {MAX_IMU_BYTES:,} are parsed")
    return deserialize(payload, typename)


def gravity_of(message, limits: LimitSettings | None = None) -> RosGravity:
    """Gravity from an Imu message object: its linear acceleration points up at rest (REP 145), so down is
    -a / |a|. A reading whose magnitude is far from g (a shock, or an IMU that reports in g instead of
    m/s^2) says little about which way is down and is refused."""
    stamp, frame_id = _header(message, limits or LimitSettings(), "Imu")
    if message.linear_acceleration_covariance[0] == -1:  # REP 145 / sensor_msgs: "no estimate"
        raise MessageError("the Imu carries no linear acceleration (linear_acceleration_covariance[0] = -1)")
    a = message.linear_acceleration
    acceleration = np.array([a.x, a.y, a.z], dtype=np.float64)
    norm = float(np.linalg.norm(acceleration))
    if not np.isfinite(norm) or not 0.5 * STANDARD_GRAVITY <= norm <= 2 * STANDARD_GRAVITY:
        raise MessageError(
            f"Imu linear acceleration {acceleration.tolist()} (|a| = {norm:.3g}) is not gravity at rest: "
            "expected about 9.81 m/s^2 (sensor_msgs/Imu is in m/s^2, pointing up at rest)"
        )
    return RosGravity(-acceleration / norm, stamp, frame_id)


def rotation_of(quaternion) -> np.ndarray:
    """3 x 3 rotation of a unit quaternion (x, y, z, w), as ROS writes them."""
    q = np.asarray(quaternion, dtype=np.float64).reshape(-1)
    if q.shape != (4,) or not np.isfinite(q).all() or abs(np.linalg.norm(q) - 1) > 1e-3:
        raise ValueError(f"{np.asarray(quaternion).tolist()} is not a unit quaternion (x, y, z, w)")
    from scipy.spatial.transform import Rotation

    return Rotation.from_quat(q).as_matrix()  # scalar last, as ROS writes them


# -- Odometry ------------------------------------------------------------------------------------------------


@dataclass
class RosPose:
    """One Odometry reading: `pose` (4 x 4) of `child_frame_id` in `frame_id`, at the header's time."""

    pose: np.ndarray
    stamp: float
    frame_id: str
    child_frame_id: str


def odometry(payload: bytes, limits: LimitSettings | None = None) -> RosPose:
    """The pose a CDR nav_msgs/msg/Odometry gives."""
    return pose_of(_small(payload, ODOMETRY, "Odometry"), limits)


def pose_of(message, limits: LimitSettings | None = None) -> RosPose:
    """The pose of an Odometry message object; refused when its position is not finite or lies beyond
    AFFORD_LIMITS__MAX_EXTENT of the odometry's origin, or its orientation is not a unit quaternion."""
    limits = limits or LimitSettings()
    stamp, frame_id = _header(message, limits, "Odometry")
    child = _child_frame(message, "Odometry")
    p, q = message.pose.pose.position, message.pose.pose.orientation
    pose = _checked_rigid(p, q, limits, "Odometry position", "Odometry orientation")
    return RosPose(pose, stamp, frame_id, child)


def _child_frame(message, what: str) -> str:
    """A message's child_frame_id, refused past MAX_FRAME_ID characters."""
    child = message.child_frame_id
    if len(child) > MAX_FRAME_ID:
        raise MessageError(f"{what} child_frame_id is {len(child):,} characters; at most {MAX_FRAME_ID}")
    return child


def _checked_rigid(position, quaternion, limits: LimitSettings, where: str, turn: str) -> np.ndarray:
    """4 x 4 transform of a message's point and quaternion; MessageError (`where` or `turn` naming the part)
    when the point is not finite or lies beyond AFFORD_LIMITS__MAX_EXTENT, or the quaternion is not a unit
    one."""
    p, q = position, quaternion
    translation = np.array([p.x, p.y, p.z], dtype=np.float64)
    if not np.isfinite(translation).all() or np.abs(translation).max() > limits.max_extent:
        raise MessageError(
            f"{where} {translation.tolist()} is not finite or beyond AFFORD_LIMITS__MAX_EXTENT "
            f"({limits.max_extent:g} m)"
        )
    try:
        rotation = rotation_of([q.x, q.y, q.z, q.w])
    except ValueError as error:
        raise MessageError(f"{turn}: {error}") from None
    rigid = np.eye(4)
    rigid[:3, :3], rigid[:3, 3] = rotation, translation
    return rigid


def rigid_of(pose) -> np.ndarray:
    """4 x 4 transform of a pose as ROS writes one: x, y, z, then the quaternion x, y, z, w."""
    values = np.asarray(pose, dtype=np.float64).reshape(-1)
    if values.shape != (7,) or not np.isfinite(values).all():
        raise ValueError(f"{np.asarray(pose).tolist()} is not a pose [x, y, z, qx, qy, qz, qw]")
    rigid = np.eye(4)
    rigid[:3, :3], rigid[:3, 3] = rotation_of(values[3:]), values[:3]
    return rigid


class _Readings:
    """The latest timed readings (arrays) of a sensor, at most `keep`. Readings come from the network
    thread, clouds are handled on the worker: hence the lock."""

    def __init__(self, keep: int = 2048):
        self._readings: deque[tuple[float, np.ndarray]] = deque(maxlen=keep)
        self._lock = threading.Condition()

    def add(self, stamp: float, value: np.ndarray) -> None:
        with self._lock:
            self._readings.append((stamp, np.asarray(value, dtype=np.float64)))
            self._lock.notify_all()

    def wait_past(self, stamp: float, timeout: float) -> bool:
        """Wait up to `timeout` seconds for a reading stamped at or after `stamp` (the newest one heard);
        whether one came. A sensor's readings come on their own topic, through their own queues, and can
        reach the service after the cloud they belong to."""
        with self._lock:
            return self._lock.wait_for(
                lambda: bool(self._readings) and self._readings[-1][0] >= stamp, timeout=max(0.0, timeout)
            )

    def __len__(self) -> int:
        return len(self._readings)


class PoseTrack(_Readings):
    """The latest odometry poses, so that each cloud gets the pose at its own time: interpolated between the
    readings either side of it, else the nearest (odometry runs at 20-100 Hz, a depth camera or LiDAR at
    10-30; between two readings a robot moves centimetres, which the registration's prior would take as
    the odometry's word)."""

    def at(self, stamp: float, max_age: float) -> np.ndarray | None:
        """The pose at `stamp`: interpolated between the readings just before and after it when both lie
        within `max_age` seconds of it, else the nearest such reading; None when none does."""
        from scipy.spatial.transform import Rotation, Slerp

        with self._lock:
            readings = sorted(self._readings, key=lambda reading: reading[0])
        stamps = np.array([s for s, _ in readings])
        near = np.flatnonzero(np.abs(stamps - stamp) <= max_age)
        if not len(near):
            return None
        before = [i for i in near if stamps[i] <= stamp]
        after = [i for i in near if stamps[i] > stamp]
        if not before or not after:
            return readings[near[np.argmin(np.abs(stamps[near] - stamp))]][1].copy()
        (t0, a), (t1, b) = readings[before[-1]], readings[after[0]]
        share = (stamp - t0) / (t1 - t0)
        pose = np.eye(4)
        pose[:3, :3] = Slerp([0.0, 1.0], Rotation.from_matrix([a[:3, :3], b[:3, :3]]))(share).as_matrix()
        pose[:3, 3] = (1 - share) * a[:3, 3] + share * b[:3, 3]
        return pose


class GravityTrack(_Readings):
    """The latest IMU readings, so that each cloud gets the gravity measured nearest its own time (an IMU
    runs at hundreds of Hz, a depth camera or LiDAR at 10-30)."""

    def at(self, stamp: float, max_age: float) -> np.ndarray | None:
        """The reading nearest `stamp`, if one lies within `max_age` seconds of it."""
        with self._lock:
            if not self._readings:
                return None
            stamps = np.fromiter((s for s, _ in self._readings), dtype=np.float64, count=len(self._readings))
            nearest = int(np.argmin(np.abs(stamps - stamp)))
            if abs(stamps[nearest] - stamp) > max_age:
                return None
            return self._readings[nearest][1].copy()


# -- tf ------------------------------------------------------------------------------------------------------


@dataclass
class RosTransform:
    """One TransformStamped: `transform` (4 x 4) is the pose of `child` in `parent`, parent_from_child."""

    parent: str
    child: str
    transform: np.ndarray
    stamp: float


def tf_message(payload: bytes, limits: LimitSettings | None = None) -> list[RosTransform]:
    """The transforms of a CDR tf2_msgs/msg/TFMessage, every one checked before any is returned: a message
    with one unusable transform is refused whole."""
    if len(payload) > MAX_TF_BYTES:
        raise MessageError(f"a TFMessage of {len(payload):,} bytes; at most {MAX_TF_BYTES:,} are parsed")
    return [transform_of(t, limits) for t in deserialize(payload, TFMESSAGE).transforms]


def tf_bytes(transforms: list[RosTransform]) -> bytes:
    """CDR bytes of a tf2_msgs/msg/TFMessage holding the transforms, each stamped with its own time."""
    from scipy.spatial.transform import Rotation

    types = typestore().types
    stamped = []
    for t in transforms:
        seconds, nanoseconds = divmod(round(t.stamp * 1e9), 1_000_000_000)
        x, y, z, w = Rotation.from_matrix(t.transform[:3, :3]).as_quat()
        stamped.append(
            types["geometry_msgs/msg/TransformStamped"](
                header=types["std_msgs/msg/Header"](
                    stamp=types["builtin_interfaces/msg/Time"](sec=seconds, nanosec=nanoseconds),
                    frame_id=t.parent,
                ),
                child_frame_id=t.child,
                transform=types["geometry_msgs/msg/Transform"](
                    translation=types["geometry_msgs/msg/Vector3"](*map(float, t.transform[:3, 3])),
                    rotation=types["geometry_msgs/msg/Quaternion"](float(x), float(y), float(z), float(w)),
                ),
            )
        )
    return serialize(types[TFMESSAGE](transforms=stamped), TFMESSAGE)


def transform_of(stamped, limits: LimitSettings | None = None) -> RosTransform:
    """A geometry_msgs/msg/TransformStamped object; refused when a frame is unnamed, its own parent or too
    long, the translation not finite or beyond AFFORD_LIMITS__MAX_EXTENT, the rotation no unit quaternion."""
    limits = limits or LimitSettings()
    stamp, parent = _header(stamped, limits, "tf")
    child = _child_frame(stamped, "tf")
    if not parent or not child or parent.strip("/") == child.strip("/"):
        raise MessageError(f"tf from {parent!r} to {child!r}: both frames must be named, and differ")
    t, q = stamped.transform.translation, stamped.transform.rotation
    pair = f"tf {parent!r} -> {child!r}"
    transform = _checked_rigid(t, q, limits, f"{pair}: translation", f"{pair}: rotation")
    return RosTransform(parent.strip("/"), child.strip("/"), transform, stamp)


class TransformTree:
    """The robot's tf tree as heard: the newest transform of each child frame from its parent, from /tf and
    /tf_static alike (a mount is static; the base's pose in odom moves, and the newest is what a mount's
    lookup needs). Frame names are taken without a leading slash, as tf2 does. Filled on the network
    thread, read on the worker: hence the lock."""

    def __init__(self, max_frames: int = MAX_TF_FRAMES):
        self._parents: dict[str, tuple[str, np.ndarray]] = {}
        self._max_frames = max_frames
        self._lock = threading.Lock()

    def add(self, transforms: list[RosTransform]) -> None:
        """Keep each child's newest transform; MessageError, and nothing kept, when the new frames would pass
        `max_frames` (a tree cannot grow without bound on hostile input)."""
        with self._lock:
            new = {t.child for t in transforms} - self._parents.keys()
            if len(self._parents) + len(new) > self._max_frames:
                raise MessageError(
                    f"tf: {len(new)} new frames would make {len(self._parents) + len(new):,}; at most "
                    f"{self._max_frames:,} are kept"
                )
            for t in transforms:
                self._parents[t.child] = (t.parent, t.transform)

    def __len__(self) -> int:
        return len(self._parents)

    def __contains__(self, frame: str) -> bool:
        """Whether the tree names the frame, as a child or as a parent."""
        frame = frame.strip("/")
        with self._lock:
            return frame in self._parents or any(parent == frame for parent, _ in self._parents.values())

    def lookup(self, target: str, source: str) -> np.ndarray | None:
        """target_from_source (4 x 4): a point in `source` expressed in `target`, chained through their
        nearest common ancestor; None when the two are not (yet) joined in the tree."""
        target, source = target.strip("/"), source.strip("/")
        with self._lock:
            up_from_source = self._chain(source)
            up_from_target = self._chain(target)
        common = next((frame for frame in up_from_source if frame in up_from_target), None)
        if common is None:
            return None
        return np.linalg.inv(up_from_target[common]) @ up_from_source[common]

    def _chain(self, frame: str) -> dict[str, np.ndarray]:
        """{ancestor: ancestor_from_frame} for the frame itself and each frame above it, nearest first (a
        cycle, which tf forbids but a hostile sender can make, ends the walk)."""
        chain = {frame: np.eye(4)}
        while frame in self._parents:
            parent, parent_from_frame = self._parents[frame]
            if parent in chain:
                break
            chain[parent] = parent_from_frame @ chain[frame]
            frame = parent
        return chain
