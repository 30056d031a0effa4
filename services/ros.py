"""ROS 2 robots in: the assembler's subscriptions to `sensor_msgs/msg/PointCloud2`, `sensor_msgs/msg/Imu` and
`nav_msgs/msg/Odometry` as a robot publishes them over Zenoh, and rosbag2 / MCAP recordings read for
`afford publish`.

Two key formats carry ROS 2 topics over Zenoh (docs/ros.md):

* rmw_zenoh (ROS 2's Zenoh middleware): ``<domain_id>/<topic>/<type>/<type hash>``, the topic without its
  leading slash (namespace included), the type in DDS form (``sensor_msgs::msg::dds_::PointCloud2_``) and
  the hash ``RIHS01_<sha256>`` (or ``TypeHashNotSupported`` on Humble). The subscription takes any hash, so
  the hash of the robot's distribution need not be configured.
* zenoh-plugin-ros2dds (the DDS bridge): ``<topic>``, the topic without its leading slash, prefixed with the
  bridge's namespace when one is configured.

Both carry the message as CDR, decoded by affordwire.ros. Clouds go through the assembler's inbox like any
scan; Imu readings are decoded on arrival (a few hundred bytes, at hundreds of Hz: they would flood the scan
inbox) into a `GravityTrack`, and each cloud takes the reading nearest its own stamp; Odometry readings
likewise into a `PoseTrack`, and each cloud takes the pose interpolated at its stamp as its pose guess, moved
to the cloud's sensor by its mount on the odometry's child frame.

The mount and the IMU's rotation to the cloud's frame come from the robot's tf (`/tf_static` and `/tf`,
AFFORD_ROS__TF_STATIC and AFFORD_ROS__TF, into a `TransformTree`), looked up by the frames the messages name;
`AFFORD_ROS__BASE_FROM_CLOUD` and `AFFORD_ROS__CLOUD_FROM_IMU` stand in for tf where they are set. The static
transforms are latched: /tf_static is subscribed with a zenoh AdvancedSubscriber whose history query reaches
the cache of a TRANSIENT_LOCAL publisher (rmw_zenoh's), so a robot that published its tree before the
assembler started is heard. Until a transform arrives, the sensor is taken to sit at the base's origin and
the IMU to share the cloud's axes, and the log says so once, naming the frames.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from affordcore.assembly.assembler import SensorFrame
from affordwire import messages, ros

from .node import Inbound, Inbox, Node
from .settings import RosSettings

# the schema a ROS subscription tags its samples with (they carry no afford schema of their own)
POINTS_SCHEMA = f"ros2:{ros.POINTCLOUD2}"
IMU_SCHEMA = f"ros2:{ros.IMU}"
ODOMETRY_SCHEMA = f"ros2:{ros.ODOMETRY}"
TF_SCHEMA = f"ros2:{ros.TFMESSAGE}"


def dds_type(typename: str) -> str:
    """rmw_zenoh's type chunk: sensor_msgs/msg/PointCloud2 -> sensor_msgs::msg::dds_::PointCloud2_."""
    package, kind, name = typename.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def topic_keys(topic: str, typename: str, settings: RosSettings) -> list[str]:
    """The key expressions a ROS 2 topic (checked by RosSettings: no wildcards) is published on, in the
    formats `settings.key_formats` names."""
    name = topic.strip("/")
    keys = []
    if "rmw_zenoh" in settings.key_formats:
        keys.append(f"{settings.domain_id}/{name}/{dds_type(typename)}/*")
    if "ros2dds" in settings.key_formats:
        keys.append(name)
    return keys


def imu_rotation(settings: RosSettings) -> np.ndarray | None:
    """cloud_from_imu as a 3 x 3 rotation, None when the IMU is mounted as the cloud sensor."""
    return None if settings.cloud_from_imu is None else ros.rotation_of(settings.cloud_from_imu)


def sensor_mounting(settings: RosSettings) -> np.ndarray | None:
    """base_from_cloud as a 4 x 4 transform, None when the sensor sits at the odometry's child frame."""
    return None if settings.base_from_cloud is None else ros.rigid_of(settings.base_from_cloud)


def pose_guess(track: ros.PoseTrack, stamp: float, settings: RosSettings, mounting: np.ndarray | None):
    """The cloud sensor's pose by the odometry at `stamp` (odom_from_cloud); None without a reading near."""
    base = track.at(stamp, settings.odometry_max_age)
    if base is None:
        return None
    return base if mounting is None else base @ mounting


