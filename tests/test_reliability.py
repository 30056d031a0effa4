"""Hostile and unlucky input, piece by piece: the limits every message is checked against, an assembler that
changes nothing when it refuses a frame, its checkpoint and journal, inboxes bounded in bytes that thin a
stream they cannot follow, and a node that answers any exception on its error key. The services under fire
as processes: tests/test_hostile.py."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from affordcore.assembly.assembler import Assembler
from affordcore.assembly.checkpoint import AssemblerStore, read_journal
from affordcore.geometry.fields import compute_fields
from affordcore.settings import LimitSettings, VoxelSettings
from affordwire import messages
from affordwire.messages import MessageError
from affordwire.sensors import decode_sensor
from services.node import Inbound, Inbox, unused_path

SCAN = messages.schema_name(messages.Scan)


def _room_points(rng: np.random.Generator, n: int = 6000) -> np.ndarray:
    """A 5 x 4 m room's floor, three walls and a table, in a frame 1.5 m above the floor: what a sensor at
    the origin sees."""
    floor = np.column_stack([rng.uniform(-2.5, 2.5, n), rng.uniform(-2, 2, n), np.full(n, -1.5)])
    wall = np.column_stack([np.full(n // 2, 2.5), rng.uniform(-2, 2, n // 2), rng.uniform(-1.5, 1, n // 2)])
    side = np.column_stack([rng.uniform(-2.5, 2.5, n // 2), np.full(n // 2, 2), rng.uniform(-1.5, 1, n // 2)])
    back = np.column_stack(
        [rng.uniform(-2.5, 2.5, n // 2), np.full(n // 2, -2), rng.uniform(-1.5, 1, n // 2)]
    )
    table = np.column_stack(
        [rng.uniform(0.5, 1.5, n // 4), rng.uniform(-0.5, 0.5, n // 4), np.full(n // 4, -0.75)]
    )
    return np.vstack([floor, wall, side, back, table])


def _moved(points: np.ndarray, x: float, yaw_deg: float = 0.0) -> np.ndarray:
    """The same room seen from a sensor moved `x` m along x and turned `yaw_deg` (points in its frame)."""
    yaw = np.radians(yaw_deg)
    rotation = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    return (points - [x, 0, 0]) @ rotation


@pytest.fixture(scope="module")
def room():
    return _room_points(np.random.default_rng(0))


def _walk(assembler: Assembler, room: np.ndarray, steps: range, stamp0: float = 100.0, store=None) -> None:
    for k in steps:
        record = assembler.register(_moved(room, 0.04 * k, 1.0 * k), stamp0 + 0.1 * k)
        if store is not None:
            store.append(record)


def _state(assembler: Assembler) -> tuple:
    return (
        assembler.frames,
        assembler.keyframes,
        len(assembler.map_points()),
        assembler.odometry.last_pose.copy(),
    )


# -- the assembler refuses without changing anything ---------------------------------------------------------


def _turned(x: float, yaw_deg: float) -> np.ndarray:
    """A pose moved `x` along x and turned `yaw_deg` about z: the sensor of `_moved`."""
    yaw, pose = np.radians(yaw_deg), np.eye(4)
    pose[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    pose[0, 3] = x
    return pose


def test_an_odometry_that_jumps_is_taken_as_a_reset_and_the_frame_kept(room):
    """A robot's odometry restarted (back at its origin) or relocalised jumps further than the robot can
    move: the frame is still good. Refused, every later frame would be measured from the old odometry and
    refused too; taken, the map would be flung 50 m. So the frame is registered without it, with a note, and
    the next guesses follow from this one."""
    assembler = Assembler()
    for k in range(6):  # the odometry is exact here
        assembler.register(_moved(room, 0.04 * k, 1.0 * k), 100.0 + 0.1 * k, pose_guess=_turned(0.04 * k, k))
    reset = np.eye(4)
    reset[0, 3] = 50.0  # the odometry starts again, 50 m off
    jumped = assembler.register(_moved(room, 0.24, 6), 100.6, pose_guess=reset @ _turned(0.0, 0.0))
    assert "taken as a reset" in jumped.note and "faster than AFFORD_LIMITS__MAX_SPEED" in jumped.note
    np.testing.assert_allclose(jumped.pose[:3, 3], [0.24, 0, 0], atol=0.03)  # where the frame is
    after = assembler.register(
        _moved(room, 0.28, 7), 100.7, pose_guess=reset @ _turned(0.04, 1.0) @ np.eye(4)
    )
    assert after.note == ""  # measured from the reset odometry: 4 cm and 1 degree
    np.testing.assert_allclose(after.pose[:3, 3], [0.28, 0, 0], atol=0.03)


def test_a_refused_frame_leaves_the_assembler_as_it_was(room):
    assembler = Assembler()
    _walk(assembler, room, range(4))
    last = assembler.trajectory.stamps[-1] + 0.1
    assembler.register(_moved(room, 0.16, 4), last, pose_guess=np.eye(4))  # the robot's odometry starts
    before = _state(assembler)
    next_frame = _moved(room, 0.2, 5)
    refusals = {
        "not after the last frame": lambda: assembler.register(next_frame, last),
        "must be finite": lambda: assembler.register(np.full((500, 3), np.nan), last + 0.1),
        "outside 0": lambda: assembler.register(next_frame, 9.3e9),
        "not a direction": lambda: assembler.register(next_frame, last + 0.1, gravity=np.zeros(3)),
        "not a rigid transform": lambda: assembler.register(next_frame, last + 0.1, np.diag([1, 1, -1, 1.0])),
        "not a finite 4 x 4": lambda: assembler.register(next_frame, last + 0.1, np.eye(3)),
    }
    for reason, refuse in refusals.items():
        with pytest.raises(ValueError, match=reason):
            refuse()
        after = _state(assembler)
        assert after[:3] == before[:3], reason
        np.testing.assert_array_equal(after[3], before[3])
    # and it goes on registering where it was, its guesses measured from the last accepted one
    assembler.register(next_frame, last + 0.1, pose_guess=np.eye(4))
    assert assembler.frames == before[0] + 1


def test_a_pose_guess_rigid_only_to_rounding_is_registered_not_a_crash():
    """A guess read from text (9 decimals) is orthogonal to about 1e-9: within the check, but KISS-ICP's
    Sophus aborts the process beyond 1e-10. Run in a child process: an abort takes the process with it."""
    script = f"""
