"""ROS 2 robots on plain DDS (Fast DDS, Cyclone DDS), with no Zenoh bridge on the robot: a ROS 2 node on the
robot's own rclpy (`afford ros-bridge`) that forwards its topics to the services' keys and the maps back, as
zenoh-plugin-ros2dds would: each message's CDR as it is, on its topic's name without the leading slash (the
`ros2dds` key format, which the assembler subscribes to and the inference service publishes on).

* In (DDS -> Zenoh): the PointCloud2, Imu and Odometry topics of AFFORD_ROS__POINTS / IMU / ODOMETRY, and tf
  (`/tf`, and `/tf_static` as TRANSIENT_LOCAL, so a tree published before the bridge started is heard).
* Out (Zenoh -> DDS): the maps of the robot under AFFORD_ROS__MAPS_NAMESPACE (places, markers, confidence of
  every affordance, each publisher made at its topic's first map) and the assembler's `/tf_static`, published
  TRANSIENT_LOCAL with a depth of one, as the inference service latches them on Zenoh.

The subscriptions take the messages serialized (rclpy's `raw`): nothing is decoded here; the services check
every message as they check one from Zenoh. What the bridge sends out on DDS it does not take back in: the
assembler's `/tf_static` would otherwise return to it as part of the robot's tree.
"""

from __future__ import annotations

import importlib
import threading
from collections import deque

from affordwire import ros, ros_maps

from .ros_maps import ros_token
from .settings import RosSettings
from .transport import put

# the rclpy message class of each ROS type the bridge carries
MESSAGE_CLASSES = {
    ros.POINTCLOUD2: ("sensor_msgs.msg", "PointCloud2"),
    ros.IMU: ("sensor_msgs.msg", "Imu"),
    ros.ODOMETRY: ("nav_msgs.msg", "Odometry"),
    ros.TFMESSAGE: ("tf2_msgs.msg", "TFMessage"),
    ros_maps.PLACES: ("geometry_msgs.msg", "PoseArray"),
    ros_maps.MARKERS: ("visualization_msgs.msg", "MarkerArray"),
    ros_maps.CONFIDENCE: ("nav_msgs.msg", "OccupancyGrid"),
}
MAP_KINDS = {"places": ros_maps.PLACES, "markers": ros_maps.MARKERS, "confidence": ros_maps.CONFIDENCE}
INSTALL = (
    "the robot's ROS 2 (source its setup.bash), or pip install ros-kilted-rclpy and its message packages"
)


def message_class(typename: str):
    """The rclpy class of a ROS type; ImportError naming what to install when its package is missing."""
    module, name = MESSAGE_CLASSES[typename]
    try:
        return getattr(importlib.import_module(module), name)
    except ImportError as error:
        raise ImportError(f"{typename} needs its ROS 2 message package: {INSTALL} ({error})") from None


def key_of(topic: str) -> str:
    """zenoh-plugin-ros2dds's key of a topic: its name without the leading slash."""
    return topic.strip("/")


def _depth(topic: str, settings: RosSettings) -> int:
    """The queue of an input topic, on DDS and to Zenoh: the latched tree's newest message; 10 clouds (a
    ROS 2 sensor queue); and some seconds of the small, fast readings (Imu, odometry, tf at hundreds of
    hertz), which must reach the assembler by their clouds' stamps however busy the bridge is."""
    if topic == settings.tf_static:
        return 1
    return 10 if topic == settings.points else 1000


