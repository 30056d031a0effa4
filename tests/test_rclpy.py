"""The wire against real ROS 2: the type hashes rmw_zenoh keys carry, and CDR both ways, checked with ROS 2
Kilted's own rclpy and message packages (the [ros2-test] extra, PyPI wheels for CPython 3.11 on x86-64 Linux),
not with rosbags, the library the project makes and reads its messages with. Elsewhere these tests skip.

DDS stays on this machine: discovery is limited to localhost, on a domain of its own."""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags")
rclpy = pytest.importorskip(
    "rclpy", reason="real ROS 2 is not installed: pip install -e '.[ros2-test]' (CPython 3.11, x86-64 Linux)"
)

from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from test_ros_maps import check_confidence, check_markers, check_places, small_map, yaw_of  # noqa: E402

from affordwire import ros, ros_maps  # noqa: E402

# every type the project puts on the wire or reads from it, and the rclpy class of each
TYPES = {
    ros.POINTCLOUD2: ("sensor_msgs.msg", "PointCloud2"),
    ros.IMU: ("sensor_msgs.msg", "Imu"),
    ros.ODOMETRY: ("nav_msgs.msg", "Odometry"),
    ros_maps.PLACES: ("geometry_msgs.msg", "PoseArray"),
    ros_maps.MARKERS: ("visualization_msgs.msg", "MarkerArray"),
    "visualization_msgs/msg/Marker": ("visualization_msgs.msg", "Marker"),
    ros_maps.CONFIDENCE: ("nav_msgs.msg", "OccupancyGrid"),
    ros_maps.GOAL: ("geometry_msgs.msg", "PoseStamped"),
    # a TFMessage is a sequence of these (tf2_msgs has no wheel on PyPI: its own hash is not checked here)
    "geometry_msgs/msg/TransformStamped": ("geometry_msgs.msg", "TransformStamped"),
}


def message_class(typename: str):
    import importlib

    module, name = TYPES[typename]
    return getattr(importlib.import_module(module), name)


@pytest.fixture(scope="module")
def node():
    from rclpy.signals import SignalHandlerOptions

    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ.setdefault(
        "AMENT_PREFIX_PATH", sys.prefix
    )  # the wheels' share/ is the venv's, as a setup.bash says
    os.environ["ROS_DOMAIN_ID"] = str(100 + os.getpid() % 100)  # away from a robot's and other runs'
    context = rclpy.context.Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    made = rclpy.create_node("afford_wire_check", context=context)
    try:
        yield made
    finally:
        made.destroy_node()
        rclpy.shutdown(context=context)


def installed_hash(typename: str) -> str:
    """The RIHS01 hash in the package's installed type description (share/<package>/msg/<Name>.json)."""
    from ament_index_python.packages import get_package_share_directory

    package, _, name = typename.split("/")
    description = json.loads(
        (Path(get_package_share_directory(package)) / "msg" / f"{name}.json").read_text()
    )
    return next(h["hash_string"] for h in description["type_hashes"] if h["type_name"] == typename)


def test_every_type_hash_in_the_project_s_keys_is_real_ros2_s(node):
    """rmw_zenoh's keys end in the type's hash: a key with another hash than the subscriber's matches
    nothing. The project's (rosbags') hashes against the installed definitions and a real publisher's."""
    topics = {typename: f"/afford_check/t{i}" for i, typename in enumerate(TYPES)}
    publishers = [node.create_publisher(message_class(t), topic, 1) for t, topic in topics.items()]
    deadline = time.monotonic() + 10
    reported = {}
    while len(reported) < len(topics) and time.monotonic() < deadline:
        for typename, topic in topics.items():
            info = node.get_publishers_info_by_topic(topic)
            if info:
                reported[typename] = str(info[0].topic_type_hash)
        time.sleep(0.05)
    for typename in TYPES:
        ours = ros_maps.type_hash(typename)
        assert ours == installed_hash(typename) == reported[typename], typename
    for publisher in publishers:
        node.destroy_publisher(publisher)


def _fields(names_offsets, datatype: int = 7):
    from sensor_msgs.msg import PointField

    return [PointField(name=n, offset=o, datatype=datatype, count=1) for n, o in names_offsets]


