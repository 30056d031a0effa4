"""Recordings in: `afford publish` streams rosbag2 folders (sqlite3 and MCAP storage), single MCAP files and
folders of PLY/PCD scans as afford.v1.Scan messages. Bags are written with rosbags' Writer, the library ROS 2
tools' bags are read with."""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import pytest

pytest.importorskip("rosbags")

from test_ros import (  # noqa: E402
    STORE,
    G,
    cdr,
    cloud_message,
    grid_points,
    imu_message,
    odometry_message,
    ros_stream,
    tf_payload,
    transform_stamped,
)

from affordwire import messages, ros  # noqa: E402

AFFORD = [sys.executable, "-m", "affordcli"]
STORAGES = ("sqlite3", "mcap")


def write_bag(
    path,
    storage: str,
    clouds,
    imus=(),
    topic="/camera/points",
    imu_topic="/imu",
    extra=(),
    odometry=(),
    tf_static=(),
):
    """A rosbag2 folder: `clouds`, `imus` and `odometry` are (stamp, CDR) pairs, written at their stamp's time
    (an Imu or Odometry a moment before, a cloud 5 ms after: received after it was taken); `extra` adds
    topics of other types; `tf_static`: TFMessage CDR payloads on /tf_static, written first."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    plugin = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}[storage]
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        points = writer.add_connection(topic, ros.POINTCLOUD2, typestore=STORE)
        gravity = writer.add_connection(imu_topic, ros.IMU, typestore=STORE) if imus else None
        odom = writer.add_connection("/odom", ros.ODOMETRY, typestore=STORE) if odometry else None
        for name, typename in extra:
            writer.add_connection(name, typename, typestore=STORE)
        if tf_static:
            tf = writer.add_connection("/tf_static", ros.TFMESSAGE, typestore=STORE)
            start = min(stamp for stamp, _ in clouds)
            for payload in tf_static:
                writer.write(tf, int((start - 1) * 1e9), payload)
        for stamp, payload in imus:
            writer.write(gravity, int(stamp * 1e9) - 1000, payload)
        for stamp, payload in odometry:
            writer.write(odom, int(stamp * 1e9) - 1000, payload)
        for stamp, payload in clouds:
            writer.write(points, int(stamp * 1e9) + 5_000_000, payload)
    return path


def small_stream(count: int = 6, start: float = 1_700_000_000.0, imu_frame: str = "lidar"):
    """`count` small organised clouds (with NaN returns) 0.1 s apart and 4 Imu readings per cloud, tilting
    slowly, so that each cloud's gravity says which reading it was given."""
    clouds, imus, downs = [], [], []
    for k in range(count):
        stamp = start + 0.1 * k
        points = grid_points(4, 5, 0.01) + k
        points[0, 0] = np.nan
        sec, nanosec = int(stamp), round((stamp % 1) * 1e9) % 1_000_000_000
        clouds.append((stamp, cdr(cloud_message(points, sec=sec, nanosec=nanosec))))
        for j in range(4):
            at = stamp - 0.05 + 0.025 * j  # readings around the cloud's time: the one at `stamp` is j = 2
            angle = 0.01 * (4 * k + j)
            acceleration = G * np.array([np.sin(angle), 0.0, np.cos(angle)])
            s, n = int(at), round((at % 1) * 1e9) % 1_000_000_000
            message = imu_message(acceleration, sec=s, nanosec=n, frame_id=imu_frame)
            imus.append((at, cdr(message, ros.IMU)))
            if j == 2:
                downs.append(-acceleration / G)
    return clouds, imus, np.array(downs)


def scans_of(path, **options) -> list[messages.Scan]:
    from services.ros import recording_frames

    stats, scans, count = recording_frames(path, **options)
    taken = [scan for _, scan in scans]
    assert len(taken) == count
    return taken


