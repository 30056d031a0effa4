"""The services over a real Zenoh router on loopback: bad input is answered on the error key while the service
keeps going, latest outputs are served to a late `get`, liveliness and status are there, and a stop closes
the recording. Services run in threads here (fast); tests/test_end_to_end.py runs them as processes."""

from __future__ import annotations

import queue
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import eventually, rrd_verify

from affordcore.geometry.features import FeatureLayout
from affordcore.learn.model import choose_models
from affordcore.mapping.recording import recorded_entities
from affordwire import messages
from services.clients import _publisher
from services.launch import free_port
from services.node import Node
from services.settings import ServiceSettings
from services.transport import Keys, encoding_of, open_session

ROBOT = "testbot"
FIELDS = messages.SceneFieldsMessage
KEYS = Keys(ROBOT)


@pytest.fixture
def router():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = open_session([], mode="router", listen=[endpoint])
    yield endpoint
    session.close()


@pytest.fixture
def client(router):
    session = open_session([router])
    yield session
    session.close()


class Running:
    """A service in a thread, stopped (and its recording closed) at the end."""

    def __init__(
        self, service_class, name: str, endpoint: str, rrd: Path, settings: ServiceSettings | None = None
    ):
        settings = settings or ServiceSettings()
        models = choose_models([], ["sitting-relaxing"], FeatureLayout.from_settings(settings))
        self.node = Node(
            name, ROBOT, [endpoint], settings, rrd, affordances=["sitting-relaxing"], models=models
        )
        self.service = service_class(self.node)
        self.thread = threading.Thread(target=self.service.run, daemon=True)
        self.thread.start()

    def stop(self) -> None:
        self.node.stop_event.set()
        self.thread.join(30)
        assert not self.thread.is_alive(), "the service did not stop"


def _listen(session, key: str) -> queue.Queue:
    inbox: queue.Queue = queue.Queue()
    session.declare_subscriber(
        key, lambda sample: inbox.put((str(sample.encoding), sample.payload.to_bytes()))
    )
    return inbox


def _send(session, key: str, payload: bytes, message_class) -> None:
    publisher = _publisher(session, key, message_class, wait=10)
    publisher.put(payload)
    publisher.undeclare()


def _next(inbox: queue.Queue, message_class, timeout: float = 30):
    encoding, payload = inbox.get(timeout=timeout)
    assert encoding == f"application/protobuf;{messages.schema_name(message_class)}"
    return messages.parse(message_class, payload)


def _alive(session) -> list[str]:
    return [
        str(r.ok.key_expr)
        for r in session.liveliness().get(KEYS.key("status", "*"), timeout=2)
        if r.ok is not None
    ]