import sys; sys.path.insert(0, {str(Path(__file__).parent)!r})
import numpy as np
from test_reliability import _moved, _room_points, _walk
from affordcore.assembly.assembler import Assembler
room = _room_points(np.random.default_rng(0))
assembler = Assembler()
_walk(assembler, room, range(3))
guess = np.eye(4)
for k in (3, 4, 5):
    guess = guess.copy()
    guess[0, 3] = 0.04 * k
    guess[:3, :3] += 3e-9 * np.array([[0, 1, -1], [1, 0, 1], [-1, 1, 0]])  # rigid to the 9th decimal
    assembler.register(_moved(room, 0.04 * k, 1.0 * k), 100.0 + 0.1 * k, pose_guess=guess)
print(assembler.frames)
"""
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.split()[-1] == "6"


def test_a_pose_far_beyond_the_largest_extent_is_refused(room):
    assembler = Assembler(limits=LimitSettings(max_extent=0.1, max_speed=100))
    _walk(assembler, room, range(2))
    with pytest.raises(ValueError, match="MAX_EXTENT"):
        _walk(assembler, room, range(2, 6))
    # the walk steps 0.04 m a frame: 0 m, 0.04 m and 0.08 m are within 0.1 m, the fourth frame (0.12 m) not
    assert assembler.frames == 3


# -- checkpoint and journal ----------------------------------------------------------------------------------


def test_a_restored_assembler_has_every_journaled_frame_and_goes_on(room, tmp_path):
    live = Assembler()
    store = AssemblerStore(tmp_path / "state")
    _walk(live, room, range(6), store=store)
    store.snapshot(live)  # frames 0-5 in the snapshot, the journal empty
    _walk(live, room, range(6, 10), store=store)  # 6-9 in the journal only
    assert [r.index for r in read_journal(store.journal_path)] == [6, 7, 8, 9]
    store.close()

    restored = Assembler()
    assert AssemblerStore(tmp_path / "state").restore(restored) == 10
    assert restored.keyframes == live.keyframes
    np.testing.assert_allclose(restored.trajectory.stamps, live.trajectory.stamps)
    np.testing.assert_allclose(np.array(restored.trajectory.poses), np.array(live.trajectory.poses))
    same = {tuple(p) for p in np.round(restored.map_points(), 6)} == {
        tuple(p) for p in np.round(live.map_points(), 6)
    }
    assert same
    # registration resumes from the last pose against the refilled local map: the next frame gets the pose
    # the live assembler gives it to a millimetre (a restored assembler stuck at the last pose would be 4 cm
    # off; the refilled local map holds the global map's cell means, not the live one's first points)
    frame = _moved(room, 0.4, 10)
    record = restored.register(frame, 101.0)
    np.testing.assert_allclose(record.pose, live.register(frame, 101.0).pose, atol=1e-3)
    # and that pose is where the frame was taken from: 0.4 m along x, turned 10 degrees
    np.testing.assert_allclose(record.pose[:3, 3], [0.4, 0, 0], atol=0.02)


def test_a_restored_assembler_levels_as_the_last_map_was_and_a_cleared_store_holds_nothing(room, tmp_path):
    """The world frame of the last map published outlives a kill (the snapshot before it had an older one, or
    none): the first map after a restart is levelled as the last map before it, so the robot's world frame
    does not move. A reset's `clear` leaves a new map to begin."""
    live = Assembler()
    store = AssemblerStore(tmp_path)
    _walk(live, room, range(4), store=store)
    store.snapshot(live)  # no map published yet: no world frame in it
    _walk(live, room, range(4, 6), store=store)
    world_from_odom = np.eye(4)
    world_from_odom[:3, 3] = [0.1, -0.2, 1.3]  # as a map published after the snapshot levelled it
    store.save_alignment(world_from_odom)
    store.close()
    restored = Assembler()
    assert AssemblerStore(tmp_path).restore(restored) == 6
    np.testing.assert_array_equal(restored.world_from_odom, world_from_odom)
    AssemblerStore(tmp_path).clear()
    fresh = Assembler()
    assert AssemblerStore(tmp_path).restore(fresh) == 0 and fresh.world_from_odom is None