@dataclass
class Counts:
    clouds: int = 0
    points: int = 0
    read: int = 0  # points read: a cloud above AFFORD_ASSEMBLER__MAX_FRAME_POINTS is thinned as it is read
    nonfinite: int = 0  # of those, dropped for a NaN or infinite coordinate
    imu: int = 0
    with_gravity: int = 0
    odometry: int = 0
    with_odometry: int = 0
    transforms: int = 0


class RosInput:
    """The assembler's ROS 2 topics (AFFORD_ROS__POINTS, AFFORD_ROS__IMU, AFFORD_ROS__ODOMETRY, and tf).
    `frame` turns a cloud sample into the assembler's SensorFrame with the gravity of the Imu reading nearest
    its stamp and the odometry's pose at it, both turned into the cloud's frame by tf."""

    def __init__(self, node: Node, inbox: Inbox):
        self.node, self.settings, self.limits = node, node.settings.ros, node.settings.limits
        ros.typestore()  # RosUnavailable (pip install affordmap[ros]) at the start, not at the first cloud
        self.rotation = imu_rotation(self.settings)  # the settings' word over tf's, when given
        self.gravity = ros.GravityTrack()  # in the IMU's frame
        self.mounting = sensor_mounting(self.settings)
        self.poses = ros.PoseTrack()
        self.tree = ros.TransformTree()
        self.counts = Counts()
        self.imu_frame: str | None = None
        self.base_frame: str | None = None  # the odometry's child frame
        self.odom_frame: str | None = None  # the odometry's own frame (its header's)
        # the robot's odometry frame from the assembler's (its first sensor frame), by the newest frame that
        # came with a pose guess: what ties afford's world to the robot's tf
        self.odom_from_assembler: np.ndarray | None = None
        self._said: set[tuple] = set()  # what the log has said once
        self._warned_nonfinite = False
        self.point_keys = topic_keys(self.settings.points, ros.POINTCLOUD2, self.settings)
        self.imu_keys = topic_keys(self.settings.imu, ros.IMU, self.settings) if self.settings.imu else []
        for key in self.point_keys:
            node.subscribe(key, inbox, schema=POINTS_SCHEMA)
        # kept referenced for the life of the service; the session's close undeclares them
        self._imu_subscribers = [node.session.declare_subscriber(key, self._on_imu) for key in self.imu_keys]
        self.odometry_keys = (
            topic_keys(self.settings.odometry, ros.ODOMETRY, self.settings) if self.settings.odometry else []
        )
        self._odometry_subscribers = [
            node.session.declare_subscriber(key, self._on_odometry) for key in self.odometry_keys
        ]
        self.tf_keys = self._subscribe_tf()
        print(
            f"[{node.service}] ROS 2 in: PointCloud2 on {', '.join(self.point_keys)}"
            + (f"; Imu on {', '.join(self.imu_keys)}" if self.imu_keys else "; no Imu (AFFORD_ROS__IMU)")
            + (
                f"; Odometry on {', '.join(self.odometry_keys)}"
                if self.odometry_keys
                else "; no odometry (AFFORD_ROS__ODOMETRY)"
            )
            + (f"; tf on {', '.join(self.tf_keys)}" if self.tf_keys else "; no tf (AFFORD_ROS__TF[_STATIC])"),
            flush=True,
        )

    def _subscribe_tf(self) -> list[str]:
        """Subscribe to /tf, and to /tf_static with its history (the robot's latched tree), on the keys of
        every format; the keys."""
        import zenoh
        import zenoh.ext

        keys = []
        self._tf_subscribers = []
        remote = zenoh.Locality.REMOTE  # not the world's transform this service publishes itself
        for topic, latched in ((self.settings.tf_static, True), (self.settings.tf, False)):
            for key in topic_keys(topic, ros.TFMESSAGE, self.settings) if topic else []:
                if latched:
                    history = zenoh.ext.HistoryConfig(detect_late_publishers=True)
                    subscriber = zenoh.ext.declare_advanced_subscriber(
                        self.node.session, key, self._on_tf, history=history, allowed_origin=remote
                    )
                else:
                    subscriber = self.node.session.declare_subscriber(key, self._on_tf, allowed_origin=remote)
                self._tf_subscribers.append(subscriber)
                keys.append(key)
        return keys

    @staticmethod
    def wanted(settings: RosSettings) -> bool:
        return bool(settings.points)

    def takes(self, item: Inbound) -> bool:
        return item.schema == POINTS_SCHEMA

    def _on_imu(self, sample) -> None:
        """On zenoh's thread: keep the reading's gravity, or answer why not on the error key."""
        self._on_reading(sample, IMU_SCHEMA, self._take_imu)

    def _take_imu(self, payload: bytes) -> None:
        reading = ros.imu(payload, self.limits)
        self.gravity.add(reading.stamp, reading.down)
        self.imu_frame = reading.frame_id
        self.counts.imu += 1

    def _on_odometry(self, sample) -> None:
        """On zenoh's thread: keep the odometry's pose, or answer why not on the error key."""
        self._on_reading(sample, ODOMETRY_SCHEMA, self._take_odometry)

    def _take_odometry(self, payload: bytes) -> None:
        reading = ros.odometry(payload, self.limits)
        self.poses.add(reading.stamp, reading.pose)
        self.base_frame, self.odom_frame = reading.child_frame_id, reading.frame_id
        self.counts.odometry += 1

    def _on_tf(self, sample) -> None:
        """On zenoh's thread: keep a TFMessage's transforms (all or, when one is unusable, none)."""
        self._on_reading(sample, TF_SCHEMA, self._take_tf)

    def _take_tf(self, payload: bytes) -> None:
        transforms = ros.tf_message(payload, self.limits)
        self.tree.add(transforms)
        self.counts.transforms += len(transforms)

    def _on_reading(self, sample, schema: str, take) -> None:
        """Decode and keep a reading; a bad one is answered on the error key (an exception must not escape
        into zenoh) and the service goes on."""
        payload = sample.payload.to_bytes()
        try:
            take(payload)
        except Exception as error:  # noqa: BLE001 - a bad reading is refused; the service goes on
            reason = str(error) if isinstance(error, ValueError) else f"{type(error).__name__}: {error}"
            item = Inbound(str(sample.key_expr), schema, str(sample.encoding), payload, time.time())
            self.node.reject(item, reason)

    def decode(self, item: Inbound):
        """A PointCloud2 sample's points (on arrival); MessageError when it is unusable."""
        # thinned as the assembler would (AFFORD_ASSEMBLER__MAX_FRAME_POINTS) before the points are converted
        cloud = ros.pointcloud2(item.payload, self.limits, keep=self.node.settings.assembler.max_frame_points)
        item.input_source = cloud.frame_id
        return cloud

    def frame(self, item: Inbound, cloud) -> SensorFrame:
        """The SensorFrame of a decoded PointCloud2 sample, with the gravity and pose guess at its stamp."""
        self._wait_for_readings(item, cloud.stamp)
        gravity = self.gravity.at(cloud.stamp, self.settings.imu_max_age) if self.imu_keys else None
        if gravity is not None:
            rotation = self._cloud_from_imu(cloud.frame_id)
            gravity = gravity if rotation is None else rotation @ gravity
        guess = None
        if self.odometry_keys:
            guess = pose_guess(self.poses, cloud.stamp, self.settings, self._base_from_cloud(cloud.frame_id))
        self.counts.clouds += 1
        self.counts.points += cloud.total
        self.counts.read += cloud.read
        self.counts.nonfinite += cloud.nonfinite
        self.counts.with_gravity += gravity is not None
        self.counts.with_odometry += guess is not None
        if cloud.nonfinite and not self._warned_nonfinite:
            self._warned_nonfinite = True
            print(
                f"[{self.node.service}] {item.key}: dropped {cloud.nonfinite:,} of {cloud.read:,} points "
                "with NaN or infinite coordinates (an organised cloud's missing returns); counted from here "
                "on and reported at the stop",
                flush=True,
            )
        return SensorFrame(
            frame_id=cloud.frame_id or "sensor",
            stamp=cloud.stamp,
            points=cloud.points,
            gravity=gravity,
            pose_guess=guess,
        )

    def _wait_for_readings(self, item: Inbound, stamp: float) -> None:
        """Give the odometry and the Imu until AFFORD_ROS__READING_WAIT after the cloud arrived to reach its
        stamp, so that a cloud does not lose its pose or gravity to a reading still on its way."""
        deadline = item.arrived + self.settings.reading_wait
        for track, heard in ((self.poses, self.odometry_keys), (self.gravity, self.imu_keys)):
            if heard:
                track.wait_past(stamp, deadline - time.time())

    def tie(self, odom_from_sensor: np.ndarray, guess: np.ndarray | None) -> None:
        """A registered frame's pose in the assembler's odometry frame, beside the pose the robot's odometry
        gave it (its guess, in the robot's odometry frame): the two frames' offset, newest kept."""
        if guess is not None:
            self.odom_from_assembler = guess @ np.linalg.inv(odom_from_sensor)

    def _base_from_cloud(self, cloud_frame: str) -> np.ndarray | None:
        """The cloud sensor's mount on the odometry's child frame: the settings', else tf's, else None (the
        sensor at the base's origin, with its axes)."""
        base = self.base_frame
        if self.mounting is not None or base is None or base.strip("/") == cloud_frame.strip("/"):
            return self.mounting
        return self._looked_up(
            base, cloud_frame, "the sensor is taken to sit at its origin with its axes", "BASE_FROM_CLOUD"
        )

    def _cloud_from_imu(self, cloud_frame: str) -> np.ndarray | None:
        """The rotation from the IMU's frame to the cloud's: the settings', else tf's, else None (alike)."""
        imu_frame = self.imu_frame
        if self.rotation is not None or imu_frame is None or imu_frame.strip("/") == cloud_frame.strip("/"):
            return self.rotation
        transform = self._looked_up(
            cloud_frame, imu_frame, "the IMU is taken to share the cloud sensor's axes", "CLOUD_FROM_IMU"
        )
        return None if transform is None else transform[:3, :3]

    def _looked_up(self, target: str, source: str, meanwhile: str, setting: str) -> np.ndarray | None:
        """tf's target_from_source, saying once on the log when it is missing and once when it is found."""
        transform = self.tree.lookup(target, source) if self.tf_keys else None
        pair = (target, source)
        if transform is None:
            if (pair, False) not in self._said:
                self._said.add((pair, False))
                heard = f"tf has {len(self.tree)} frames" if self.tf_keys else "tf is not read"
                print(
                    f"[{self.node.service}] no transform from {source!r} to {target!r} ({heard}): "
                    f"{meanwhile}; publish it on {self.settings.tf_static or '/tf_static'} or set "
                    f"AFFORD_ROS__{setting}",
                    flush=True,
                )
        elif (pair, True) not in self._said:
            self._said.add((pair, True))
            x, y, z = transform[:3, 3]
            print(
                f"[{self.node.service}] tf: {source!r} sits at ({x:.3f}, {y:.3f}, {z:.3f}) m in {target!r}",
                flush=True,
            )
        return transform

    def summary(self) -> str:
        c = self.counts
        return (
            f"ROS 2: {c.clouds} clouds decoded ({c.points:,} points, {c.read:,} of them read, "
            f"{c.nonfinite:,} of those NaN or infinite and dropped), {c.with_gravity} with an Imu gravity, "
            f"{c.with_odometry} with the odometry's pose; {c.imu} Imu and {c.odometry} Odometry readings "
            f"and {c.transforms} tf transforms taken"
        )


