"""ROS 2 out: the inference service's maps as ROS 2 topics (AFFORD_ROS__MAPS), so that a robot on ROS 2 gets
them without an afford client. Per robot and affordance, under AFFORD_ROS__MAPS_NAMESPACE
(`/<robot>/affordances` by default):

* `<namespace>/<affordance>/places`: geometry_msgs/msg/PoseArray, the places, likeliest first;
* `<namespace>/<affordance>/markers`: visualization_msgs/msg/MarkerArray, an arrow and a label per place;
* `<namespace>/<affordance>/confidence`: nav_msgs/msg/OccupancyGrid, the confidence map scaled to 0 ... 100.

The bytes are made by affordwire.ros_maps; this module puts them on the keys of both formats services/ros.py
subscribes to (AFFORD_ROS__KEY_FORMATS), as a ROS 2 publisher with rmw_zenoh would (docs/ros.md):

* rmw_zenoh: `<domain>/<topic>/<DDS type>/<RIHS01 hash>` (the real hash of the type: a subscriber's key has
  its own, and a key with another hash would not match it). Each sample carries rmw_zenoh's attachment
  (sequence number, source time, publisher gid): rmw_zenoh's subscriptions drop a sample without one. A
  liveliness token per topic (and one for the node) puts the publishers in the ROS graph, so that `ros2 topic
  list` and RViz2 list the topics with their types.
* zenoh-plugin-ros2dds: `<topic>`, the plain CDR.

Latching (transient_local): every key gets a zenoh AdvancedPublisher with a cache of one sample and publisher
detection, as rmw_zenoh declares a TRANSIENT_LOCAL publisher (rmw_publisher_data.cpp); rmw_zenoh's
TRANSIENT_LOCAL subscriptions are AdvancedSubscribers whose history query reaches that cache, so a subscriber
that joins late gets the newest map.
"""

from __future__ import annotations

import hashlib
import re
import struct
import time

import numpy as np

from affordcore.labels import affordance_colours
from affordwire import messages, ros, ros_maps

from .node import Node
from .ros import dds_type

# rmw_zenoh's QoS field of a liveliness token for a RELIABLE, TRANSIENT_LOCAL, KEEP_LAST 1 publisher, as
# rmw_zenoh writes it (liveliness_utils.cpp, qos_to_keyexpr): what equals its default QoS is left out
# (RELIABLE, KEEP_LAST; deadline, lifespan, liveliness), so durability 1 and depth 1 only
TOKEN_QOS = ":1:,1:,:,:,,"
# the hash chunk of Humble's keys and tokens: Humble has no type hashes, and its subscribers match only this
NO_TYPE_HASH = "TypeHashNotSupported"

TOPICS = {"places": ros_maps.PLACES, "markers": ros_maps.MARKERS, "confidence": ros_maps.CONFIDENCE}


def ros_token(name: str) -> str:
    """A name as one ROS 2 name token: characters ROS forbids (`-`, `.`) become `_`, and a leading digit
    (forbidden too) gets a `_` before it."""
    token = re.sub(r"[^A-Za-z0-9_]", "_", name)
    return f"_{token}" if token[:1].isdigit() else token


def _namespace(namespace: str, robot: str) -> str:
    """AFFORD_ROS__MAPS_NAMESPACE for one robot, without its slashes: 'robot1/affordances'."""
    return namespace.replace("{robot}", ros_token(robot)).strip("/")


def map_topics(namespace: str, robot: str, affordance: str) -> dict[str, str]:
    """{'places': '/robot1/affordances/sitting_relaxing/places', ...} under AFFORD_ROS__MAPS_NAMESPACE."""
    base = _namespace(namespace, robot)
    return {kind: f"/{base}/{ros_token(affordance)}/{kind}" for kind in TOPICS}