def test_a_journal_cut_short_by_a_kill_loses_only_the_unfinished_frame(room, tmp_path):
    live = Assembler()
    store = AssemblerStore(tmp_path)
    _walk(live, room, range(5), store=store)
    store.close()
    data = store.journal_path.read_bytes()
    store.journal_path.write_bytes(data[:-100])  # the last record half-written
    restored = Assembler()
    assert AssemblerStore(tmp_path).restore(restored) == 4
    # the cut tail is gone, so new records follow whole ones
    assert [r.index for r in read_journal(tmp_path / "journal.bin")] == [0, 1, 2, 3]


def test_a_journal_that_outlived_its_snapshot_replays_nothing_twice(room, tmp_path):
    live = Assembler()
    store = AssemblerStore(tmp_path)
    _walk(live, room, range(5), store=store)
    journal = store.journal_path.read_bytes()
    store.snapshot(live)  # a kill between writing the snapshot and emptying the journal:
    store.close()
    store.journal_path.write_bytes(journal)
    restored = Assembler()
    assert AssemblerStore(tmp_path).restore(restored) == 5
    assert restored.keyframes == live.keyframes


# -- messages against the limits -----------------------------------------------------------------------------


def _scan(points: np.ndarray, at: float = 1.7e9) -> messages.Scan:
    scan = messages.Scan(frame_id="lidar")
    messages.pack_points(scan, points)
    messages.stamp(scan.timestamp, at)
    return scan


@pytest.mark.parametrize("seconds", [-1.0, 9.3e9, 2e11])
def test_timestamps_outside_the_sane_range_are_refused(room, seconds):
    scan = _scan(room)
    scan.timestamp.seconds = int(seconds)
    with pytest.raises(MessageError, match="LATEST_TIMESTAMP"):
        decode_sensor(SCAN, scan.SerializeToString())


