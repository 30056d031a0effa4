"""End to end, as on a robot: a router and the three services as processes on free loopback ports, depth
frames streamed with `afford publish`, the maps awaited with `afford watch`; then every recording must verify
and hold the entities its service logs."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import SHARED_DATA, needs_shared, rrd_verify

from affordcore.mapping.recording import recorded_entities
from services.launch import Stack

AFFORD = [sys.executable, "-m", "affordcli"]  # the command line of this interpreter, as a user runs it

pytestmark = pytest.mark.slow
AFFORDANCES = ("sitting-relaxing", "sitting-working", "standing-working")
KITCHEN = SHARED_DATA / "sequences" / "7scenes_redkitchen_frames_000000-000299"
ENTITIES = {
    "assembler": {
        "/world/odom",
        "/world/odom/sensor",
        "/world/odom/sensor/scan",
        "/world/odom/trajectory",
        "/world/cloud",
    },
    "features": {"/world/fields/occupied", "/world/fields/normals"},  # the cloud is the assembler's
    "inference": {
        f"/world/{name}/{part}" for name in AFFORDANCES for part in ("confidence", "skeletons", "places")
    },
}


# every frame registered however loaded the machine: these tests check the maps; skipping frames to keep up
# is tested on its own (tests/test_reliability.py)
EVERY_FRAME = {"AFFORD_SERVICE__MAX_LAG": "600"}


def _afford(*args: str, timeout: float) -> subprocess.CompletedProcess:
    return subprocess.run(AFFORD + list(args), capture_output=True, text=True, timeout=timeout)


def _stream_and_watch(
    stack: Stack, frames_folder: Path, out: Path, publish_args: list[str], frames: int
) -> str:
    watch = subprocess.Popen(
        AFFORD
        + [
            "watch",
            "--connect",
            stack.endpoint,
            "--robot",
            stack.robot,
            "--frames",
            str(frames),
            "--timeout",
            "300",
            "--out",
            str(out),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    published = _afford(
        "publish",
        str(frames_folder),
        "--connect",
        stack.endpoint,
        "--robot",
        stack.robot,
        "-q",
        *publish_args,
        timeout=300,
    )
    assert published.returncode == 0, published.stderr + stack.logs()
    assert f"published {frames} depth frames" in published.stdout
    output, _ = watch.communicate(timeout=360)
    assert watch.returncode == 0, output[-3000:] + stack.logs()
    return output


def _check_recordings(folder: Path, recording_id: str) -> None:
    from rerun.chunk import RrdReader

    for service, entities in ENTITIES.items():
        rrd = folder / f"{service}.rrd"
        verify = rrd_verify(rrd)
        assert verify.returncode == 0, f"{rrd}: {verify.stdout}{verify.stderr}"
        missing = entities - recorded_entities(rrd)
        assert not missing, f"{service}.rrd lacks {sorted(missing)}"
        # one recording id across the processes: the viewer opens the three files as one recording
        assert [(e.application_id, e.recording_id) for e in RrdReader(str(rrd)).recordings()] == [
            ("affordmap", recording_id)
        ]


def _check_maps(out: Path, frames: int, watched: str) -> dict:
    documents = {}
    for name in AFFORDANCES:
        document = json.loads((out / f"{name}.json").read_text())
        assert document["format"] == "affordance-map/1" and document["affordance"] == name
        world_from_input = np.array(document["world_from_input"])
        assert np.allclose(world_from_input[:3, :3] @ world_from_input[:3, :3].T, np.eye(3), atol=1e-6)
        for skeleton in document["skeletons"]:
            assert np.array(skeleton["joints"]).shape == (15, 3)
        documents[name] = document
    assert f"({frames} frames)" in watched, "the map, fields and maps of every frame must have been published"
    for key in ("map/cloud: map of", "fields: fields", "map/pose: sensor at"):
        assert key in watched, f"watch never saw {key}"
    return documents


def _latest_cloud(stack: Stack):
    """The assembler's latest map cloud, by a get on map/cloud (what the last maps were computed from)."""
    from affordwire import messages
    from services.transport import Keys

    session = stack.session()
    try:
        for reply in session.get(Keys(stack.robot).cloud, timeout=10.0):
            if reply.ok is not None:
                return messages.parse(messages.CloudMessage, reply.ok.payload.to_bytes())
    finally:
        session.close()
    raise AssertionError("the assembler did not answer a get on map/cloud")


