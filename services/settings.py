"""The services' settings: the library's (affordcore.settings) and the processes' own, from the same
AFFORD_* environment variables."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, Field, field_validator

from affordcore.settings import Settings


class NodeSettings(BaseModel):
    """What every service process shares (AFFORD_SERVICE__*)."""

    mode: str = Field(
        "client",
        pattern="^(peer|client)$",
        description="zenoh mode of the services and clients: client talks only through the router named by "
        "--connect, so its access control cannot be bypassed; peer also links processes directly",
    )
    zenoh_config: Path | None = Field(
        None,
        description="a zenoh JSON5 config file (TLS certificates, access control, ...) the session starts "
        "from; --connect, --listen and the mode are set on top of it (docs/security.md)",
    )
    recording_id: str = Field(
        "",
        description="Rerun recording id every service shares, so their .rrd files open as one recording; "
        "empty: afford-<robot>",
    )
    status_period: float = Field(5.0, gt=0, description="each service republishes its status this often (s)")
    max_queue: int = Field(
        1000,
        ge=1,
        description="inputs waiting beyond this are refused on the service's error key, not dropped silently",
    )
    max_queue_bytes: int = Field(
        512 * 2**20,
        ge=2**20,
        description="... or beyond this many bytes waiting (one payload larger than this is refused)",
    )
    max_lag: float = Field(
        0.5,
        gt=0,
        description="the assembler passes over a scan that waited longer than this (s) when a newer one "
        "waits, and says so on its status key: it follows the sensor instead of falling behind",
    )
    max_gap: float = Field(
        0.5,
        gt=0,
        description="... as long as the next one waiting arrived within this many seconds of the last scan "
        "taken: the frames registered are never further apart (registration bridges a short gap, its "
        "motion guess spanning the gap's time, not a long one)",
    )
    state: Path | None = Field(
        None,
        description="assembler: folder of its checkpoint (map, trajectory, and a journal of every frame "
        "since), reloaded on start; none: the map lives in memory only",
    )
    downstream_nice: int = Field(
        0,
        ge=0,
        le=19,
        description="features and inference run this much nicer than the assembler. 0: a niced process "
        "cannot be un-niced, and against a robot's other work at the default priority it kept about a tenth "
        "of a core, so the last maps came 10-40 s after the scans stopped (docs/services.md, Latency); the "
        "assembler keeps up by passing over late scans and by publishing fewer maps while behind",
    )
    blas_threads: int = Field(
        1,
        ge=0,
        description="BLAS threads per service process (0: the library's default, one per core): the "
        "services' matrices are thin (points x 3), and a second OpenBLAS thread spin-waits between calls on "
        "the cores the processes share (as `afford map`, affordcli/room.py)",
    )
    map_workers: int = Field(
        0,
        ge=0,
        description="inference (one robot): processes that score the models side by side; 0: one per model "
        "on Linux with 2 cores or more, 1: every model in the service's own process",
    )
    hold_back_superseded: bool = Field(
        True,
        description="features: fields of a map superseded while they were computed (a newer map waits) are "
        "not published, never twice in a row, so that inference maps the newer map without mapping the "
        "older one beside it",
    )
    give_up_stale_maps: bool = Field(
        True,
        description="inference (one robot): maps being made are given up when a newer map reaches the "
        "features service (its status) or newer fields arrive, except right after maps given up, so that "
        "at least every other fields message is mapped: the last map of a walk waits less for stale maps",
    )


class RosSettings(BaseModel):
    """ROS 2 robots (AFFORD_ROS__*): the topics the assembler takes as its robot publishes them over Zenoh,
    with rmw_zenoh or through zenoh-plugin-ros2dds (docs/ros.md). Needs the `[ros]` extra."""

    points: str = Field(
        "",
        description="sensor_msgs/msg/PointCloud2 topic the assembler takes scans from, with its namespace, "
        "e.g. /points or /robot1/points; empty: no ROS 2 input",
    )
    imu: str = Field(
        "",
        description="sensor_msgs/msg/Imu topic whose linear acceleration gives each scan the gravity "
        "measured nearest its time; empty: none (the map is levelled by its floor)",
    )
    odometry: str = Field(
        "",
        description="nav_msgs/msg/Odometry topic (the robot's own odometry, e.g. /odom) giving each scan its "
        "pose guess, interpolated at its time; the assembler then registers with the odometry as a prior "
        "(AFFORD_ASSEMBLER__ODOMETRY_PRIOR); empty: none",
    )
    tf: str = Field(
        "/tf",
        description="tf2_msgs/msg/TFMessage topic of the robot's moving transforms; with tf_static, where "
        "the assembler finds the cloud sensor's mount on the odometry's child frame and the IMU's rotation "
        "to the cloud's frame; empty: not read",
    )
    tf_static: str = Field(
        "/tf_static",
        description="tf2_msgs/msg/TFMessage topic of the robot's fixed transforms (latched: what the robot "
        "published before the assembler started is fetched too); empty: not read",
    )
    base_from_cloud: list[float] | None = Field(
        None,
        description="where the cloud's sensor is mounted on the odometry's child frame (the robot's base): "
        "[x, y, z, qx, qy, qz, qw], e.g. '[0.2,0,0.5,0,0,0,1]', in place of what tf says; none: tf's "
        "transform, and until tf has one, the base's origin with its axes",
    )
    odometry_max_age: float = Field(
        0.1,
        gt=0,
        description="a scan takes odometry readings only within this many seconds of its header stamp",
    )
    reading_wait: float = Field(
        0.1,
        ge=0,
        description="a scan whose odometry or Imu readings have not yet reached its header stamp waits up "
        "to this many seconds after it arrived for one that does (the readings come on their own topics "
        "and can arrive after the scan they belong to); a scan already this late waits no more",
    )
    domain_id: int = Field(0, ge=0, le=232, description="ROS_DOMAIN_ID: the first chunk of rmw_zenoh's keys")
    distribution: Literal["humble", "jazzy", "kilted", "rolling"] = Field(
        "jazzy",
        description="the robot's ROS 2 distribution: on humble the maps' and tf's rmw_zenoh keys carry "
        "TypeHashNotSupported in place of the type's hash, which Humble's subscribers match (the "
        "subscriptions take any hash either way)",
    )
    key_formats: list[Literal["rmw_zenoh", "ros2dds"]] = Field(
        ["rmw_zenoh", "ros2dds"],
        min_length=1,
        description="which key formats to subscribe to: rmw_zenoh's <domain_id>/<topic>/<type>/<type "
        "hash> (any hash) and zenoh-plugin-ros2dds's <topic>",
    )
    cloud_from_imu: list[float] | None = Field(
        None,
        description="rotation (quaternion x, y, z, w) from the IMU's frame to the cloud's, e.g. "
        "'[0,0,0.7071068,0.7071068]', in place of what tf says; none: tf's rotation, and until tf has "
        "one, the IMU's axes taken to be the cloud sensor's",
    )
    imu_max_age: float = Field(
        0.5,
        gt=0,
        description="a scan gets the Imu reading nearest its header stamp only within this many seconds",
    )
    maps: bool = Field(
        False,
        description="the inference service also publishes each affordance's map as ROS 2 topics (places as "
        "geometry_msgs/PoseArray, markers as visualization_msgs/MarkerArray, the confidence as "
        "nav_msgs/OccupancyGrid), latched, in the key formats of key_formats",
    )
    maps_namespace: str = Field(
        "/{robot}/affordances",
        description="the maps' topics are <maps_namespace>/<affordance>/places, .../markers and "
        ".../confidence; {robot} is the robot's name (a character ROS names forbid, such as -, becomes _)",
    )
    maps_frame_id: str = Field(
        "world",
        description="the frame_id of the maps' headers: afford's world (gravity-aligned, z up, floor at "
        "z = 0); with odometry and the maps on, the assembler publishes its pose in the odometry's frame on "
        "tf_static; a name the robot's tf does not use",
    )

    @field_validator("points", "imu", "odometry", "tf", "tf_static")
    @classmethod
    def _ros_name(cls, topic: str) -> str:
        """Checked before the service starts: a wildcard or space would subscribe to what it should not."""
        if topic and not re.fullmatch(r"/?[A-Za-z0-9_~{}]+(/[A-Za-z0-9_~{}]+)*/?", topic):
            raise ValueError(
                f"ROS topic {topic!r} is not a ROS 2 name (letters, digits and _ between slashes, e.g. "
                "/robot1/points)"
            )
        return topic

    @field_validator("maps_namespace")
    @classmethod
    def _ros_namespace(cls, namespace: str) -> str:
        """Checked with a robot's name in place of {robot}: the names the service will publish on."""
        if not re.fullmatch(r"/?[A-Za-z0-9_]+(/[A-Za-z0-9_]+)*/?", namespace.replace("{robot}", "robot")):
            raise ValueError(
                f"maps_namespace {namespace!r} is not a ROS 2 namespace (letters, digits and _ between "
                "slashes, and {robot}; e.g. /{robot}/affordances)"
            )
        return namespace

    @field_validator("maps_frame_id")
    @classmethod
    def _frame_id(cls, frame_id: str) -> str:
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_/]*", frame_id):
            raise ValueError(f"maps_frame_id {frame_id!r} is not a tf frame name (letters, digits, _ and /)")
        return frame_id

    @field_validator("cloud_from_imu")
    @classmethod
    def _unit_quaternion(cls, quaternion: list[float] | None) -> list[float] | None:
        if quaternion is not None and (len(quaternion) != 4 or not _unit(quaternion)):
            raise ValueError(f"cloud_from_imu {quaternion} is not a unit quaternion [x, y, z, w]")
        return quaternion

    @field_validator("base_from_cloud")
    @classmethod
    def _mounting(cls, pose: list[float] | None) -> list[float] | None:
        if pose is not None and (
            len(pose) != 7 or not all(abs(v) < float("inf") for v in pose) or not _unit(pose[3:])
        ):
            raise ValueError(f"base_from_cloud {pose} is not a pose [x, y, z, qx, qy, qz, qw] (a unit q)")
        return pose


def _unit(quaternion: list[float]) -> bool:
    """Whether a quaternion's norm is 1 to within 1e-3 (False for NaN too)."""
    return abs(sum(q * q for q in quaternion) ** 0.5 - 1) <= 1e-3


class ServiceSettings(Settings):
    """Everything a service process reads: the library's settings and `service` (AFFORD_SERVICE__*)."""

    service: NodeSettings = NodeSettings()
    ros: RosSettings = RosSettings()