@pytest.mark.parametrize("storage", STORAGES)
def test_a_bag_streams_its_clouds_with_their_stamps_and_the_nearest_imu_gravity(tmp_path, storage):
    clouds, imus, downs = small_stream()
    bag = write_bag(tmp_path / "bag", storage, clouds, imus, extra=[("/chatter", "std_msgs/msg/String")])
    scans = scans_of(bag)
    assert len(scans) == len(clouds)
    for k, scan in enumerate(scans):
        points, _ = messages.unpack_points(scan)
        expected = ros.pointcloud2(clouds[k][1])
        np.testing.assert_allclose(points, expected.points, rtol=1e-6)
        assert len(points) == 19  # one NaN return dropped
        assert messages.seconds(scan.timestamp) == pytest.approx(clouds[k][0], abs=1e-6)  # the header's
        assert scan.frame_id == "lidar"
        np.testing.assert_allclose(messages.gravity_of(scan), downs[k], atol=1e-9)


def test_sqlite3_and_mcap_bags_and_a_lone_mcap_file_give_the_same_scans(tmp_path):
    clouds, imus, _ = small_stream()
    streams = [scans_of(write_bag(tmp_path / storage, storage, clouds, imus)) for storage in STORAGES]
    streams.append(scans_of(tmp_path / "mcap" / "mcap.mcap"))  # one MCAP file, without its metadata.yaml
    first = [scan.SerializeToString() for scan in streams[0]]
    for other in streams[1:]:
        assert [scan.SerializeToString() for scan in other] == first


def test_first_step_frames_and_no_imu_choose_what_is_streamed(tmp_path):
    clouds, imus, _ = small_stream(10)
    bag = write_bag(tmp_path / "bag", "mcap", clouds, imus)
    scans = scans_of(bag, first=1, step=3, frames=2, imu=False)
    assert [messages.seconds(s.timestamp) for s in scans] == pytest.approx([clouds[1][0], clouds[4][0]])
    assert not any(scan.HasField("gravity") for scan in scans)


def odometry_stream(start: float, seconds: float, rate: float = 50.0):
    """A robot's odometry at `rate` Hz: driving along x at 0.5 m/s while turning at 0.5 rad/s, as (stamp,
    CDR) pairs, and the true base pose at any time."""

    def pose(t: float) -> np.ndarray:
        yaw, matrix = 0.5 * (t - start), np.eye(4)
        matrix[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
        matrix[0, 3] = 0.5 * (t - start)
        return matrix

    readings = []
    for k in range(int(seconds * rate) + 1):
        t = start + k / rate
        yaw = 0.5 * (t - start)
        sec, nanosec = int(t), round((t % 1) * 1e9) % 1_000_000_000
        message = odometry_message(
            [0.5 * (t - start), 0, 0], [0, 0, np.sin(yaw / 2), np.cos(yaw / 2)], sec=sec, nanosec=nanosec
        )
        readings.append((t, cdr(message, ros.ODOMETRY)))
    return readings, pose


def test_each_scan_of_a_bag_carries_the_odometry_interpolated_at_its_stamp_on_the_sensor(tmp_path):
    """Clouds at 10 Hz between odometry readings at 50 Hz: each scan's pose guess is the base's pose at the
    cloud's time (the reading after it comes later in the bag), moved to where the sensor is mounted."""
    from services.settings import RosSettings

    clouds, _, _ = small_stream(6, start=1_700_000_000.013)  # off the odometry's 20 ms beat
    readings, truth = odometry_stream(1_700_000_000.0, 0.7)
    bag = write_bag(tmp_path / "bag", "mcap", clouds, odometry=readings)
    mounting = [0.3, 0.0, 0.4, 0.0, 0.0, 0.0, 1.0]  # 30 cm ahead of the base, 40 cm up
    scans = scans_of(bag, settings=RosSettings(base_from_cloud=mounting))
    mounted = ros.rigid_of(mounting)
    for (stamp, _), scan in zip(clouds, scans, strict=True):
        guess = messages.pose_matrix(scan.pose_guess)
        np.testing.assert_allclose(guess, truth(stamp) @ mounted, atol=2e-4)  # linear between readings
    assert not any(scan.HasField("pose_guess") for scan in scans_of(bag, odometry=False))


def test_a_bag_s_tf_static_gives_the_sensor_s_mount_and_the_imu_s_rotation(tmp_path):
    """The same stream with no mount set, but the bag's /tf_static saying where the sensor sits on the base
    and how the IMU is turned: each scan's guess is on the sensor, its gravity in the sensor's frame; an
    unusable TFMessage beside them is left out and reported."""
    from services.ros import recording_frames

    clouds, imus, downs = small_stream(6, start=1_700_000_000.013, imu_frame="imu_link")
    readings, truth = odometry_stream(1_700_000_000.0, 0.7)
    yaw = (0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4))  # the IMU's x is the lidar's y
    tree = tf_payload(
        transform_stamped("base_link", "lidar", [0.3, 0.0, 0.4]),
        transform_stamped("lidar", "imu_link", [0.0, 0.0, 0.1], quaternion=yaw),
    )
    broken = tf_payload(transform_stamped("base_link", "lidar", [np.nan, 0, 0]))
    bag = write_bag(tmp_path / "bag", "mcap", clouds, imus, odometry=readings, tf_static=[tree, broken])
    stats, stream, _ = recording_frames(bag)
    scans = [scan for _, scan in stream]
    mounted = ros.rigid_of([0.3, 0.0, 0.4, 0, 0, 0, 1])
    turn = ros.rotation_of(yaw)
    for (stamp, _), scan, down in zip(clouds, scans, downs, strict=True):
        np.testing.assert_allclose(messages.pose_matrix(scan.pose_guess), truth(stamp) @ mounted, atol=2e-4)
        np.testing.assert_allclose(messages.gravity_of(scan), turn @ down, atol=1e-9)
    assert stats.tf_topics == ("/tf_static",) and stats.bad_tf == 1
    assert "1 unusable TFMessages of /tf_static were left out" in stats.notes()