def _assert_same_as_afford_map(cloud, documents: dict) -> None:
    """The services' maps are what `afford map`'s path computes from the same cloud: the same places at the
    same scores, the same cut, whatever the models find in this scan."""
    from affordcore.geometry.scene import Cloud
    from affordcore.learn.model import choose_models
    from affordcore.mapping.pipeline import map_affordances, prepare_scene
    from affordcore.settings import Settings
    from affordwire import messages

    settings = Settings()
    seen_from = messages.cloud_origins(cloud)  # the assembler sends where the camera stood: the same carving
    scene = prepare_scene(Cloud(messages.cloud_points(cloud), origins=seen_from), settings, gravity="none")
    maps = map_affordances(scene.fields, scene.layout, choose_models([], [], scene.layout), settings)
    for name in AFFORDANCES:
        expected = maps[name].to_json("", np.eye(4))
        got = documents[name]
        assert got["place_threshold"] == pytest.approx(expected["place_threshold"], abs=1e-3), name
        # assert_allclose compares shapes too: np.allclose would broadcast a missing place against one
        np.testing.assert_allclose(place_rows(got), place_rows(expected), atol=1e-3, err_msg=name)
        assert len(got["positives"]) == len(expected["positives"]), name


def place_rows(document: dict) -> np.ndarray:
    """(n, 5) rows of (x, y, z, theta, score), one per place of an affordance-map/1 document."""
    rows = [[s[k] for k in ("x", "y", "z", "theta", "score")] for s in document["skeletons"]]
    return np.array(rows, dtype=np.float64).reshape(-1, 5)


def _room_from_world(sequence, document: dict) -> np.ndarray:
    """A map's world frame into the generated room's: the odometry frame is the first camera's, whose true
    pose (camera to room) the generator wrote."""
    return sequence.pose(0) @ np.linalg.inv(np.array(document["world_from_input"]))


def _places_in_room(document: dict, room_from_world: np.ndarray) -> np.ndarray:
    """(n, 3) rows of (x, y, facing) of a map's places in the generated room's frame."""
    rows = place_rows(document)
    xyz = rows[:, :3] @ room_from_world[:3, :3].T + room_from_world[:3, 3]
    ahead = np.stack([np.cos(rows[:, 3]), np.sin(rows[:, 3]), np.zeros(len(rows))], axis=1)
    ahead = ahead @ room_from_world[:3, :3].T
    return np.column_stack([xyz[:, :2], np.arctan2(ahead[:, 1], ahead[:, 0])])


def _truth_labels(room, affordance: str) -> list:
    """The generated room's ground-truth labels of an affordance, from the generator (not from a map)."""
    from affordcore.labels import Label

    return [
        Label(d["affordance"], d["facing"], at=d.get("at"), start=d.get("from"), end=d.get("to"))
        for d in room.labels()["labels"]
        if d["affordance"] == affordance
    ]


def assert_a_place_on_a_label(documents: dict, room, sequence) -> None:
    """Some place of the maps (of a walk through the generated `room`, `sequence`) lies at a ground-truth
    label of its affordance, facing its way. The tolerances are DESIGN's (0.15 m, 0.4 rad) plus the
    registration's drift over the walk."""
    from affordcore.labels import angle_gap

    room_from_world = _room_from_world(sequence, documents[AFFORDANCES[0]])

    found = [
        (name, x, y, facing)
        for name, document in documents.items()
        for x, y, facing in _places_in_room(document, room_from_world)
        for label in _truth_labels(room, name)
        if label.distance(np.array([x, y])) <= 0.25 and angle_gap(facing, label.facing) <= 0.5
    ]
    assert found, "no place of the maps is at a place of the room's ground truth"


def _assert_poses_follow_the_true_walk(poses: list, sequence, indices) -> None:
    """The assembler's pose of every frame against the generator's true camera pose relative to the first
    camera (the odometry frame)."""
    from affordwire import messages

    assert len(poses) == len(indices)
    first = np.linalg.inv(sequence.pose(0))
    got = np.array([messages.pose_matrix(messages.parse(messages.Pose, p))[:3, 3] for p in poses])
    want = np.array([(first @ sequence.pose(i))[:3, 3] for i in indices])
    assert np.linalg.norm(want[-1]) > 0.5  # the walk goes somewhere
    # KISS-ICP drifts 0.16 m over this 0.8 m walk (7 degrees of turn); a stuck or lost assembler is 0.8 m off
    assert np.linalg.norm(got - want, axis=1).max() < 0.25


def test_generated_depth_frames_become_affordance_maps_through_the_three_services(
    generated_sequence, generated_room, tmp_path
):
    from affordcore.assembly.sequence import read_sequence
    from services.transport import Keys

    env = {"AFFORD_SERVICE__RECORDING_ID": "e2e-generated", **EVERY_FRAME}
    stack = Stack(tmp_path / "run", env=env).start()
    try:
        session = stack.session()
        poses = []
        subscriber = session.declare_subscriber(
            Keys(stack.robot).pose, lambda sample: poses.append(sample.payload.to_bytes())
        )
        watched = _stream_and_watch(
            stack, generated_sequence, tmp_path / "maps", ["--rate", "30", "--step", "3"], frames=40
        )
        cloud = _latest_cloud(stack)
        subscriber.undeclare()
        session.close()
    finally:
        codes = stack.stop()
    assert codes == {"assembler": 0, "features": 0, "inference": 0, "router": 0}, stack.logs()
    assert cloud.frames == 40
    documents = _check_maps(tmp_path / "maps", 40, watched)
    _assert_same_as_afford_map(cloud, documents)
    sequence = read_sequence(generated_sequence)
    _assert_poses_follow_the_true_walk(poses, sequence, range(0, 120, 3))
    assert_a_place_on_a_label(documents, generated_room, sequence)
    _check_recordings(tmp_path / "run", "e2e-generated")
    assert "0 rejected" in (tmp_path / "run" / "assembler.log").read_text()