def _box_room_scan(rng: np.random.Generator, n: int = 20_000) -> np.ndarray:
    """Points of a 4 x 3 x 2.5 m room (floor, two walls) and a 0.45 m high seat box, in a z-up frame."""
    floor = np.column_stack([rng.uniform(0, 4, n), rng.uniform(0, 3, n), np.zeros(n)])
    wall_x = np.column_stack([np.zeros(n // 2), rng.uniform(0, 3, n // 2), rng.uniform(0, 2.5, n // 2)])
    wall_y = np.column_stack([rng.uniform(0, 4, n // 2), np.zeros(n // 2), rng.uniform(0, 2.5, n // 2)])
    seat = np.column_stack([rng.uniform(1, 2, n // 4), rng.uniform(1, 1.6, n // 4), np.full(n // 4, 0.45)])
    return np.vstack([floor, wall_x, wall_y, seat])


def test_the_assembler_rejects_bad_scans_with_a_reason_and_keeps_registering(router, client, tmp_path):
    from services.assembler import AssemblerService

    errors = _listen(client, KEYS.error("assembler"))
    poses = _listen(client, KEYS.pose)
    running = Running(AssemblerService, "assembler", router, tmp_path / "assembler.rrd")
    try:
        _send(client, KEYS.scan("cam"), b"\x08\x96\x01 not protobuf at all", messages.Scan)
        error = _next(errors, messages.Error)
        assert error.service == "assembler" and error.key == KEYS.scan("cam")
        assert "not a valid afford.v1.Scan" in error.reason

        wrong_size = messages.DepthFrame(width=640, height=480, depth=b"\x00" * 100, depth_scale=0.001)
        wrong_size.intrinsics.fx = wrong_size.intrinsics.fy = 585
        _send(client, KEYS.scan("cam"), wrong_size.SerializeToString(), messages.DepthFrame)
        assert "depth holds 100 bytes" in _next(errors, messages.Error).reason

        # a message of another schema
        client.put(KEYS.scan("cam"), b"{}", encoding=encoding_of(messages.Status))
        assert (
            "expected encoding application/protobuf with schema afford.v1.Scan or afford.v1.DepthFrame"
            in _next(errors, messages.Error).reason
        )

        rng = np.random.default_rng(0)
        room = _box_room_scan(rng) - [2.0, 1.5, 1.2]  # the sensor in the middle of the room
        for k in range(3):
            scan = messages.Scan(frame_id="lidar")
            messages.pack_points(scan, room + [0.02 * k, 0, 0])
            _send(client, KEYS.scan("cam"), scan.SerializeToString(), messages.Scan)
            pose = _next(poses, messages.Pose)
        moved = messages.pose_matrix(pose)[:3, 3]
        assert moved[0] == pytest.approx(-0.04, abs=0.01), (
            "three scans 2 cm apart: the sensor moved 4 cm against x"
        )
        assert errors.empty()

        replies = list(client.get(KEYS.status("assembler"), timeout=5))
        status = messages.parse(messages.Status, replies[0].ok.payload.to_bytes())
        assert (status.accepted, status.rejected) == (3, 3)
    finally:
        running.stop()


def test_the_assembler_publishes_fewer_maps_while_scans_wait(router, client, tmp_path):
    """Behind the sensor, a map at most every busy_publish_period (features and inference leave the cores to
    the assembler); keeping up, every publish_period; the last map once the scans stop, either way."""
    from services.assembler import AssemblerService

    settings = ServiceSettings()
    settings.assembler.publish_period, settings.assembler.busy_publish_period = 0.0, 600.0
    settings.service.max_lag = 60.0  # every scan of the burst is taken, none passed over
    clouds, poses = _listen(client, KEYS.cloud), _listen(client, KEYS.pose)
    running = Running(AssemblerService, "assembler", router, tmp_path / "assembler.rrd", settings)
    room = _box_room_scan(np.random.default_rng(0)) - [2.0, 1.5, 1.2]

    def scan(k: int) -> bytes:
        message = messages.Scan(frame_id="lidar")
        messages.pack_points(message, room + [0.01 * k, 0, 0])
        messages.stamp(message.timestamp, 1_700_000_000.0 + 0.1 * k)
        return message.SerializeToString()

    def maps_of(scans: range, burst: bool) -> list[int]:
        """Frames of each map cloud published while `scans` go in (all at once, or each once the last is
        registered), and the one after they stop."""
        publisher = _publisher(client, KEYS.scan("cam"), messages.Scan, wait=10)
        for k in scans:
            publisher.put(scan(k))
            if not burst:
                _next(poses, messages.Pose)
        for _ in scans if burst else ():
            _next(poses, messages.Pose)
        publisher.undeclare()
        last = scans[-1] + 1
        frames = []
        while not frames or frames[-1] < last:
            frames.append(_next(clouds, messages.CloudMessage).frames)
        return frames

    try:
        in_step = maps_of(range(4), burst=False)
        assert in_step == [1, 2, 3, 4], "keeping up: a map after every scan (publish_period 0)"
        burst = maps_of(range(4, 12), burst=True)
        assert len(burst) <= 2 and burst[-1] == 12, f"behind: the maps of {burst} frames"
    finally:
        running.stop()


def test_the_assembler_says_why_its_scans_make_no_map_until_one_sees_a_floor(router, client, tmp_path):
    """`Status.no_output`: set when the map of the scans taken cannot be levelled, cleared by the next scan
    taken (whether that makes a map is not known until it is tried), and empty once a map goes out."""
    from services.assembler import AssemblerService

    settings = ServiceSettings()
    settings.assembler.publish_period = 0.0
    clouds, poses = _listen(client, KEYS.cloud), _listen(client, KEYS.pose)
    running = Running(AssemblerService, "assembler", router, tmp_path / "assembler.rrd", settings)
    room = _box_room_scan(np.random.default_rng(0)) - [2.0, 1.5, 1.2]
    walls = room[
        np.abs(room[:, 2] - np.array([-1.2, -0.75])[:, None]).min(axis=0) > 0.01
    ]  # no floor, no seat
    publisher = _publisher(client, KEYS.scan("cam"), messages.Scan, wait=10)

    def send(points: np.ndarray) -> None:
        message = messages.Scan(frame_id="lidar")
        messages.pack_points(message, points)
        messages.stamp(message.timestamp)
        message.gravity.z = -9.81  # an IMU's: the walls alone cannot be taken for a floor
        publisher.put(message.SerializeToString())
        _next(poses, messages.Pose)

    try:
        send(walls)
        assert eventually(lambda: _status(client, "assembler").no_output, timeout=30)
        status = _status(client, "assembler")
        assert "1 frames, no map yet" in status.no_output and "floor" in status.no_output, status.no_output
        assert clouds.empty()
        send(room + [0.1, 0, 0])  # the room with its floor, 10 cm on (a keyframe): levelled, and it goes out
        assert _next(clouds, messages.CloudMessage).frames == 2
        assert _status(client, "assembler").no_output == ""
    finally:
        publisher.undeclare()
        running.stop()


def _status(client, service: str) -> messages.Status:
    replies = [r.ok for r in client.get(KEYS.status(service), timeout=5) if r.ok is not None]
    return messages.parse(messages.Status, replies[0].payload.to_bytes())


def _fields_of(client, cloud: messages.CloudMessage, timeout: float = 60):
    """The fields the features service answers a get with, once they are those of `cloud`."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for reply in client.get(KEYS.fields, timeout=2):
            if reply.ok is not None:
                message = messages.parse(messages.SceneFieldsMessage, reply.ok.payload.to_bytes())
                if message.cloud_timestamp == cloud.timestamp:
                    return message
        time.sleep(0.2)
    raise AssertionError("the fields of the cloud never arrived")


def test_features_level_a_cloud_in_its_own_frame_refuse_a_world_one_without_a_floor_and_serve_the_latest(
    router, client, tmp_path
):
    from scipy.spatial.transform import Rotation

    from services.features import FeaturesService

    errors = _listen(client, KEYS.error("features"))
    running = Running(FeaturesService, "features", router, tmp_path / "features.rrd")
    try:
        assert not list(client.get(KEYS.fields, timeout=2)), "no fields before any map"
        room = _box_room_scan(np.random.default_rng(1))
        raised = messages.cloud_message(room + [0, 0, 0.8], np.eye(4), "file", at=1_700_000_001.5)
        _send(client, KEYS.cloud, raised.SerializeToString(), messages.CloudMessage)
        error = _next(errors, messages.Error)
        assert "floor at z = 0, but its floor is at z = +0.80 m" in error.reason
        assert error.input_timestamp == raised.timestamp, "the refusal names the cloud it answers"
        assert (error.input_source, error.key) == ("file", KEYS.cloud)
        status = _status(client, "features")
        assert not status.HasField("newest_input"), "a refused cloud is not the newest the service has"
        # its fields were made beside the check, with a copy of the normals: none of them is kept
        assert len(running.service.normals.points) == 0
        # a client that starts waiting after the refusal finds it: the service answers a get with it
        import zenoh

        every = zenoh.ConsolidationMode.NONE
        replies = client.get(KEYS.error("*"), consolidation=every)
        kept = [messages.parse(messages.Error, r.ok.payload.to_bytes()) for r in replies]
        assert [(e.input_timestamp, e.reason) for e in kept] == [(raised.timestamp, error.reason)]

        # the same room y-up with its floor 1.2 m below the frame's origin, sent in its own frame: levelled
        camera_from_world = np.eye(4)
        camera_from_world[:3, :3] = Rotation.from_euler("x", -90, degrees=True).as_matrix()  # z up -> y up
        camera_from_world[:3, 3] = [0.3, -1.2, 0.5]
        in_camera = room @ camera_from_world[:3, :3].T + camera_from_world[:3, 3]
        sensor = np.array([[3.0, 2.0, 1.5]]) @ camera_from_world[:3, :3].T + camera_from_world[:3, 3]
        cloud = messages.cloud_message(
            in_camera, np.eye(4), "file", frames=7, at=1_700_000_002.5, origins=sensor
        )
        cloud.frame_id = "camera"
        _send(client, KEYS.cloud, cloud.SerializeToString(), messages.CloudMessage)
        fields_message = _fields_of(client, cloud)
        fields = messages.scene_fields(fields_message)
        assert fields_message.frames == 7
        world_from_camera = messages.pose_matrix(fields_message.world_from_input)
        # levelling finds up and the floor; where the room is in plan (x, y, yaw) stays the camera's
        world = in_camera @ world_from_camera[:3, :3].T + world_from_camera[:3, 3]
        assert np.abs(world[room[:, 2] == 0, 2]).max() < 0.02, "the floor is at z = 0"
        np.testing.assert_allclose(world[:, 2], room[:, 2], atol=0.02)
        seat = fields.lattice.voxel_of(world[[-1]])[0]
        assert fields.occupancy[tuple(seat)] == 1 and fields.distance[tuple(seat)] == 0
        # the sensor position came along, levelled with the points: the air above the seat was seen
        from affordcore.geometry.visibility import FREE, UNKNOWN

        assert fields.visibility is not None
        above_seat, under_floor = fields.lattice.voxel_of(np.array([[1.5, 1.3, 1.0], [1.5, 1.3, -0.5]]))
        assert fields.visibility[tuple(above_seat)] == FREE
        assert fields.visibility[tuple(under_floor)] == UNKNOWN
        status = _status(client, "features")
        assert status.newest_input == cloud.timestamp
        assert "gravity alignment (auto): up = input +y" in status.detail

        assert eventually(lambda: _alive(client) == [KEYS.status("features")]), _alive(client)
    finally:
        running.stop()
    assert eventually(lambda: _alive(client) == []), "the liveliness token outlived the service"
    entities = recorded_entities(tmp_path / "features.rrd")
    assert {"/world/fields/occupied", "/world/fields/normals"} <= entities
    assert "/world/cloud" not in entities  # the assembler's: one process logs an entity


def test_features_hold_back_the_fields_of_a_map_superseded_while_they_were_computed(
    router, client, tmp_path, capsys
):
    """A map that comes while the fields of the last are computed makes those stale: they are not published
    (inference would map them beside the newer), but never twice in a row, so a stream of maps still gets
    every other map's fields."""
    from services.features import FeaturesService

    fields, status = _listen(client, KEYS.fields), _listen(client, KEYS.status("features"))
    running = Running(FeaturesService, "features", router, tmp_path / "features.rrd")
    rng = np.random.default_rng(2)
    clouds = [  # sizes that tell their "computing the fields of N points" apart, and take a while
        messages.cloud_message(_box_room_scan(rng, n), np.eye(4), "file", at=1_700_000_010.5 + k)
        for k, n in enumerate((400_000, 400_004, 400_008))
    ]

    said = []

    def when_busy_on(cloud) -> None:
        points = f"{len(messages.cloud_points(cloud)):,} points"
        while True:
            said.append(_next(status, messages.Status).detail)
            if said[-1].startswith("computing the fields") and said[-1].endswith(points):
                return

    try:
        _send(client, KEYS.cloud, clouds[0].SerializeToString(), messages.CloudMessage)
        for earlier, later in zip(clouds, clouds[1:]):
            when_busy_on(earlier)
            _send(client, KEYS.cloud, later.SerializeToString(), messages.CloudMessage)
        published = [_next(fields, FIELDS).cloud_timestamp for _ in range(2)]
        assert published == [clouds[1].timestamp, clouds[2].timestamp]  # the first held back, not the second
        assert fields.empty()
        while not status.empty():
            said.append(_next(status, messages.Status).detail)
        assert sum(d.startswith("held back the fields") for d in said) == 1, said
    finally:
        running.stop()
    assert "fields held back, their map superseded while computed: 1" in capsys.readouterr().out


def test_inference_refuses_fields_at_another_resolution_facing_kind_or_normals(router, client, tmp_path):
    from affordcore.geometry.fields import compute_fields
    from affordcore.settings import NORMAL_ESTIMATORS, NormalSettings, Settings, VoxelSettings
    from services.inference import InferenceService

    errors = _listen(client, KEYS.error("inference"))
    running = Running(InferenceService, "inference", router, tmp_path / "inference.rrd")
    try:
        points = _box_room_scan(np.random.default_rng(3))
        cloud = messages.cloud_message(points, np.eye(4), "file")
        coarse = compute_fields(points, VoxelSettings(resolution=0.2))
        _send(client, KEYS.fields, messages.fields_message(coarse, cloud).SerializeToString(), FIELDS)
        assert "fields at 0.2 m voxels" in _next(errors, messages.Error).reason
        # the shipped models were trained on normals facing the room's centre
        floor_facing = compute_fields(points, normal_settings=NormalSettings(steep_facing="floor"))
        _send(client, KEYS.fields, messages.fields_message(floor_facing, cloud).SerializeToString(), FIELDS)
        assert "steep normals facing 'floor'" in _next(errors, messages.Error).reason
        # and on binary fields
        soft = compute_fields(points, VoxelSettings(fields="soft"))
        _send(client, KEYS.fields, messages.fields_message(soft, cloud).SerializeToString(), FIELDS)
        assert (
            "soft fields; the models here were trained on binary ones" in _next(errors, messages.Error).reason
        )
        # and on the normals of one estimator
        (other,) = set(NORMAL_ESTIMATORS) - {Settings().normals.estimator}
        estimated = compute_fields(points, normal_settings=NormalSettings(estimator=other))
        _send(client, KEYS.fields, messages.fields_message(estimated, cloud).SerializeToString(), FIELDS)
        assert f"fields with normals by '{other}'" in _next(errors, messages.Error).reason
    finally:
        running.stop()


def test_inference_updates_the_maps_of_a_changed_room_as_a_mapping_from_scratch_would(
    router, client, tmp_path
):
    from affordcore.geometry.fields import compute_fields
    from affordcore.mapping.pipeline import map_affordances
    from services.inference import InferenceService

    maps = _listen(client, KEYS.affordance("sitting-relaxing"))
    running = Running(InferenceService, "inference", router, tmp_path / "inference.rrd")
    try:
        rng = np.random.default_rng(3)
        room = _box_room_scan(rng)
        grown = np.vstack([room, rng.uniform([3.0, 2.2, 0.0], [3.4, 2.6, 0.5], (3000, 3))])  # a box put down
        for points in (room, grown):
            fields = compute_fields(points)
            message = messages.fields_message(fields, messages.cloud_message(points, np.eye(4), "file"))
            _send(client, KEYS.fields, message.SerializeToString(), messages.SceneFieldsMessage)
            received = _next(maps, messages.AffordanceMapMessage, timeout=60)
        assert eventually(lambda: "rescored" in _status(client, "inference").detail, timeout=10)
        detail = _status(client, "inference").detail
        assert "updated" in detail and int(detail.split("updated: ")[1].split(" %")[0]) < 100, detail
        scratch = map_affordances(fields, running.service.layout, running.service.models)["sitting-relaxing"]
        np.testing.assert_array_equal(
            np.frombuffer(received.confidence, "<f4").reshape(scratch.confidence.shape), scratch.confidence
        )
    finally:
        running.stop()


def test_inference_gives_up_maps_a_newer_map_at_the_features_service_supersedes_but_never_twice(
    router, client, tmp_path
):
    """The features service's status says a newer map reached it: fields of an older map are not mapped
    (they would be stale before done), except right after maps given up; fields of that newer map are."""
    from affordcore.geometry.fields import compute_fields
    from services.inference import InferenceService

    maps = _listen(client, KEYS.affordance("sitting-relaxing"))
    running = Running(InferenceService, "inference", router, tmp_path / "inference.rrd")
    try:
        room = _box_room_scan(np.random.default_rng(4))
        fields = compute_fields(room)
        forged = messages.Status(service="features", state=messages.Status.BUSY)
        forged.newest_input.seconds = 10**12  # beyond AFFORD_LIMITS__LATEST_TIMESTAMP: no newer map at all
        newer = messages.Status(service="features", state=messages.Status.BUSY)
        newer.newest_input.FromNanoseconds(1_700_000_100 * 10**9)
        publisher = _publisher(client, KEYS.status("features"), messages.Status, wait=10)
        publisher.put(forged.SerializeToString())
        publisher.put(b"\xff not a status")
        publisher.put(newer.SerializeToString())  # as the features service says it, on its status key
        publisher.undeclare()
        assert eventually(lambda: running.service.features_newest == 1_700_000_100 * 10**9, timeout=10)

        def send(at: float) -> None:
            cloud = messages.cloud_message(room, np.eye(4), "file", at=at)
            message = messages.fields_message(fields, cloud)
            _send(client, KEYS.fields, message.SerializeToString(), messages.SceneFieldsMessage)

        send(1_700_000_090.5)  # older than what the features service has: given up before it begins
        assert eventually(lambda: running.service.given_up == 1, timeout=30)
        send(1_700_000_091.5)  # older too, but right after maps given up: mapped
        assert messages.seconds(_next(maps, messages.AffordanceMapMessage).cloud_timestamp) == 1_700_000_091.5
        send(1_700_000_100.0)  # the newer map itself
        assert messages.seconds(_next(maps, messages.AffordanceMapMessage).cloud_timestamp) == 1_700_000_100.0
        assert maps.empty()
        assert running.service.given_up == 1
    finally:
        running.stop()


def test_a_service_process_runs_on_one_blas_thread_unless_told_otherwise(monkeypatch):
    from threadpoolctl import threadpool_info

    from services.registry import limit_blas

    def blas_threads() -> set[int]:
        return {pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"}

    limits = limit_blas(ServiceSettings())
    try:
        assert blas_threads() == {1}
    finally:
        limits.restore_original_limits()
    monkeypatch.setenv("AFFORD_SERVICE__BLAS_THREADS", "0")
    assert limit_blas(ServiceSettings()) is None


def test_a_robot_name_must_be_one_key_chunk():
    for bad in ("", "a/b", "r*", "@x", "two words"):
        with pytest.raises(ValueError, match="one non-empty key chunk"):
            Keys(bad)
    assert Keys("r2").affordance("sitting-relaxing") == "afford/@v1/r2/affordance/sitting-relaxing"


@pytest.mark.slow  # the gRPC sink gives up on the absent viewer after about 10 s
def test_a_recording_whose_viewer_is_absent_still_writes_the_whole_file(tmp_path):
    import subprocess
    import sys

    from affordcore.mapping.recording import close_recording, log_cloud, open_recording

    rrd = tmp_path / "sub" / "with-viewer.rrd"
    recording = open_recording(
        rrd, ["sitting-relaxing"], "absent-viewer", viewer=f"rerun+http://127.0.0.1:{free_port()}/proxy"
    )
    log_cloud(recording, np.random.default_rng(0).uniform(0, 3, (5000, 3)))
    warning = close_recording(recording, timeout=1.0)
    assert warning is not None and "viewer unreachable" in warning
    verify = subprocess.run(
        [sys.executable, "-m", "rerun", "rrd", "verify", str(rrd)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert verify.returncode == 0, verify.stderr
    assert "/world/cloud" in recorded_entities(rrd)


# -- afford publish, each kind of source ---------------------------------------------------------------------


def _afford(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "affordcli", *args], capture_output=True, text=True, timeout=120
    )


def test_publish_as_map_sends_the_room_in_the_world_frame(router, client, tmp_path):
    from affordcore.geometry.scene import Cloud, save_cloud

    points = _box_room_scan(np.random.default_rng(5))
    y_up = points[:, [0, 2, 1]] * [1, 1, -1] + [0, 0.8, 0]  # y up, floor at y = +0.8
    save_cloud(tmp_path / "room.ply", Cloud(y_up))
    np.save(tmp_path / "room.origins.npy", np.array([[3.0, 1.5, -2.0]]))  # 1.5 m up, y-up like the room
    clouds = _listen(client, KEYS.cloud)
    result = _afford("publish", str(tmp_path / "room.ply"), "--as-map", "--connect", router, "--robot", ROBOT)
    assert result.returncode == 0, result.stderr
    assert f"as the map of robot {ROBOT} ({len(points):,} points)" in result.stdout
    cloud = _next(clouds, messages.CloudMessage)
    world = messages.cloud_points(cloud)
    assert cloud.source == "room.ply" and len(world) == len(points)
    np.testing.assert_allclose(world[:20_000, 2], 0.0, atol=1e-3)  # the floor (first rows), now at z = 0
    np.testing.assert_allclose(world[-5_000:, 2], 0.45, atol=1e-3)  # the seat (last rows), 0.45 m above it
    assert world[:, 2].max() == pytest.approx(2.5, abs=0.05)  # the walls stand up along z
    transform = messages.pose_matrix(cloud.world_from_input)
    np.testing.assert_allclose(y_up @ transform[:3, :3].T + transform[:3, 3], world, atol=1e-4)
    np.testing.assert_allclose(messages.cloud_origins(cloud)[0, 2], 1.5 - 0.8, atol=1e-3)  # over the floor


def test_publish_sends_a_cloud_file_as_one_scan(router, client, tmp_path):
    from affordcore.geometry.scene import Cloud, save_cloud

    points = np.random.default_rng(6).uniform(-2, 2, (500, 3))
    save_cloud(tmp_path / "scan.npy", Cloud(points))
    scans = _listen(client, KEYS.scan("velodyne"))
    result = _afford(
        "publish", str(tmp_path / "scan.npy"), "--sensor", "velodyne", "--connect", router, "--robot", ROBOT
    )
    assert result.returncode == 0, result.stderr
    scan = _next(scans, messages.Scan)
    assert scan.frame_id == "velodyne"
    np.testing.assert_allclose(messages.unpack_points(scan)[0], points, atol=1e-6)  # float32 on the wire


def test_publish_with_no_service_listening_says_so_and_exits_2(router, tmp_path):
    from affordcore.geometry.scene import Cloud, save_cloud

    save_cloud(tmp_path / "scan.npy", Cloud(np.zeros((10, 3))))
    result = _afford(
        "publish", str(tmp_path / "scan.npy"), "--connect", router, "--robot", ROBOT, "--wait", "1"
    )
    assert result.returncode == 2
    assert f"nothing subscribes to afford/@v1/{ROBOT}/scan/sensor after 1 s" in result.stderr


def test_afford_serve_runs_a_service_until_sigterm(router, client, tmp_path):
    """The command docker/compose.yaml runs: up (its liveliness token seen), then a clean stop on SIGTERM with
    its recording closed. A service that scores nothing starts whatever the feature layout: only inference
    needs models that match it."""
    import os
    import signal

    command = [
        sys.executable,
        "-m",
        "affordcli",
        "serve",
        "features",
        "--connect",
        router,
        "--robot",
        ROBOT,
        "--rrd",
        str(tmp_path / "features.rrd"),
    ]
    env = {**os.environ, "AFFORD_FEATURES__CELL_SIZE": "0.5"}  # the shipped models' layout is 0.25 m cells
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        deadline = time.monotonic() + 60
        while KEYS.status("features") not in _alive(client):
            assert process.poll() is None, process.stdout.read()
            assert time.monotonic() < deadline, "afford serve features did not come up within 60 s"
            time.sleep(0.3)
        process.send_signal(signal.SIGTERM)
        output, _ = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 0, output
    assert "[features] stopped: 0 inputs taken, 0 rejected" in output
    verify = rrd_verify(tmp_path / "features.rrd")  # closed whole at the stop: a cut-off file fails here
    assert verify.returncode == 0, verify.stdout + verify.stderr


def test_a_cloud_refused_after_it_superseded_a_good_one_gives_that_one_back(router, client, tmp_path):
    """Validate before any state changes: a malformed cloud is refused on arrival and supersedes nothing; a
    sound-looking cloud refused later (a 'world' cloud without its floor at 0) gives back the good cloud it
    superseded, whose fields then come, as they would have without it."""
    from services.features import FeaturesService

    fields, errors = _listen(client, KEYS.fields), _listen(client, KEYS.error("features"))
    status = _listen(client, KEYS.status("features"))
    running = Running(FeaturesService, "features", router, tmp_path / "features.rrd")
    rng = np.random.default_rng(5)
    busy = messages.cloud_message(_box_room_scan(rng, 400_000), np.eye(4), "file", at=1_700_000_020.5)
    good = messages.cloud_message(_box_room_scan(rng), np.eye(4), "good", at=1_700_000_021.5)
    raised = messages.cloud_message(_box_room_scan(rng) + [0, 0, 0.8], np.eye(4), "bad", at=1_700_000_022.5)
    malformed = messages.cloud_message(_box_room_scan(rng), np.eye(4), "torn", at=1_700_000_023.5)
    malformed.data = malformed.data[:-5]
    try:
        _send(client, KEYS.cloud, busy.SerializeToString(), messages.CloudMessage)
        computing = f"computing the fields of {len(messages.cloud_points(busy)):,} points"
        while _next(status, messages.Status).detail != computing:
            pass
        for cloud in (
            good,
            malformed,
            raised,
        ):  # good waits; the torn one is refused at once; raised supersedes
            _send(client, KEYS.cloud, cloud.SerializeToString(), messages.CloudMessage)
        refused = [_next(errors, messages.Error) for _ in range(2)]
        assert [(e.input_source, e.input_timestamp) for e in refused] == [
            ("torn", malformed.timestamp),
            ("bad", raised.timestamp),
        ]
        # the busy cloud's fields were held back for a newer cloud; that one was refused: the good one is next
        assert _next(fields, FIELDS).cloud_timestamp == good.timestamp
        assert eventually(lambda: _status(client, "features").state == messages.Status.READY)
        counts = _status(client, "features")
        assert (counts.accepted, counts.rejected, counts.skipped) == (2, 2, 0), counts
        assert counts.newest_input == good.timestamp, "the refused clouds are not the newest"
        assert fields.empty()
    finally:
        running.stop()


def test_inference_maps_the_fields_it_gave_up_for_a_newer_map_the_features_service_then_refused(
    router, client, tmp_path
):
    from affordcore.geometry.fields import compute_fields
    from services.inference import InferenceService

    maps = _listen(client, KEYS.affordance("sitting-relaxing"))
    running = Running(InferenceService, "inference", router, tmp_path / "inference.rrd")
    try:
        room = _box_room_scan(np.random.default_rng(6))
        cloud = messages.cloud_message(room, np.eye(4), "file", at=1_700_000_090.5)
        publisher = _publisher(client, KEYS.status("features"), messages.Status, wait=10)

        def features_newest(at: float) -> None:  # as the features service says it, on its status key
            said = messages.Status(service="features", state=messages.Status.BUSY)
            said.newest_input.FromNanoseconds(int(at * 1e9))
            publisher.put(said.SerializeToString())
            assert eventually(lambda: running.service.features_newest == int(at * 1e9), timeout=10)

        features_newest(1_700_000_100.0)  # a newer cloud reached the features service
        message = messages.fields_message(compute_fields(room), cloud)
        _send(client, KEYS.fields, message.SerializeToString(), messages.SceneFieldsMessage)
        assert eventually(lambda: running.service.given_up == 1, timeout=30)
        assert maps.empty()
        features_newest(1_700_000_090.5)  # ... and was refused there: these fields are the newest again
        assert messages.seconds(_next(maps, messages.AffordanceMapMessage).cloud_timestamp) == 1_700_000_090.5
        publisher.undeclare()
    finally:
        running.stop()


def test_every_publication_on_a_session_blocks_on_a_full_queue_rather_than_dropping():
    """zenoh's default congestion control (DROP) loses a multi-megabyte cloud when the transmission queue is
    full, as it is under load: every put and publisher the services and clients make on a session says
    BLOCK (services/transport does; the DDS bridge once did not, and lost a cloud in forty)."""
    import ast

    publishing = {"put", "declare_publisher", "declare_advanced_publisher"}
    unblocked = []
    root = Path(__file__).parents[1]
    for path in sorted(p for package in ("services", "affordcli") for p in (root / package).rglob("*.py")):
        for call in ast.walk(ast.parse(path.read_text())):
            if not (isinstance(call, ast.Call) and isinstance(call.func, ast.Attribute)):
                continue
            on = [ast.unparse(call.func.value)] + [ast.unparse(a) for a in call.args[:1]]
            if call.func.attr in publishing and any(o.endswith("session") for o in on):
                if "congestion_control" not in {k.arg for k in call.keywords}:
                    unblocked.append(f"{path.name}:{call.lineno} {ast.unparse(call.func)}")
    assert unblocked == []