def test_an_organised_padded_cloud_rclpy_serialises_decodes_right():
    """3 x 4 points, x y z float32 after an intensity, each point padded to 20 bytes and each row by 8 more, a
    missing return as NaN: the finite points come out, in order."""
    from sensor_msgs.msg import PointCloud2

    height, width, point_step, row_step = 3, 4, 20, 4 * 20 + 8
    xyz = np.arange(height * width * 3, dtype=np.float32).reshape(height, width, 3) / 10
    xyz[1, 2] = np.nan
    data = np.zeros((height, row_step), np.uint8)
    for r in range(height):
        for c in range(width):
            data[r, c * point_step + 4 : c * point_step + 16] = np.frombuffer(xyz[r, c].tobytes(), np.uint8)
    message = PointCloud2(height=height, width=width, point_step=point_step, row_step=row_step)
    message.header.frame_id, message.header.stamp.sec = "camera_depth_optical_frame", 1_700_000_000
    message.fields = _fields([("intensity", 0), ("x", 4), ("y", 8), ("z", 12)])
    message.data = data.tobytes()
    cloud = ros.pointcloud2(serialize_message(message))
    finite = xyz.reshape(-1, 3)[np.isfinite(xyz.reshape(-1, 3)).all(axis=1)]
    np.testing.assert_array_equal(cloud.points, finite.astype(np.float64))
    assert (cloud.nonfinite, cloud.total, cloud.frame_id, cloud.stamp) == (
        1,
        12,
        "camera_depth_optical_frame",
        1_700_000_000.0,
    )


def test_a_big_endian_float64_cloud_rclpy_serialises_decodes_right():
    from sensor_msgs.msg import PointCloud2

    xyz = np.array([[1.5, -2.25, 3.0], [0.125, 4.0, -1.0]])
    message = PointCloud2(height=1, width=2, point_step=24, row_step=48, is_bigendian=True, is_dense=True)
    message.fields = _fields([("x", 0), ("y", 8), ("z", 16)], datatype=8)
    message.data = xyz.astype(">f8").tobytes()
    np.testing.assert_array_equal(ros.pointcloud2(serialize_message(message)).points, xyz)


def test_imu_and_odometry_rclpy_serialises_decode_right():
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import Imu

    imu = Imu()
    imu.header.frame_id, imu.header.stamp.sec, imu.header.stamp.nanosec = "imu_link", 12, 500_000_000
    imu.linear_acceleration.x, imu.linear_acceleration.z = 0.5, 9.79
    reading = ros.imu(serialize_message(imu))
    np.testing.assert_allclose(reading.down, -np.array([0.5, 0, 9.79]) / np.hypot(0.5, 9.79))
    assert (reading.frame_id, reading.stamp) == ("imu_link", 12.5)
    odometry = Odometry(child_frame_id="base_link")
    odometry.header.frame_id = "odom"
    odometry.pose.pose.position.x, odometry.pose.pose.position.y = 1.0, -2.0
    half = np.radians(40) / 2
    odometry.pose.pose.orientation.z, odometry.pose.pose.orientation.w = np.sin(half), np.cos(half)
    pose = ros.odometry(serialize_message(odometry))
    assert (pose.frame_id, pose.child_frame_id) == ("odom", "base_link")
    np.testing.assert_allclose(pose.pose[:3, 3], [1.0, -2.0, 0.0])
    np.testing.assert_allclose(pose.pose[:2, 0], [np.cos(2 * half), np.sin(2 * half)], atol=1e-12)


def test_the_maps_the_project_makes_deserialise_in_rclpy():
    from geometry_msgs.msg import PoseArray
    from nav_msgs.msg import OccupancyGrid
    from visualization_msgs.msg import MarkerArray

    message, confidence = small_map()
    colour = (0.2, 0.4, 0.6, 1.0)
    check_places(deserialize_message(ros_maps.pose_array(message, "world"), PoseArray), message)
    check_markers(
        deserialize_message(ros_maps.marker_array(message, "world", colour), MarkerArray), message, colour
    )
    grid = deserialize_message(ros_maps.occupancy_grid(message, "world"), OccupancyGrid)
    check_confidence(grid, message, confidence)


def test_the_next_views_deserialise_in_rclpy_the_best_as_a_goal_on_the_floor():
    from geometry_msgs.msg import PoseArray, PoseStamped

    from affordwire import messages

    message = messages.NextViewsMessage(frame_id="world")
    message.cloud_timestamp.FromNanoseconds(1_700_000_000_250_000_000)
    for x, y, heading in ((1.0, 2.0, 0.5), (3.0, -1.0, -2.5)):
        view = message.views.add(heading=heading, gain=0.4)
        view.pose.position.x, view.pose.position.y, view.pose.position.z = x, y, 1.0
    poses = deserialize_message(ros_maps.view_poses(message, "map"), PoseArray)
    assert poses.header.frame_id == "map" and poses.header.stamp.nanosec == 250_000_000
    assert [(p.position.x, p.position.y, p.position.z) for p in poses.poses] == [(1, 2, 1), (3, -1, 1)]
    assert [yaw_of(p.orientation) for p in poses.poses] == pytest.approx([0.5, -2.5])
    goal = deserialize_message(ros_maps.best_view_goal(message, "map"), PoseStamped)
    assert (goal.pose.position.x, goal.pose.position.y, goal.pose.position.z) == (1, 2, 0)
    assert yaw_of(goal.pose.orientation) == pytest.approx(0.5) and goal.header.frame_id == "map"
    assert ros_maps.best_view_goal(messages.NextViewsMessage(), "map") is None