@needs_shared
def test_the_real_kitchen_frames_become_affordance_maps_through_the_three_services(tmp_path):
    stack = Stack(tmp_path / "run", env=EVERY_FRAME).start()
    try:
        watched = _stream_and_watch(
            stack, KITCHEN, tmp_path / "maps", ["--rate", "30", "--step", "3"], frames=100
        )
        cloud = _latest_cloud(stack)
    finally:
        codes = stack.stop()
    assert codes == {"assembler": 0, "features": 0, "inference": 0, "router": 0}, stack.logs()
    assert cloud.frames == 100
    _assert_same_as_afford_map(cloud, _check_maps(tmp_path / "maps", 100, watched))
    _check_recordings(tmp_path / "run", f"afford-{stack.robot}")


def _hostile_clouds(rng: np.random.Generator) -> list[bytes]:
    """Another client's bad clouds, as a client built from schemas/ alone would send them: stamped far in the
    future and before 1970, with NaN points, random bytes, 500 points spread over +-50 km, and a room whose
    floor is 0.8 m above the z = 0 its 'world' frame claims (the one refused only once worked on)."""
    from affordwire import messages

    room = np.column_stack([rng.uniform(0, 3, 3000), rng.uniform(0, 3, 3000), np.zeros(3000)])
    future, past, nan, far, raised = (
        messages.cloud_message(points, np.eye(4), "other-client")
        for points in (room, room, room, rng.uniform(-5e4, 5e4, (500, 3)), room + [0, 0, 0.8])
    )
    future.timestamp.seconds = 17_000_000_000  # the year 2508
    past.timestamp.seconds = -86_400
    values = np.frombuffer(nan.data, "<f4").copy()
    values[::7] = np.nan
    nan.data = values.tobytes()
    return [m.SerializeToString() for m in (future, past, nan, far, raised)] + [rng.bytes(2000)]


def test_another_client_s_refused_clouds_never_end_the_operator_s_watch(generated_sequence, tmp_path):
    """The sequence of a new user's report: a burst of another client's hostile clouds, then the robot's
    stream and at once `afford watch --frames N`: the watch shows the refusals and prints the stream's maps;
    a watch started after the stream prints them too."""
    from affordwire import messages
    from services.transport import Keys, encoding_of, put

    stack = Stack(tmp_path / "run", env=EVERY_FRAME).start()
    try:
        session = stack.session()
        for payload in _hostile_clouds(np.random.default_rng(5)):
            put(session, Keys(stack.robot).cloud, payload, encoding_of(messages.CloudMessage))
        publish = subprocess.Popen(
            AFFORD
            + ["publish", str(generated_sequence), "--connect", stack.endpoint, "--robot", stack.robot]
            + ["--rate", "10", "--step", "3", "--frames", "20", "-q"],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        endpoint = ["--connect", stack.endpoint, "--robot", stack.robot, "--frames", "20", "--timeout", "240"]
        at_once = _afford("watch", *endpoint, timeout=300)
        published, _ = publish.communicate(timeout=120)
        later = _afford("watch", *endpoint, timeout=300)
        session.close()
    finally:
        codes = stack.stop()
    assert codes == {"assembler": 0, "features": 0, "inference": 0, "router": 0}, stack.logs()
    assert publish.returncode == 0, published
    for watch in (at_once, later):
        assert watch.returncode == 0, watch.stdout[-3000:] + watch.stderr
        assert all(f"{name:<18}" in watch.stdout for name in AFFORDANCES), watch.stdout[-2000:]
    # the refusals the watch started at once saw or fetched were shown, named, and not taken as its answer
    # (the watch started after the burst: every refusal kept by the service, fetched, each one shown)
    assert at_once.stdout.count("REJECTED 'other-client'") == 4, at_once.stdout[:3000]  # 4 that parsed
    assert "REJECTED an input" in at_once.stdout and "not the cloud waited for" in at_once.stdout
    # five refused; the NaN points' cloud is taken with those points dropped (schemas/), and its maps, which
    # cover no scan of the stream, were not taken as the stream's either
    assert "5 rejected" in (tmp_path / "run" / "features.log").read_text()