class _Forwarder:
    """One topic's messages onto its Zenoh key, in order, from a thread of its own: a put that waits on a
    full Zenoh queue (congestion control BLOCK) holds back only its own topic, and rclpy's executor, which
    takes every topic's samples, never waits on Zenoh. Past `depth` waiting, the oldest is dropped and
    counted, as a DDS queue of that depth would. A put that fails (a closing session, a refused key) loses
    that message alone: it is counted, its error said once, and the topic goes on."""

    def __init__(self, session, key: str, depth: int):
        self.session, self.key = session, key
        self.waiting: deque[bytes] = deque(maxlen=depth)
        self.sent = self.dropped = self.failed = 0
        self.error = ""  # the last failed put's error
        self._ready = threading.Condition()
        self._closed = False
        self._thread = threading.Thread(target=self._run, name=f"ros-bridge {key}", daemon=True)
        self._thread.start()

    def offer(self, payload: bytes) -> None:
        with self._ready:
            self.dropped += len(self.waiting) == self.waiting.maxlen
            self.waiting.append(payload)
            self._ready.notify()

    def _run(self) -> None:
        while True:
            with self._ready:
                self._ready.wait_for(lambda: self.waiting or self._closed)
                if not self.waiting:
                    return
                payload = self.waiting.popleft()
            try:
                put(self.session, self.key, payload)  # BLOCK: never dropped by Zenoh
            except Exception as error:  # noqa: BLE001 - whatever Zenoh raises, the topic must go on
                self.failed += 1
                if str(error) != self.error:
                    print(f"[ros-bridge] {self.key}: a message was not put on Zenoh: {error}", flush=True)
                self.error = str(error)
                continue
            self.sent += 1

    def close(self, timeout: float = 5.0) -> None:
        """Send what is waiting (for up to `timeout` seconds), then end the thread."""
        with self._ready:
            self._closed = True
            self._ready.notify()
        self._thread.join(timeout)