# -- recordings (afford publish) -----------------------------------------------------------------------------


class RecordingError(ValueError):
    """A recording that cannot be streamed as asked; the message names the topics it has."""


def is_recording(path: Path) -> bool:
    """A rosbag2 folder (metadata.yaml), or a single MCAP or sqlite3 storage file."""
    path = Path(path)
    if path.is_dir():
        return (path / "metadata.yaml").is_file()
    return path.suffix.lower() in (".mcap", ".db3")


@dataclass
class RecordingStats:
    """What streaming a recording skipped, to be reported."""

    topic: str = ""
    imu_topic: str | None = None
    refused: int = 0  # PointCloud2 messages that are unusable (MessageError)
    first_refusal: str = ""
    bad_imu: int = 0
    nonfinite: int = 0
    with_gravity: int = 0
    odometry_topic: str | None = None
    bad_odometry: int = 0
    with_odometry: int = 0
    tf_topics: tuple[str, ...] = ()
    bad_tf: int = 0

    def describe(self, sent: int, path: Path) -> str:
        gravity = f", {self.with_gravity} with gravity from {self.imu_topic}" if self.imu_topic else ""
        if self.odometry_topic:
            gravity += f", {self.with_odometry} with the pose of {self.odometry_topic}"
        return f"{sent} scans of {self.topic} from {path}{gravity}"

    def notes(self) -> list[str]:
        """What a person streaming the recording should hear about."""
        said = []
        if self.refused:
            said.append(f"{self.refused} unusable PointCloud2 messages were left out ({self.first_refusal})")
        if self.bad_imu:
            said.append(f"{self.bad_imu} unusable Imu messages of {self.imu_topic} were left out")
        if self.bad_odometry:
            said.append(
                f"{self.bad_odometry} unusable Odometry messages of {self.odometry_topic} were left out"
            )
        if self.bad_tf:
            said.append(f"{self.bad_tf} unusable TFMessages of {', '.join(self.tf_topics)} were left out")
        if self.nonfinite:
            said.append(f"dropped {self.nonfinite:,} points with NaN or infinite coordinates")
        return said