def view_topics(namespace: str, robot: str) -> dict[str, str]:
    """{'views': '/robot1/affordances/next_views', 'goal': '/robot1/affordances/next_view_goal'}."""
    base = _namespace(namespace, robot)
    return {"views": f"/{base}/next_views", "goal": f"/{base}/next_view_goal"}


def rmw_zenoh_key(domain_id: int, topic: str, typename: str, distribution: str = "jazzy") -> str:
    return f"{domain_id}/{topic.strip('/')}/{dds_type(typename)}/{key_hash(typename, distribution)}"


def key_hash(typename: str, distribution: str) -> str:
    """The type's RIHS01 hash as rmw_zenoh's keys carry it, or Humble's placeholder."""
    return NO_TYPE_HASH if distribution == "humble" else ros_maps.type_hash(typename)


def attachment(sequence: int, source_time_ns: int, gid: bytes) -> bytes:
    """rmw_zenoh's attachment (attachment_helpers.cpp), in zenoh-ext's serialization: the sequence number
    and the source time as int64 little-endian, then the 16-byte gid as a sequence (its length, 16, as one
    LEB128 byte, then the bytes)."""
    return struct.pack("<qqB", sequence, source_time_ns, len(gid)) + gid


def _mangle(name: str) -> str:
    """rmw_zenoh's mangle_name: a ROS name in one key chunk, `/` as `%`."""
    return name.replace("/", "%")


class LatchedTopics:
    """A service's ROS 2 publishers, each as rmw_zenoh declares a RELIABLE + TRANSIENT_LOCAL one, on the keys
    of every format of AFFORD_ROS__KEY_FORMATS: a zenoh AdvancedPublisher with a cache of one sample, the
    rmw_zenoh attachment on each sample, and liveliness tokens for the topic and the node `node_name` (so
    that `ros2 topic list` and RViz2 see them)."""

    def __init__(self, node: Node, node_name: str):
        import zenoh.ext  # noqa: F401 - the AdvancedPublisher: fail at the start, not at the first sample

        ros_maps.type_hash(ros_maps.PLACES)  # RosUnavailable (pip install affordmap[ros]) at the start too
        self.node, self.settings, self.node_name = node, node.settings.ros, node_name
        self.zid = str(node.session.info.zid())
        self._tokens: list = []
        self._sequence = 0
        self._node_token = False

    def declare(self, topic: str, typename: str) -> list[tuple[str, object, bytes | None]]:
        """(key, publisher, rmw_zenoh gid or None) of the topic on each key format."""
        import zenoh

        if not self._node_token and "rmw_zenoh" in self.settings.key_formats:
            self._node_token = True
            self._liveliness(0, "NN", "")
        keys = []
        if "rmw_zenoh" in self.settings.key_formats:
            keys.append(
                (rmw_zenoh_key(self.settings.domain_id, topic, typename, self.settings.distribution), True)
            )
        if "ros2dds" in self.settings.key_formats:
            keys.append((topic.strip("/"), False))
        publishers = []
        for key, rmw in keys:
            publisher = zenoh.ext.declare_advanced_publisher(
                self.node.session,
                key,
                encoding=zenoh.Encoding("application/cdr"),
                congestion_control=zenoh.CongestionControl.BLOCK,  # rare samples that must arrive
                reliability=zenoh.Reliability.RELIABLE,
                cache=zenoh.ext.CacheConfig(1),  # the newest sample: what a late subscriber gets
                publisher_detection=True,  # lets a late subscriber's history query find this cache
                # as rmw_zenoh's RELIABLE + TRANSIENT_LOCAL publisher: its subscription recovers a missed
                # last sample from the heartbeat's sequence number (and the cache is sequenced by number,
                # so the session needs no timestamping)
                sample_miss_detection=zenoh.ext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=0.5),
            )
            self.node.hold(publisher)
            gid = None
            if rmw:
                entity_id = len(self._tokens) + 1
                ros_type = _mangle(dds_type(typename))
                type_hash = key_hash(typename, self.settings.distribution)
                rest = f"{_mangle(topic)}/{ros_type}/{type_hash}/{TOKEN_QOS}"
                self._liveliness(entity_id, "MP", rest)
                # rmw_zenoh's gid is a hash of the token's key; any 16 bytes unique to the publisher do
                gid = hashlib.sha256(f"{self.zid}/{key}".encode()).digest()[:16]
            publishers.append((key, publisher, gid))
        return publishers

    def put(self, publishers: list[tuple[str, object, bytes | None]], payload: bytes, now: int) -> None:
        """One sample on every key of a topic, `now` its source time (ns)."""
        self._sequence += 1
        for _, publisher, gid in publishers:
            extra = {} if gid is None else {"attachment": attachment(self._sequence, now, gid)}
            publisher.put(payload, **extra)

    def _liveliness(self, entity_id: int, kind: str, rest: str) -> None:
        """A token as rmw_zenoh's liveliness::Entity writes it: @ros2_lv/<domain>/<zid>/<node id>/<entity
        id>/<NN|MP>/<enclave>/<namespace>/<node name>[/<topic>/<type>/<hash>/<qos>]; node id 0."""
        key = f"@ros2_lv/{self.settings.domain_id}/{self.zid}/0/{entity_id}/{kind}/%/%/{self.node_name}"
        key += f"/{rest}" if rest else ""
        self._tokens.append(self.node.hold(self.node.session.liveliness().declare_token(key)))


