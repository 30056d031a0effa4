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

from affordcore.labels import affordance_colours
from affordwire import messages, ros_maps

from .node import Node
from .ros import dds_type

# rmw_zenoh's QoS field of a liveliness token (liveliness_utils.cpp, qos_to_keyexpr): reliability
# RELIABLE (1), durability TRANSIENT_LOCAL (1), history KEEP_LAST (1) of depth 1; deadline, lifespan and
# liveliness left to the defaults. Written out, not left to rmw_zenoh's defaults: those changed between
# releases.
TOKEN_QOS = "1:1:1,1:,:,:,,"

TOPICS = {"places": ros_maps.PLACES, "markers": ros_maps.MARKERS, "confidence": ros_maps.CONFIDENCE}


def ros_token(name: str) -> str:
    """A name as one ROS 2 name token: characters ROS forbids (`-`, `.`) become `_`, and a leading digit
    (forbidden too) gets a `_` before it."""
    token = re.sub(r"[^A-Za-z0-9_]", "_", name)
    return f"_{token}" if token[:1].isdigit() else token


def map_topics(namespace: str, robot: str, affordance: str) -> dict[str, str]:
    """{'places': '/robot1/affordances/sitting_relaxing/places', ...} under AFFORD_ROS__MAPS_NAMESPACE."""
    base = namespace.replace("{robot}", ros_token(robot)).strip("/")
    return {kind: f"/{base}/{ros_token(affordance)}/{kind}" for kind in TOPICS}


def rmw_zenoh_key(domain_id: int, topic: str, typename: str) -> str:
    return f"{domain_id}/{topic.strip('/')}/{dds_type(typename)}/{ros_maps.type_hash(typename)}"


def attachment(sequence: int, source_time_ns: int, gid: bytes) -> bytes:
    """rmw_zenoh's attachment (attachment_helpers.cpp), in zenoh-ext's serialization: the sequence number
    and the source time as int64 little-endian, then the 16-byte gid as a sequence (its length, 16, as one
    LEB128 byte, then the bytes)."""
    return struct.pack("<qqB", sequence, source_time_ns, len(gid)) + gid


def _mangle(name: str) -> str:
    """rmw_zenoh's mangle_name: a ROS name in one key chunk, `/` as `%`."""
    return name.replace("/", "%")


class RosMapOutput:
    """Publishes each map the inference service makes on its ROS 2 topics. Publishers are declared at the
    first map of a (robot, affordance), so that a worker serving many robots declares only what it maps."""

    def __init__(self, node: Node, affordances: list[str], robot: str | None = None):
        """`robot`: the one robot of the service, whose topics are declared now (they are in the ROS graph
        before the first map); None for a sharded worker, which declares a robot's at its first map."""
        import zenoh.ext  # noqa: F401 - the AdvancedPublisher: fail at the start, not at the first map

        ros_maps.type_hash(ros_maps.PLACES)  # RosUnavailable (pip install affordmap[ros]) at the start too
        self.node, self.settings = node, node.settings.ros
        self.colours = affordance_colours(affordances)  # as the recordings colour them
        self.zid = str(node.session.info.zid())
        self._publishers: dict[tuple[str, str], list[tuple[str, str, object, bytes | None]]] = {}
        self._tokens: list = []
        self._sequence = 0
        self._node_token = False
        self.published = 0
        for affordance in affordances if robot is not None else []:
            self._publishers[(robot, affordance)] = self._declare(robot, affordance)
        example = map_topics(
            self.settings.maps_namespace, robot or "ROBOT", affordances[0] if affordances else "A"
        )
        print(
            f"[{node.service}] ROS 2 out: maps on {example['places'].rsplit('/', 2)[0]}/<affordance>/"
            f"{{places,markers,confidence}} in frame {self.settings.maps_frame_id!r} "
            f"({', '.join(self.settings.key_formats)})",
            flush=True,
        )

    def _liveliness(self, entity_id: int, kind: str, rest: str) -> None:
        """A token as rmw_zenoh's liveliness::Entity writes it: @ros2_lv/<domain>/<zid>/<node id>/<entity
        id>/<NN|MP>/<enclave>/<namespace>/<node name>[/<topic>/<type>/<hash>/<qos>]; node id 0."""
        keys = self.node.keys  # a robot's, or a sharded worker's (WorkerKeys: no robot, a worker id)
        name = (
            f"afford_inference_{ros_token(getattr(keys, 'robot', None) or getattr(keys, 'worker', 'worker'))}"
        )
        key = f"@ros2_lv/{self.settings.domain_id}/{self.zid}/0/{entity_id}/{kind}/%/%/{name}"
        key += f"/{rest}" if rest else ""
        self._tokens.append(self.node.hold(self.node.session.liveliness().declare_token(key)))

    def _declare(self, robot: str, affordance: str) -> list:
        import zenoh
        import zenoh.ext

        if not self._node_token and "rmw_zenoh" in self.settings.key_formats:
            self._node_token = True
            self._liveliness(0, "NN", "")
        publishers = []
        for kind, topic in map_topics(self.settings.maps_namespace, robot, affordance).items():
            typename = TOPICS[kind]
            keys = []
            if "rmw_zenoh" in self.settings.key_formats:
                keys.append((rmw_zenoh_key(self.settings.domain_id, topic, typename), True))
            if "ros2dds" in self.settings.key_formats:
                keys.append((topic.strip("/"), False))
            for key, rmw in keys:
                publisher = zenoh.ext.declare_advanced_publisher(
                    self.node.session,
                    key,
                    encoding=zenoh.Encoding("application/cdr"),
                    congestion_control=zenoh.CongestionControl.BLOCK,  # a map is rare and must arrive
                    reliability=zenoh.Reliability.RELIABLE,
                    cache=zenoh.ext.CacheConfig(1),  # the newest map: what a late subscriber gets
                    publisher_detection=True,  # lets a late subscriber's history query find this cache
                    # as rmw_zenoh's RELIABLE + TRANSIENT_LOCAL publisher: its subscription recovers a
                    # missed last sample from the heartbeat's sequence number (and the cache is sequenced
                    # by number, so the session needs no timestamping)
                    sample_miss_detection=zenoh.ext.MissDetectionConfig(
                        heartbeat=None, sporadic_heartbeat=0.5
                    ),
                )
                self.node.hold(publisher)
                gid = None
                if rmw:
                    entity_id = len(self._tokens) + 1
                    ros_type = _mangle(dds_type(typename))
                    rest = f"{_mangle(topic)}/{ros_type}/{ros_maps.type_hash(typename)}/{TOKEN_QOS}"
                    self._liveliness(entity_id, "MP", rest)
                    # rmw_zenoh's gid is a hash of the token's key; any 16 bytes unique to the publisher do
                    gid = hashlib.sha256(f"{self.zid}/{key}".encode()).digest()[:16]
                publishers.append((kind, key, publisher, gid))
        return publishers

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
        self._sequence += 1
        now = time.time_ns()
        for kind, _, publisher, gid in self._publishers[unit]:
            extra = {} if gid is None else {"attachment": attachment(self._sequence, now, gid)}
            publisher.put(payloads[kind], **extra)
        self.published += 1

    def summary(self) -> str:
        return f"ROS 2: {self.published} maps published on {3 * len(self._publishers)} topics"