def _topics_of(reader, typename: str) -> list[str]:
    return sorted(topic for topic, info in reader.topics.items() if info.msgtype == typename)


def _choose(reader, path: Path, typename: str, wanted: str, option: str) -> str:
    topics = _topics_of(reader, typename)
    listed = ", ".join(topics) or "none"
    if wanted:
        if wanted not in topics:
            raise RecordingError(
                f"{path}: no {typename} topic {wanted!r} ({option}); its {typename} topics: {listed}"
            )
        return wanted
    if len(topics) != 1:
        every = ", ".join(f"{topic} ({info.msgtype})" for topic, info in sorted(reader.topics.items()))
        raise RecordingError(
            f"{path}: {'no' if not topics else len(topics)} {typename} topics"
            + (f" ({listed}); choose one with {option}" if topics else f"; it has {every or 'no topics'}")
        )
    return topics[0]


def recording_frames(
    path: Path,
    topic: str = "",
    imu_topic: str = "",
    imu: bool = True,
    first: int = 0,
    frames: int = 0,
    step: int = 1,
    settings: RosSettings | None = None,
    limits=None,
    odometry_topic: str = "",
    odometry: bool = True,
) -> tuple[RecordingStats, Iterator[tuple[int, messages.Scan]], int]:
    """(stats, (index, Scan) pairs, how many) of a rosbag2 folder (sqlite3 or MCAP storage) or a single MCAP
    file, read by rosbags' AnyReader. `topic` is the PointCloud2 topic (default: the only one), `imu_topic`
    an Imu topic giving each scan its gravity (default: the only one, if any; none with `imu` False). Each
    Scan keeps its header stamp (the bag's receive time when the header has none): the assembler's motion
    limits use the recorded times, whatever the rate of the replay. `odometry_topic`: a nav_msgs/Odometry
    topic giving each scan its pose guess (default: the only one, if any; none with `odometry` False), the
    sensor's pose by its mount, and the Imu's gravity turned into the cloud's frame: by
    `settings.base_from_cloud` and `cloud_from_imu` where set, else by the bag's tf (its `settings.tf_static`
    and `settings.tf` topics). RecordingError when the topics are not as asked."""
    try:
        from rosbags.highlevel import AnyReader
    except ImportError:
        ros.typestore()  # raises RosUnavailable naming the extra
        raise
    from affordcore.settings import LimitSettings

    settings, limits = settings or RosSettings(), limits or LimitSettings()
    path = Path(path)
    reader = AnyReader([path], default_typestore=ros.typestore())
    try:
        reader.open()
    except Exception as error:  # rosbags' reader errors: a folder or file that is not a readable bag
        raise RecordingError(f"{path}: not a readable rosbag2 or MCAP recording ({error})") from None
    try:
        stats = RecordingStats(topic=_choose(reader, path, ros.POINTCLOUD2, topic, "--topic"))
        if imu and (imu_topic or _topics_of(reader, ros.IMU)):
            stats.imu_topic = _choose(reader, path, ros.IMU, imu_topic, "--imu-topic or --no-imu")
        if odometry and (odometry_topic or _topics_of(reader, ros.ODOMETRY)):
            stats.odometry_topic = _choose(
                reader, path, ros.ODOMETRY, odometry_topic, "--odometry-topic or --no-odometry"
            )
        tf_topics = set(_topics_of(reader, ros.TFMESSAGE))
        stats.tf_topics = tuple(t for t in (settings.tf_static, settings.tf) if t and t in tf_topics)
    except BaseException:
        reader.close()
        raise
    total = reader.topics[stats.topic].msgcount
    indices = range(first, total, step)
    count = len(indices[: frames or None])
    if not count:
        reader.close()
        raise RecordingError(f"{path}: no messages of {stats.topic} from {first} (it has {total})")
    wanted = set(indices[: frames or None])
    return stats, _stream(reader, stats, wanted, settings, limits), count