def test_a_broken_cloud_in_a_bag_is_left_out_and_reported(tmp_path):
    from services.ros import recording_frames

    clouds, _, _ = small_stream(4)
    clouds[2] = (clouds[2][0], clouds[2][1][:60])  # cut short
    stats, scans, count = recording_frames(write_bag(tmp_path / "bag", "sqlite3", clouds))
    assert (count, len(list(scans)), stats.refused) == (4, 3, 1)
    assert "message 2: Could not deserialize" in stats.notes()[0]
    assert stats.imu_topic is None


def _publish(*args: str) -> subprocess.CompletedProcess:
    # nothing listens on port 9: these fail on the recording, before any connection
    return subprocess.run(
        AFFORD + ["publish", *args, "--connect", "tcp/127.0.0.1:9", "--robot", "r1", "--wait", "1"],
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_publish_refuses_a_bag_without_the_cloud_topic_it_needs_and_names_the_topics(tmp_path):
    clouds, imus, _ = small_stream(2)
    no_cloud = tmp_path / "no-cloud"
    from rosbags.rosbag2 import StoragePlugin, Writer

    with Writer(no_cloud, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection("/imu", ros.IMU, typestore=STORE)
        writer.add_connection("/chatter", "std_msgs/msg/String", typestore=STORE)
        for stamp, payload in imus:
            writer.write(connection, int(stamp * 1e9), payload)
    done = _publish(str(no_cloud))
    assert done.returncode == 2, done.stderr
    assert "no sensor_msgs/msg/PointCloud2 topics" in done.stderr
    assert "/chatter (std_msgs/msg/String)" in done.stderr and "/imu (sensor_msgs/msg/Imu)" in done.stderr

    two = write_bag(tmp_path / "two", "sqlite3", clouds, extra=[("/lidar/points", ros.POINTCLOUD2)])
    done = _publish(str(two))
    assert done.returncode == 2 and "2 sensor_msgs/msg/PointCloud2 topics" in done.stderr, done.stderr
    assert "/camera/points, /lidar/points" in done.stderr and "--topic" in done.stderr

    done = _publish(str(two), "--topic", "/points")
    assert done.returncode == 2, done.stderr
    assert "no sensor_msgs/msg/PointCloud2 topic '/points'" in done.stderr
    assert "/camera/points, /lidar/points" in done.stderr

    done = _publish(str(tmp_path / "two" / "two.db3"), "--topic", "/lidar/points", "--imu-topic", "/imu")
    assert done.returncode == 2 and "no sensor_msgs/msg/Imu topic '/imu'" in done.stderr, done.stderr

    done = _publish(str(tmp_path), "--topic", "/points")  # a folder that is not a recording
    assert done.returncode == 2 and "are for ROS 2 recordings" in done.stderr, done.stderr


def test_a_folder_of_ply_and_pcd_scans_is_read_in_natural_name_order(tmp_path):
    import open3d as o3d

    from affordcore.assembly.sequence import read_sequence
    from affordcore.geometry.scene import Cloud, save_cloud
    from services.clients import sequence_messages

    rng = np.random.default_rng(0)
    clouds = [rng.normal(size=(50, 3)) + k for k in range(12)]
    for k, points in enumerate(clouds):  # scan_2 must come before scan_10
        if k % 2:
            save_cloud(tmp_path / f"scan_{k}.ply", Cloud(points))
        else:
            cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
            o3d.io.write_point_cloud(str(tmp_path / f"scan_{k}.pcd"), cloud)
    sequence = read_sequence(tmp_path)
    assert sequence.kind == "cloud"
    assert [p.stem for p in sequence.frames] == [f"scan_{k}" for k in range(12)]
    sent = list(sequence_messages(sequence, range(12)))
    for (_, scan), points in zip(sent, clouds):
        np.testing.assert_allclose(messages.unpack_points(scan)[0], points, atol=1e-5)
    assert sent[0][1].frame_id == "lidar" and not sent[0][1].HasField("gravity")


# -- end to end ----------------------------------------------------------------------------------------------


def _kitchen_like_bag(sequence, folder, storage: str, start: float):
    """The generated sequence's 40 frames (every third) as a robot would record them: organised clouds at
    10 Hz on /camera/depth/points and the IMU on /imu."""
    stream = list(ros_stream(sequence, range(0, 120, 3), start, 0.1))
    clouds = [(stamp, cloud) for stamp, cloud, _ in stream]
    imus = [(stamp, reading) for stamp, _, reading in stream]
    return write_bag(folder, storage, clouds, imus, topic="/camera/depth/points")


@pytest.mark.slow
def test_bags_in_both_storages_stream_into_affordance_maps(generated_sequence, generated_room, tmp_path):
    """The first 20 scans from a sqlite3 bag, the next 20 from the MCAP file of another, into the three
    services: the maps of all 40 come out, the assembler having taken every scan with its IMU gravity."""
    from test_end_to_end import (
        EVERY_FRAME,
        _assert_same_as_afford_map,
        _check_maps,
        _latest_cloud,
        assert_a_place_on_a_label,
    )

    from affordcore.assembly.sequence import read_sequence
    from services.launch import Stack

    sequence = read_sequence(generated_sequence)
    start = time.time() - 3600  # recorded an hour ago: the bag's stamps are kept
    sqlite_bag = _kitchen_like_bag(sequence, tmp_path / "sqlite", "sqlite3", start)
    mcap_file = _kitchen_like_bag(sequence, tmp_path / "mcap", "mcap", start) / "mcap.mcap"
    stack = Stack(tmp_path / "run", env=EVERY_FRAME).start()
    try:
        connect = ["--connect", stack.endpoint, "--robot", stack.robot]
        watch = subprocess.Popen(
            AFFORD
            + ["watch", *connect, "--frames", "40", "--timeout", "240", "--out", str(tmp_path / "maps")],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        published = []
        for source, part in ((sqlite_bag, ["--frames", "20"]), (mcap_file, ["--first", "20"])):
            done = subprocess.run(
                AFFORD + ["publish", str(source), *connect, "--rate", "30", "-q", *part],
                capture_output=True,
                text=True,
                timeout=120,
            )
            assert done.returncode == 0, done.stderr + stack.logs()
            published.append(done.stdout)
        watched, _ = watch.communicate(timeout=300)
        assert watch.returncode == 0, watched[-3000:] + stack.logs()
        cloud = _latest_cloud(stack)
    finally:
        codes = stack.stop()
    assert codes == {"assembler": 0, "features": 0, "inference": 0, "router": 0}, stack.logs()
    assert "published 20 scans of /camera/depth/points" in published[0]
    assert "20 with gravity from /imu" in published[1]
    assert cloud.frames == 40
    assert messages.seconds(cloud.timestamp) == pytest.approx(start + 3.9, abs=1e-3)  # the last scan's stamp
    documents = _check_maps(tmp_path / "maps", 40, watched)
    _assert_same_as_afford_map(cloud, documents)
    assert_a_place_on_a_label(documents, generated_room, sequence)
    assert "0 rejected" in (tmp_path / "run" / "assembler.log").read_text()


@pytest.mark.slow
def test_a_folder_of_ply_scans_streams_into_the_assembler_in_order(generated_sequence, tmp_path):
    """PLY scans named scan_0 ... scan_39, registered by the assembler service: every pose is the one the
    library's assembler gives the scans in their true order (this walk's registration is itself 0.2 m off
    the ground truth, by the depth-frame path alike). In name order scan_10 would come third, and the jump
    is refused by the motion limits: fewer than 40 poses."""
    from test_ros import organised_cloud

    from affordcore.assembly.assembler import Assembler
    from affordcore.assembly.sequence import read_sequence
    from affordcore.geometry.scene import Cloud, load_cloud, save_cloud
    from affordcore.settings import Settings
    from affordwire.sensors import decode_sensor
    from services.launch import Stack
    from services.transport import Keys, schema_of

    sequence = read_sequence(generated_sequence)
    folder = tmp_path / "scans"
    folder.mkdir()
    for k, index in enumerate(range(0, 120, 3)):
        points = organised_cloud(sequence, index).reshape(-1, 3)
        save_cloud(folder / f"scan_{k}.ply", Cloud(points[np.isfinite(points).all(axis=1)]))
    # every scan taken, each registered as a calm assembler does (a busy one registers on fewer points)
    # and on one thread, so that its sums are added in one order: the same poses to the bit in every run
    calm = {
        "AFFORD_SERVICE__MAX_LAG": "600",
        "AFFORD_ASSEMBLER__BUSY_REGISTRATION_VOXELS": "1.5",
        "AFFORD_ASSEMBLER__REGISTRATION_THREADS": "1",
    }
    stack = Stack(tmp_path / "run", env=calm, services=("assembler",)).start()
    try:
        session = stack.session()
        poses, scans = [], []
        subscriber = session.declare_subscriber(
            Keys(stack.robot).pose, lambda s: poses.append(s.payload.to_bytes())
        )
        scan_subscriber = session.declare_subscriber(
            Keys(stack.robot).scans, lambda s: scans.append((schema_of(s), s.payload.to_bytes()))
        )
        done = subprocess.run(
            AFFORD
            + [
                "publish",
                str(folder),
                "--connect",
                stack.endpoint,
                "--robot",
                stack.robot,
                "--rate",
                "30",
                "-q",
            ],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert done.returncode == 0, done.stderr + stack.logs()
        deadline = time.monotonic() + 60
        while len(poses) < 40 and time.monotonic() < deadline:
            time.sleep(0.2)
        subscriber.undeclare()
        scan_subscriber.undeclare()
        session.close()
    finally:
        codes = stack.stop()
    assert codes == {"assembler": 0, "router": 0}, stack.logs()
    assert "published 40 cloud frames" in done.stdout
    assert len(poses) == 40, stack.logs()
    poses = [messages.parse(messages.Pose, pose) for pose in poses]
    got = np.array([messages.pose_matrix(pose)[:3, 3] for pose in poses])
    settings = Settings()
    settings.assembler.registration_threads = 1
    assembler = Assembler(settings.assembler, settings.limits)
    # at the scans' own stamps as the service reads them (its motion guess scales with the time between; a
    # pose carries its scan's stamp to the nanosecond, not to the bit of the float the service worked with)
    stamps = [decode_sensor(schema, payload).stamp for schema, payload in scans]
    assert len(stamps) == 40
    for k, stamp in enumerate(stamps):
        assembler.register(load_cloud(folder / f"scan_{k}.ply").points, stamp)
    want = np.array([pose[:3, 3] for pose in assembler.trajectory.poses])
    assert np.linalg.norm(want[-1]) > 0.5  # the walk goes somewhere
    # the same frames in the same order: the same poses (on many threads the sums' last bits differ from run
    # to run, and ICP along this drifting walk grows them: 1.7 mm by frame 10, 1 cm by frame 40 on a busy CI)
    assert np.abs(got - want).max() < 1e-9