def test_sizes_beyond_the_limits_are_refused_before_they_are_read(room):
    limits = LimitSettings(max_points=1000, max_depth_pixels=100)
    with pytest.raises(MessageError, match="MAX_POINTS"):
        decode_sensor(SCAN, _scan(room).SerializeToString(), limits)
    depth = messages.depth_frame_message(np.zeros((20, 30), np.uint16), np.diag([500.0, 500.0, 1.0]))
    with pytest.raises(MessageError, match="MAX_DEPTH_PIXELS"):
        decode_sensor(messages.schema_name(messages.DepthFrame), depth.SerializeToString(), limits)
    wide = np.vstack([room, [[300.0, 0, 0]]])
    with pytest.raises(MessageError, match="MAX_EXTENT"):
        messages.cloud_points(messages.cloud_message(wide, np.eye(4), "x", at=1.7e9))


def test_fields_grids_are_capped_before_allocation():
    points = np.array([[0.0, 0, 0], [60, 60, 0], [30, 30, 1]])
    with pytest.raises(ValueError, match="MAX_VOXELS"):
        compute_fields(points, VoxelSettings(max_voxels=1_000_000))
    with pytest.raises(ValueError, match="finite"):
        compute_fields(np.array([[0.0, 0, np.nan]] * 10))


@pytest.fixture(scope="module")
def fields_message(room):
    cloud = messages.cloud_message(_moved(room, 0, 0) + [0, 0, 1.5], np.eye(4), "test", at=1.7e9)
    fields = compute_fields(messages.cloud_points(cloud))
    return messages.fields_message(fields, cloud, at=1.7e9)