def ros_node_name(node: Node) -> str:
    """The ROS node name a service appears as: afford_<service>_<robot> (a sharded worker: its worker id)."""
    keys = node.keys  # a robot's, or a sharded worker's (WorkerKeys: no robot, a worker id)
    who = getattr(keys, "robot", None) or getattr(keys, "worker", "worker")
    return f"afford_{ros_token(node.service)}_{ros_token(who)}"


class RosMapOutput:
    """Publishes each map the inference service makes on its ROS 2 topics. Publishers are declared at the
    first map of a (robot, affordance), so that a worker serving many robots declares only what it maps."""

    def __init__(self, node: Node, affordances: list[str], robot: str | None = None):
        """`robot`: the one robot of the service, whose topics are declared now (they are in the ROS graph
        before the first map); None for a sharded worker, which declares a robot's at its first map."""
        self.topics = LatchedTopics(node, ros_node_name(node))
        self.node, self.settings = node, node.settings.ros
        self.colours = affordance_colours(affordances)  # as the recordings colour them
        self._publishers: dict[tuple[str, str], dict[str, list]] = {}
        self._view_publishers: dict[str, dict[str, list]] = {}  # {robot: the next views' publishers}
        self.published = 0
        for affordance in affordances if robot is not None else []:
            self._publishers[(robot, affordance)] = self._declare(robot, affordance)
        example = map_topics(
            self.settings.maps_namespace, robot or "ROBOT", affordances[0] if affordances else "A"
        )
        print(
            f"[{node.service}] ROS 2 out: maps on {example['places'].rsplit('/', 2)[0]}/<affordance>/"
            f"{{places,markers,confidence}} in frame {self.settings.maps_frame_id!r} "
            f"({', '.join(self.settings.key_formats)})"
            + (
                f"; next views on {view_topics(self.settings.maps_namespace, robot or 'ROBOT')['views']}"
                " and the best as a goal on .../next_view_goal"
                if node.settings.next_views.count
                else ""
            ),
            flush=True,
        )

    def _declare(self, robot: str, affordance: str) -> dict[str, list]:
        topics = map_topics(self.settings.maps_namespace, robot, affordance)
        return {kind: self.topics.declare(topic, TOPICS[kind]) for kind, topic in topics.items()}

    def publish(self, robot: str, message: messages.AffordanceMapMessage) -> None:
        """Put one map on its topics (on the service's worker thread)."""
        unit = (robot, message.affordance)
        if unit not in self._publishers:
            self._publishers[unit] = self._declare(robot, message.affordance)
        frame = self.settings.maps_frame_id
        colour = self.colours.get(message.affordance, (0.5, 0.5, 0.5))
        payloads = {
            "places": ros_maps.pose_array(message, frame),
            "markers": ros_maps.marker_array(message, frame, colour),
            "confidence": ros_maps.occupancy_grid(message, frame),
        }
        now = time.time_ns()
        for kind, publishers in self._publishers[unit].items():
            self.topics.put(publishers, payloads[kind], now)
        self.published += 1

    def publish_views(self, robot: str, message: messages.NextViewsMessage) -> None:
        """Put a robot's next views on their topics: every view as a PoseArray, the best as a PoseStamped
        goal (left as it was when there is none)."""
        if robot not in self._view_publishers:
            topics = view_topics(self.settings.maps_namespace, robot)
            self._view_publishers[robot] = {
                "views": self.topics.declare(topics["views"], ros_maps.VIEWS),
                "goal": self.topics.declare(topics["goal"], ros_maps.GOAL),
            }
        frame, now, publishers = self.settings.maps_frame_id, time.time_ns(), self._view_publishers[robot]
        self.topics.put(publishers["views"], ros_maps.view_poses(message, frame), now)
        goal = ros_maps.best_view_goal(message, frame)
        if goal is not None:
            self.topics.put(publishers["goal"], goal, now)

    def summary(self) -> str:
        return f"ROS 2: {self.published} maps published on {3 * len(self._publishers)} topics"