# -- afford ros-bridge: a robot on plain DDS -----------------------------------------------------------------


@pytest.fixture
def bridged(node, monkeypatch):
    """(the bridge, a zenoh session on its router) for robot1 with /robot1/points and /robot1/imu, spinning
    in a thread."""
    import threading

    from services.dds import DdsBridge
    from services.launch import free_port
    from services.settings import RosSettings
    from services.transport import open_session

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_session([], mode="router", listen=[endpoint])
    bridge_session, client = open_session([endpoint]), open_session([endpoint])
    settings = RosSettings(points="/robot1/points", imu="/robot1/imu")
    bridge = DdsBridge(bridge_session, "robot1", settings, node_name=f"afford_dds_test_{os.getpid()}")
    stop = threading.Event()
    thread = threading.Thread(target=bridge.run, args=(stop,), daemon=True)
    thread.start()
    try:
        yield bridge, client
    finally:
        stop.set()
        thread.join(10)
        for session in (client, bridge_session, router):
            session.close()


def _spin_until(node, condition, timeout: float = 20.0, act=None) -> bool:
    """Spin the node (in its own context) until `condition()`, calling `act()` before each spin."""
    from rclpy.executors import SingleThreadedExecutor

    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    deadline = time.monotonic() + timeout
    try:
        while not condition():
            if time.monotonic() > deadline:
                return False
            if act is not None:
                act()
            executor.spin_once(timeout_sec=0.05)
        return True
    finally:
        executor.remove_node(node)
        executor.shutdown()


def test_the_bridge_carries_a_dds_robot_s_clouds_to_their_keys_and_the_maps_back_latched(node, bridged):
    """A PointCloud2 published on DDS by a real rclpy node reaches the assembler's key as its CDR; a map
    put on Zenoh (as the inference service puts it) reaches a TRANSIENT_LOCAL rclpy subscription that joins
    after it went out."""
    import zenoh
    from geometry_msgs.msg import PoseArray
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from sensor_msgs.msg import PointCloud2

    bridge, client = bridged
    heard = []
    subscriber = client.declare_subscriber("robot1/points", lambda s: heard.append(s.payload.to_bytes()))
    cloud = PointCloud2(height=1, width=2, point_step=12, row_step=24, is_dense=True)
    cloud.header.frame_id = "lidar"
    cloud.fields = _fields([("x", 0), ("y", 4), ("z", 8)])
    cloud.data = np.array([[1, 2, 3], [4, 5, 6]], np.float32).tobytes()
    publisher = node.create_publisher(PointCloud2, "/robot1/points", 10)
    assert _spin_until(node, lambda: publisher.get_subscription_count() > 0)
    # sent until heard: DDS matching on both sides takes a moment
    assert _spin_until(node, lambda: heard, act=lambda: publisher.publish(cloud))
    carried = ros.pointcloud2(heard[0])  # the CDR as DDS carried it (its padding bytes are the writer's)
    np.testing.assert_array_equal(carried.points, [[1, 2, 3], [4, 5, 6]])
    assert carried.frame_id == "lidar"
    subscriber.undeclare()

    message, _ = small_map()
    places = zenoh.ext.declare_advanced_publisher(
        client,
        "robot1/affordances/sitting_relaxing/places",
        cache=zenoh.ext.CacheConfig(1),
        publisher_detection=True,
        sample_miss_detection=zenoh.ext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=0.5),
    )
    places.put(ros_maps.pose_array(message, "world"))
    assert _spin_until(node, lambda: bridge.counts["out"] == 1)
    got = []
    latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    node.create_subscription(PoseArray, "/robot1/affordances/sitting_relaxing/places", got.append, latched)
    assert _spin_until(node, lambda: got)
    check_places(got[0], message)
    places.undeclare()