def _stream(reader, stats: RecordingStats, wanted: set[int], settings: RosSettings, limits):
    """The wanted clouds as Scans, in order. With an odometry topic a scan waits until a reading at or after
    its stamp is read (the bag is in receive order): its pose is interpolated, not the last before it."""
    rotation, mounting = imu_rotation(settings), sensor_mounting(settings)
    track, poses, tree = ros.GravityTrack(), ros.PoseTrack(), ros.TransformTree()
    frames = {"imu": None, "base": None}  # the Imu's frame and the odometry's child frame, as read
    waiting: list[tuple[int, messages.Scan, float]] = []

    def looked_up(target, source, override):
        """The settings' transform, else tf's target_from_source (None: the frames taken to coincide)."""
        if override is not None or None in (source, target) or source.strip("/") == target.strip("/"):
            return override
        return tree.lookup(target, source)

    def ready(until: float):
        while waiting and waiting[0][2] <= until:
            index, scan, stamp = waiting.pop(0)
            guess = pose_guess(poses, stamp, settings, looked_up(frames["base"], scan.frame_id, mounting))
            if guess is not None:
                messages.set_pose(scan.pose_guess, guess, "odom", scan.frame_id, at=stamp)
                stats.with_odometry += 1
            yield index, scan

    topics = {stats.topic, stats.imu_topic, stats.odometry_topic, *stats.tf_topics} - {None}
    connections = [c for c in reader.connections if c.topic in topics]
    sensor = stats.topic.strip("/").replace("/", "_") or "sensor"
    index, last = -1, max(wanted)
    try:
        for connection, bag_time, raw in reader.messages(connections=connections):
            if connection.topic in stats.tf_topics:
                try:
                    message = reader.deserialize(raw, connection.msgtype)
                    tree.add([ros.transform_of(t, limits) for t in message.transforms])
                except Exception:  # noqa: BLE001 - one bad message: the tree keeps what it had
                    stats.bad_tf += 1
                continue
            if connection.topic == stats.imu_topic:
                try:
                    reading = ros.gravity_of(reader.deserialize(raw, connection.msgtype), limits)
                except Exception:  # noqa: BLE001 - one bad reading: the cloud takes a neighbour's
                    stats.bad_imu += 1
                    continue
                track.add(reading.stamp, reading.down)
                frames["imu"] = reading.frame_id
                continue
            if connection.topic == stats.odometry_topic:
                try:
                    pose = ros.pose_of(reader.deserialize(raw, connection.msgtype), limits)
                except Exception:  # noqa: BLE001 - one bad reading: the cloud's pose from its neighbours
                    stats.bad_odometry += 1
                    continue
                poses.add(pose.stamp, pose.pose)
                frames["base"] = pose.child_frame_id
                yield from ready(pose.stamp)
                continue
            index += 1
            if index not in wanted:
                if index > last:
                    break
                continue
            try:
                cloud = ros.cloud_of(reader.deserialize(raw, connection.msgtype), limits)
            except Exception as error:  # noqa: BLE001 - reported at the end; the stream goes on
                stats.refused += 1
                stats.first_refusal = stats.first_refusal or f"message {index}: {error}"
                continue
            stats.nonfinite += cloud.nonfinite
            stamp = cloud.stamp or bag_time * 1e-9
            scan = messages.Scan(frame_id=cloud.frame_id or sensor)
            messages.pack_points(scan, cloud.points)
            messages.stamp(scan.timestamp, stamp)
            gravity = track.at(stamp, settings.imu_max_age) if stats.imu_topic else None
            if gravity is not None:
                turn = rotation
                if turn is None and (tf := looked_up(scan.frame_id, frames["imu"], None)) is not None:
                    turn = tf[:3, :3]
                messages.set_vector(scan.gravity, gravity if turn is None else turn @ gravity)
                stats.with_gravity += 1
            waiting.append((index, scan, stamp))
            if not stats.odometry_topic:
                yield from ready(stamp)
        yield from ready(float("inf"))
    finally:
        reader.close()