class WorldInTf:
    """afford's world in the robot's tf: with odometry, the assembler publishes on /tf_static (latched) the
    pose of AFFORD_ROS__MAPS_FRAME_ID in the odometry's frame with each map it aligns, so that RViz2 and Nav2
    with the fixed frame `odom`, or `map` where the robot localises (map -> odom), show the maps. The tie is
    the newest frame that came with an odometry pose: registration and odometry drift apart slowly, and the
    maps are right where the robot is. Republished only when it moves (by a millimetre or more)."""

    def __init__(self, node: Node, ros_input):
        self.node, self.ros, self.settings = node, ros_input, node.settings.ros
        self.topics = LatchedTopics(node, ros_node_name(node))
        self.publishers = self.topics.declare(self.settings.tf_static, ros.TFMESSAGE)
        self.last: np.ndarray | None = None
        self.published = 0
        self._said: set[str] = set()

    @staticmethod
    def wanted(settings) -> bool:
        return bool(settings.maps and settings.odometry and settings.tf_static)

    def publish(self, world_from_odom: np.ndarray, stamp: float) -> None:
        tie, parent, frame = self.ros.odom_from_assembler, self.ros.odom_frame, self.settings.maps_frame_id
        if tie is None or parent is None:
            self._say_once("no frame with an odometry pose yet: the maps' frame is not in tf")
            return
        if frame in self.ros.tree:
            self._say_once(
                f"the robot's tf already has a frame {frame!r}: afford's world is not published in it; set "
                "AFFORD_ROS__MAPS_FRAME_ID to a name of its own (e.g. afford_world)"
            )
            return
        odom_from_world = tie @ np.linalg.inv(world_from_odom)
        if self.last is not None and np.allclose(odom_from_world, self.last, atol=1e-3):
            return
        payload = ros.tf_bytes([ros.RosTransform(parent, frame, odom_from_world, stamp)])
        self.topics.put(self.publishers, payload, time.time_ns())
        if self.last is None:
            print(
                f"[{self.node.service}] tf out: {frame!r} in {parent!r} on {self.settings.tf_static}",
                flush=True,
            )
        self.last, self.published = odom_from_world, self.published + 1

    def _say_once(self, text: str) -> None:
        if text not in self._said:
            self._said.add(text)
            print(f"[{self.node.service}] tf out: {text}", flush=True)