@pytest.mark.parametrize(
    "spoil, reason",
    [
        (
            lambda m: setattr(m, "distance", np.full(len(m.distance) // 4, np.nan, "<f4").tobytes()),
            "distance",
        ),
        (lambda m: setattr(m, "normals", np.full(len(m.normals) // 4, np.inf, "<f4").tobytes()), "normals"),
        (lambda m: setattr(m, "occupancy", b"\x07" * len(m.occupancy)), "occupancy"),
        (lambda m: setattr(m.grid.origin, "x", float("nan")), "origin"),
        (lambda m: setattr(m.grid, "nx", 2**31), "MAX_VOXELS"),
        (lambda m: setattr(m.cloud_timestamp, "seconds", 10**10), "LATEST_TIMESTAMP"),
        (lambda m: setattr(m, "x_max", float("nan")), "footprint"),
    ],
)
def test_fields_that_would_poison_the_maps_are_refused(fields_message, spoil, reason):
    message = messages.SceneFieldsMessage()
    message.CopyFrom(fields_message)
    spoil(message)
    with pytest.raises(MessageError, match=reason):
        messages.scene_fields(message, LimitSettings(), 10_000_000)


# -- inboxes -------------------------------------------------------------------------------------------------


def _item(size: int = 10, age: float = 0.0) -> Inbound:
    return Inbound("k", "s", "e", b"x" * size, time.time() - age)


def test_an_inbox_is_bounded_in_bytes_as_well_as_count():
    inbox = Inbox(latest_only=False, limit=100, max_bytes=1000)
    assert inbox.offer(_item(600)) is None
    assert "MAX_QUEUE_BYTES" in inbox.offer(_item(600))
    assert "MAX_QUEUE_BYTES" in inbox.offer(_item(2000))  # larger than the whole inbox
    assert inbox.take(0.1) is not None and inbox.offer(_item(600)) is None  # taking frees the bytes
    small = Inbox(latest_only=False, limit=2, max_bytes=1000)
    assert small.offer(_item()) is None and small.offer(_item()) is None
    assert "MAX_QUEUE" in small.offer(_item())


@pytest.mark.parametrize(
    ("max_gap", "expected"),
    [(0.15, list(range(10))), (0.25, [0, 2, 4, 6, 8, 9]), (0.35, [0, 3, 6, 8, 9])],
)
def test_a_late_stream_is_thinned_with_frames_taken_at_most_max_gap_apart(max_gap, expected):
    inbox = Inbox(latest_only=False, limit=100, max_bytes=10**6, max_lag=0.5, max_gap=max_gap)
    items = [_item(age=5.0 - 0.1 * k) for k in range(9)] + [_item()]  # 10 Hz, all but the last late
    for item in items:
        inbox.offer(item)
    taken = []
    while (item := inbox.take(0.05)) is not None:
        taken.append(items.index(item))
    assert taken == expected  # the first always, the last because nothing newer waits
    assert inbox.skipped == 10 - len(expected)
    assert max(np.diff([items[k].arrived for k in taken[:-1]])) < max_gap  # never further apart
    fresh = Inbox(latest_only=False, limit=100, max_bytes=10**6, max_lag=0.5)
    for _ in range(3):
        fresh.offer(_item())
    assert [fresh.take(0.05) is not None for _ in range(3)] == [True] * 3 and fresh.skipped == 0


def test_a_latest_only_inbox_keeps_the_newest():
    inbox = Inbox(latest_only=True, limit=1, max_bytes=10**6)
    first, second = _item(), _item()
    inbox.offer(first)
    inbox.offer(second)
    assert inbox.take(0.05) is second and inbox.take(0.05) is None


def test_a_recording_is_never_overwritten(tmp_path):
    path = tmp_path / "features.rrd"
    assert unused_path(path) == path
    path.write_bytes(b"crashed run")
    assert unused_path(path) == tmp_path / "features-1.rrd"
    (tmp_path / "features-1.rrd").write_bytes(b"")
    assert unused_path(path) == tmp_path / "features-2.rrd"


def test_a_failure_of_the_services_own_work_is_answered_but_not_counted_as_a_rejected_input(tmp_path):
    """The idle work failing, whatever the exception, is answered on the error key; rejected counts inputs."""
    import threading

    from affordwire.messages import Error
    from services.launch import free_port
    from services.node import Node
    from services.transport import Keys, open_session

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_session([], mode="router", listen=[endpoint])
    client = open_session([endpoint])
    errors: list[Error] = []
    client.declare_subscriber(
        Keys("idlebot").error("probe"), lambda s: errors.append(messages.parse(Error, s.payload.to_bytes()))
    )
    node = Node("probe", "idlebot", [endpoint], rrd=tmp_path / "probe.rrd")

    def idle() -> None:
        node.stop_event.set()
        raise ZeroDivisionError("idle went wrong")

    inbox = node.inbox(latest_only=True)
    thread = threading.Thread(target=node.run, args=(inbox, lambda item: None, idle))
    thread.start()
    thread.join(30)
    try:
        assert not thread.is_alive()
        deadline = time.monotonic() + 5
        while not errors and time.monotonic() < deadline:
            time.sleep(0.05)
        assert errors and errors[0].key == "(idle)"
        assert errors[0].reason == "internal error, ZeroDivisionError: idle went wrong"
        assert node.counts["rejected"] == 0
    finally:
        client.close()
        router.close()


def test_a_refused_input_is_never_counted_as_both_taken_and_refused(tmp_path):
    """Status counts move an input from accepted to rejected in one step: the status a refusal publishes (and
    any read meanwhile) counts each input once, so a client summing them never sees more than it sent."""
    from services.launch import free_port
    from services.node import Node
    from services.transport import open_session

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_session([], mode="router", listen=[endpoint])
    node = Node("probe", "countbot", [endpoint], rrd=tmp_path / "probe.rrd")
    seen = []
    publish_status = node.publish_status

    def recording_status(state, detail):
        seen.append(dict(node.counts))
        publish_status(state, detail)

    def refuse(item):
        raise ValueError("not a scan")

    node.publish_status = recording_status
    try:
        inbox = node.inbox(latest_only=False)
        for sent in range(1, 4):
            node._handle(_item(), refuse if sent != 2 else (lambda item: None), inbox)
            assert node.counts["accepted"] + node.counts["rejected"] == sent
        assert (node.counts["accepted"], node.counts["rejected"]) == (1, 2)
        first_refusal = seen[0]  # the status the first refusal published, while its input was in hand
        assert first_refusal["accepted"] + first_refusal["rejected"] == 1, first_refusal
    finally:
        node.close()
        router.close()