class DdsBridge:
    """The ROS 2 node and its Zenoh session's subscriptions; `run` spins until `stop` is set."""

    def __init__(
        self, session, robot: str, settings: RosSettings | None = None, node_name: str | None = None
    ):
        import rclpy
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
        from rclpy.signals import SignalHandlerOptions

        self.session, self.robot, self.settings = session, robot, settings or RosSettings()
        self.context = rclpy.context.Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(node_name or f"afford_dds_{ros_token(robot)}", context=self.context)
        self.latched = QoSProfile(
            depth=1,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
            reliability=ReliabilityPolicy.RELIABLE,
            history=HistoryPolicy.KEEP_LAST,
        )
        self.counts = {"out": 0}
        self._forwarders: dict[str, _Forwarder] = {}  # per Zenoh key of an input topic
        self._sent: deque[bytes] = deque(maxlen=32)  # what went out on DDS, not to be taken back in
        self._publishers: dict[str, object] = {}
        self._lock = threading.Lock()
        self.skipped: list[str] = []
        self._subscribe_dds()
        self._subscribe_zenoh()

    def _subscribe_dds(self) -> None:
        """Each input topic is subscribed once a publisher of it appears, with that publisher's reliability
        (and durability): a BEST_EFFORT subscription (which matches every publisher) loses large clouds'
        fragments, a RELIABLE one matches no BEST_EFFORT driver."""
        s = self.settings
        wanted = [(s.points, ros.POINTCLOUD2), (s.imu, ros.IMU), (s.odometry, ros.ODOMETRY)]
        wanted += [(s.tf, ros.TFMESSAGE), (s.tf_static, ros.TFMESSAGE)]
        self._pending: dict[str, type] = {}
        for topic, typename in wanted:
            if not topic:
                continue
            try:
                self._pending[topic] = message_class(typename)
            except ImportError as error:
                self.skipped.append(f"{topic}: {error}")
        self._dds_subscriptions = []
        self._subscribe_published()
        self._timer = self.node.create_timer(0.5, self._subscribe_published)

    def _subscribe_published(self) -> None:
        from rclpy.qos import QoSProfile

        for topic, cls in list(self._pending.items()):
            offered = self.node.get_publishers_info_by_topic(topic)
            if not offered:
                continue
            qos = offered[0].qos_profile
            depth = _depth(topic, self.settings)
            profile = QoSProfile(depth=depth, reliability=qos.reliability, durability=qos.durability)
            key = key_of(topic)
            forwarder = self._forwarders[key] = _Forwarder(self.session, key, depth)
            callback = lambda payload, forwarder=forwarder: self._to_zenoh(forwarder, payload)  # noqa: E731
            self._dds_subscriptions.append(
                self.node.create_subscription(cls, topic, callback, profile, raw=True)
            )
            del self._pending[topic]
            print(f"[ros-bridge] {topic} ({qos.reliability.name.lower()}) -> {key}", flush=True)

    def _subscribe_zenoh(self) -> None:
        import zenoh
        import zenoh.ext

        base = self.settings.maps_namespace.replace("{robot}", ros_token(self.robot)).strip("/")
        history = zenoh.ext.HistoryConfig(detect_late_publishers=True)
        remote = zenoh.Locality.REMOTE  # not what this bridge itself put on Zenoh
        keys = [(f"{base}/*/{kind}", typename) for kind, typename in MAP_KINDS.items()]
        if self.settings.tf_static:
            keys.append((key_of(self.settings.tf_static), ros.TFMESSAGE))
        self._zenoh_subscribers = [
            zenoh.ext.declare_advanced_subscriber(
                self.session,
                key,
                lambda sample, typename=typename: self._to_dds(str(sample.key_expr), typename, sample),
                history=history,
                allowed_origin=remote,
            )
            for key, typename in keys
        ]

    def _to_zenoh(self, forwarder: _Forwarder, payload: bytes) -> None:
        """A DDS sample to its forwarder (on rclpy's executor thread); one this bridge sent out is not."""
        if payload not in self._sent:
            forwarder.offer(payload)

    def _to_dds(self, key: str, typename: str, sample) -> None:
        """A Zenoh sample onto its DDS topic, latched (on zenoh's thread)."""
        payload = sample.payload.to_bytes()
        topic = "/" + key
        with self._lock:
            publisher = self._publishers.get(topic)
            if publisher is None:
                try:
                    cls = message_class(typename)
                except ImportError as error:
                    if not any(line.startswith(f"{topic}:") for line in self.skipped):
                        self.skipped.append(f"{topic}: {error}")
                        print(f"[ros-bridge] not bridged: {self.skipped[-1]}", flush=True)
                    return
                publisher = self._publishers[topic] = self.node.create_publisher(cls, topic, self.latched)
            self._sent.append(payload)
            publisher.publish(payload)
            self.counts["out"] += 1

    def run(self, stop: threading.Event) -> None:
        from rclpy.executors import SingleThreadedExecutor

        executor = SingleThreadedExecutor(context=self.context)
        executor.add_node(self.node)
        try:
            while not stop.is_set():
                executor.spin_once(timeout_sec=0.1)
        finally:
            executor.shutdown()
            self.close()

    def close(self) -> None:
        import rclpy

        for subscriber in self._zenoh_subscribers:
            subscriber.undeclare()
        self._zenoh_subscribers = []
        for forwarder in self._forwarders.values():
            forwarder.close()
        if self.context.ok():
            self.node.destroy_node()
            rclpy.shutdown(context=self.context)

    def summary(self) -> str:
        forwarders = sorted(self._forwarders.values(), key=lambda f: f.key)
        each = ", ".join(f"{f.key} {f.sent}" for f in forwarders)
        said = f"ROS 2 over DDS: {self.messages_in} messages in ({each or 'none'}), {self.counts['out']} out"
        dropped = [f"{f.key} {f.dropped}" for f in forwarders if f.dropped]
        if dropped:
            said += f"; dropped, the oldest of a topic's {', '.join(dropped)} (Zenoh did not keep up)"
        failed = [f"{f.key} {f.failed} ({f.error})" for f in forwarders if f.failed]
        if failed:
            said += f"; not put on Zenoh: {', '.join(failed)}"
        return said

    @property
    def messages_in(self) -> int:
        return sum(f.sent for f in self._forwarders.values())


def run_dds_bridge(
    robot: str,
    endpoints: list[str],
    settings: RosSettings | None = None,
    zenoh_config=None,
    stop: threading.Event | None = None,
) -> None:
    """The bridge between the robot's DDS and the services at `endpoints`, until SIGINT/SIGTERM or `stop`."""
    from .transport import open_session, stop_on_signals

    stop = stop or threading.Event()
    stop_on_signals(stop)
    session = open_session(endpoints, base=zenoh_config, wait=None, stop=stop)
    try:
        bridge = DdsBridge(session, robot, settings)
        s = bridge.settings
        inputs = [t for t in (s.points, s.imu, s.odometry, s.tf, s.tf_static) if t]
        maps = s.maps_namespace.replace("{robot}", ros_token(robot))
        print(
            f"[ros-bridge] DDS -> Zenoh: {', '.join(inputs) or 'nothing (AFFORD_ROS__POINTS)'}; "
            f"Zenoh -> DDS: the maps under {maps} and {s.tf_static}",
            flush=True,
        )
        for skipped in bridge.skipped:
            print(f"[ros-bridge] not bridged: {skipped}", flush=True)
        bridge.run(stop)
        print(f"[ros-bridge] {bridge.summary()}", flush=True)
    finally:
        session.close()