@pytest.mark.slow
def test_a_ros2_robot_on_dds_gets_its_maps_on_dds_through_the_bridge(node, generated_sequence, tmp_path):
    """A real rclpy node publishes a walk's PointCloud2, Imu and Odometry on Fast DDS (localhost); `afford
    ros-bridge` carries them to the three services and the maps back; a TRANSIENT_LOCAL rclpy subscriber gets
    PoseArray, MarkerArray and OccupancyGrid for every affordance, the PoseArray with the places `afford
    watch` writes from the same maps."""
    import subprocess

    from geometry_msgs.msg import PoseArray
    from nav_msgs.msg import OccupancyGrid, Odometry
    from rclpy.qos import DurabilityPolicy, QoSProfile, qos_profile_sensor_data
    from sensor_msgs.msg import Imu, PointCloud2
    from test_end_to_end import AFFORD, AFFORDANCES, EVERY_FRAME, _check_maps
    from test_ros import odometry_reading, ros_stream, watching
    from visualization_msgs.msg import MarkerArray

    from affordcore.assembly.sequence import read_sequence
    from services.launch import Stack
    from services.ros_maps import map_topics

    sequence = read_sequence(generated_sequence)
    indices = list(range(0, 120, 3))
    topics = {"AFFORD_ROS__POINTS": "/robot1/camera/points", "AFFORD_ROS__IMU": "/robot1/imu"}
    topics["AFFORD_ROS__ODOMETRY"] = "/robot1/odom"
    env = {**EVERY_FRAME, **topics, "AFFORD_ROS__MAPS": "true", "AFFORD_SERVICE__RECORDING_ID": "e2e-dds"}
    stack = Stack(tmp_path / "run", env=env).start()
    bridge = None
    try:
        bridge_env = {**os.environ, **topics, "AFFORD_ROS__MAPS": "true"}
        bridge_log = (tmp_path / "run" / "ros-bridge.log").open("w")  # beside the services' in stack.logs()
        bridge = subprocess.Popen(
            AFFORD + ["ros-bridge", "--connect", stack.endpoint, "--robot", stack.robot],
            env=bridge_env,
            stdout=bridge_log,
            stderr=subprocess.STDOUT,
        )
        watch = watching(stack, tmp_path / "maps", frames=40)
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        received = {}
        for affordance in AFFORDANCES:
            for kind, topic in map_topics("/{robot}/affordances", "robot1", affordance).items():
                cls = {"places": PoseArray, "markers": MarkerArray, "confidence": OccupancyGrid}[kind]
                callback = lambda m, key=(affordance, kind): received.__setitem__(key, m)  # noqa: E731
                node.create_subscription(cls, topic, callback, latched)
        points = node.create_publisher(PointCloud2, "/robot1/camera/points", 10)
        # the readings as drivers publish them (sensor data QoS, best effort): a RELIABLE stream that loses a
        # sample to the clouds' load holds every later one until the writer's next heartbeat (Fast DDS: 3 s)
        imu = node.create_publisher(Imu, "/robot1/imu", qos_profile_sensor_data)
        odometry = node.create_publisher(Odometry, "/robot1/odom", qos_profile_sensor_data)
        publishers = (points, imu, odometry)  # the bridge subscribes to each once it sees its publisher
        assert _spin_until(node, lambda: all(p.get_subscription_count() for p in publishers), timeout=60)
        start = time.time()
        for k, (stamp, cloud, reading) in enumerate(ros_stream(sequence, indices, start, 1 / 30)):
            imu.publish(reading)  # serialized CDR, published as it is
            odometry.publish(odometry_reading(sequence, indices[k], stamp))
            time.sleep(0.005)
            points.publish(cloud)
            time.sleep(1 / 30)
        watched, _ = watch.communicate(timeout=300)
        assert watch.returncode == 0, watched[-3000:] + stack.logs()
        documents = _check_maps(tmp_path / "maps", 40, watched)
        wanted = {(a, k) for a in AFFORDANCES for k in ("places", "markers", "confidence")}

        def final() -> bool:  # every topic heard, and the places those of the last maps
            return wanted <= received.keys() and all(
                len(received[(a, "places")].poses) == len(documents[a]["skeletons"]) for a in AFFORDANCES
            )

        assert _spin_until(node, final, timeout=60), (sorted(received), stack.logs())
    finally:
        if bridge is not None:
            bridge.terminate()
            bridge.wait(timeout=30)
            bridge_log.close()
            said = (tmp_path / "run" / "ros-bridge.log").read_text()
        codes = stack.stop()
    assert codes == {"assembler": 0, "features": 0, "inference": 0, "router": 0}, stack.logs()
    assert sum(len(received[(a, "places")].poses) for a in AFFORDANCES) > 0  # places to compare
    for affordance in AFFORDANCES:
        poses = received[(affordance, "places")].poses
        for pose, skeleton in zip(poses, documents[affordance]["skeletons"]):
            assert (pose.position.x, pose.position.y) == pytest.approx(
                (skeleton["x"], skeleton["y"]), abs=1e-4
            )
    log = (tmp_path / "run" / "assembler.log").read_text()
    assert "40 clouds" in log and "40 with an Imu gravity" in log and "40 with the odometry's pose" in log, (
        log + said
    )
    # every cloud (RELIABLE) and none dropped on the way to Zenoh; a best-effort reading may be lost on DDS
    assert "messages in (robot1/camera/points 40, robot1/imu " in said and "dropped" not in said, said
