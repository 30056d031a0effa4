"""Differential fuzzing of the whole stream (tests/test_stream_fuzz.py, benchmarks/fuzz_stream.py).

A valid stream (generated depth frames, paced as a sensor the assembler keeps up with) goes into the router
and the three services as processes, once as it is and once with hostile messages interleaved at seeded random
points (beside each frame, and while the last map is made): one at a time and in bursts, from several client
sessions at once, on every input key (scans, depth frames, ROS 2 PointCloud2, Imu and Odometry, map clouds,
fields). Every damage kind of tests/test_hostile.py is drawn, and kept when it makes a message the services
must refuse: the wire's decoders alone refuse it, or it is a sound-looking 'world' cloud whose floor is not at
z = 0 (some of those come while the last map is made, when they supersede it). The outcome is what a robot
would read: the assembler's last map, each affordance's last map, what two `afford watch --frames N` (one
started with the stream, one after it) took as the answer, the refusals per service, and whether any process
exited."""

from __future__ import annotations

import hashlib
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from test_hostile import _settle, _valid_inputs, hostile_inputs
from test_ros import cdr, cloud_message, imu_message, odometry_message

from affordcore.settings import LimitSettings
from affordwire import messages, ros
from affordwire.sensors import decode_sensor
from services.clients import MapWatcher, folder_frames, watch
from services.launch import Stack
from services.ros import topic_keys
from services.settings import RosSettings
from services.transport import Keys, declare_publisher, encoding_of, put

ROBOT = "diffbot"
KEYS = Keys(ROBOT)
AFFORDANCES = ["sitting-relaxing", "sitting-working", "standing-working"]
ROS_ENV = {"AFFORD_ROS__POINTS": "/points", "AFFORD_ROS__IMU": "/imu", "AFFORD_ROS__ODOMETRY": "/odom"}
LIMITS = LimitSettings()
CLIENTS = 3  # hostile client sessions, sending at once
QUIET = 0.8  # seconds after each frame's pose: the assembler publishes after 0.5 s without a scan


def _ros_key(topic: str, typename: str) -> str:
    """A concrete rmw_zenoh key of a topic (the subscription's last chunk is the type hash)."""
    return topic_keys(topic, typename, RosSettings())[0].replace("*", "RIHS01_" + "0" * 64)


@dataclass(frozen=True)
class Hostile:
    key: str
    payload: bytes
    encoding: str
    service: str  # which service must answer it on its error key
    late: bool = False  # refused only once worked on (a sound-looking cloud): it may supersede a good one


def _schema(encoding: str) -> str:
    prefix = "application/protobuf;"
    return encoding[len(prefix) :] if encoding.startswith(prefix) else ""


def _decoders_refuse(kind: str, payload: bytes, encoding: str) -> bool:
    """Whether the wire's decoders alone refuse the message (so every service must, whatever its state)."""
    schema = _schema(str(encoding))
    try:
        if kind in ("scan", "depth"):
            decode_sensor(schema, payload, LIMITS)
        elif kind == "cloud":
            if schema != messages.schema_name(messages.CloudMessage):
                return True
            cloud = messages.parse(messages.CloudMessage, payload)
            messages.cloud_points(cloud, LIMITS)
            messages.cloud_origins(cloud, LIMITS)
        elif kind == "fields":
            if schema != messages.schema_name(messages.SceneFieldsMessage):
                return True
            messages.scene_fields(messages.parse(messages.SceneFieldsMessage, payload), LIMITS)
        else:
            {"points": ros.pointcloud2, "imu": ros.imu, "odometry": ros.odometry}[kind](payload, LIMITS)
    except Exception:  # noqa: BLE001 - any refusal will do
        return True
    return False


def _ros_damage(valid: bytes, rng: np.random.Generator, count: int):
    """Random bytes, truncations and bit flips of a valid CDR message."""
    for index in range(count):
        kind = index % 3
        if kind == 0:
            yield rng.bytes(int(rng.integers(0, 2048)))
        elif kind == 1:
            yield valid[: int(rng.integers(0, len(valid)))]
        else:
            flipped = bytearray(valid)
            for bit in rng.integers(0, 8 * len(valid), int(rng.integers(1, 9))):
                flipped[bit // 8] ^= 1 << (bit % 8)
            yield bytes(flipped)


def hostile_pool(rng: np.random.Generator, per_key: int) -> list[Hostile]:
    """Hostile messages for every input key, `per_key` candidates each, kept when they must be refused."""
    pool: list[Hostile] = []
    valid = _valid_inputs(rng)
    for kind, key, service in (
        ("scan", KEYS.scan("camera"), "assembler"),
        ("depth", KEYS.scan("camera"), "assembler"),
        ("cloud", KEYS.cloud, "features"),
        ("fields", KEYS.fields, "inference"),
    ):
        for payload, encoding, _ in hostile_inputs(*valid[kind], rng, per_key):
            if _decoders_refuse(kind, payload, encoding):
                pool.append(Hostile(key, payload, str(encoding), service))
    # sound-looking 'world' clouds whose floor is not at z = 0: refused only once worked on, after they have
    # superseded the assembler's cloud waiting, and made inference give up maps in hand
    room = messages.cloud_points(valid["cloud"][0])
    for lift in rng.uniform(0.4, 1.2, max(1, per_key // 20)):
        raised = messages.cloud_message(room + [0.0, 0.0, lift], np.eye(4), "raised")
        encoding = encoding_of(messages.CloudMessage)
        pool.append(Hostile(KEYS.cloud, raised.SerializeToString(), encoding, "features", late=True))
    grid = rng.normal(size=(4, 6, 3)).astype(np.float32)
    ros_valid = {
        "points": (cdr(cloud_message(grid)), _ros_key("/points", ros.POINTCLOUD2)),
        "imu": (cdr(imu_message((0.0, 0.0, 9.81)), ros.IMU), _ros_key("/imu", ros.IMU)),
        "odometry": (cdr(odometry_message((1.0, 0.0, 0.0)), ros.ODOMETRY), _ros_key("/odom", ros.ODOMETRY)),
    }
    for kind, (message, key) in ros_valid.items():
        for payload in _ros_damage(message, rng, per_key):
            if _decoders_refuse(kind, payload, ""):
                pool.append(Hostile(key, payload, "application/cdr", "assembler"))
    return pool


def hostile_plan(
    rng: np.random.Generator, pool: list[Hostile], frames: int, count: int
) -> list[list[Hostile]]:
    """`count` hostile messages spread beside the stream's `frames` frames and after its last (while its last
    map is made): mostly one or two at a point, some bursts."""
    gaps = frames + 1
    plan: list[list[Hostile]] = [[] for _ in range(gaps)]
    picks = iter(rng.permutation(len(pool)).tolist() * (count // max(len(pool), 1) + 1))
    plan[-1].extend([h for h in pool if h.late][: count // 4])  # while the last map is made
    left = count - len(plan[-1])
    while left > 0:
        size = int(min(left, rng.choice([1, 1, 2, 3, 25])))
        plan[int(rng.integers(0, gaps))].extend(pool[next(picks)] for _ in range(size))
        left -= size
    return plan


@dataclass
class Outcome:
    cloud: str = ""  # sha256 of the assembler's last map's points
    frames: int = 0
    maps: dict[str, tuple] = field(default_factory=dict)  # affordance: (frames, confidence sha256, places)
    watched: list[dict[str, list]] = field(default_factory=list)  # each watch's places per affordance
    refused: dict[str, int] = field(default_factory=dict)  # Error messages seen, per service
    sent: dict[str, int] = field(default_factory=dict)  # hostile messages sent, per service
    exited: dict[str, int] = field(default_factory=dict)
    poses: list = field(default_factory=list)  # odom_from_sensor of each frame, as the assembler said it


def _places(document: dict) -> list:
    return [(s["x"], s["y"], s["theta"], s["score"]) for s in document["skeletons"]]


def _watcher(session, frames: int, timeout: float, result: list) -> threading.Thread:
    """An `afford watch --frames N` of its own, in a thread; its maps' places go to `result`."""

    def run() -> None:
        watcher = MapWatcher(KEYS, AFFORDANCES, frames, None, echo=lambda line: None)
        done = watch(session, KEYS, watcher, timeout)
        result.append(
            {"done": done, "refused": watcher.refused}
            | {name: _places(watcher.received[name]) for name in watcher.received}
        )

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def run_stream(
    folder: Path,
    run: Path,
    frames: int,
    plan: list[list[Hostile]] | None = None,
    kills: dict[int, tuple[str, float]] | None = None,
    timeout: float = 240.0,
) -> Outcome:
    """The stream of `frames` frames (every 3rd of the folder's) into a fresh stack, with `plan[i]` sent
    beside frame i (half just before it, half just after, spread over the client sessions) and
    `plan[frames]` as the last map is made; `kills[i] = (service, delay)`: that service killed with SIGKILL
    `delay` seconds after frame i went out (`frames`: after the last map went out) and started again. The
    sensor here is a careful one: a frame that got neither a pose nor a refusal (its assembler died with it)
    is sent again, the same message, once the assembler is back."""
    outcome = Outcome()
    stack = Stack(run, robot=ROBOT, env=ROS_ENV, state=run / "state").start()
    pids = {name: process.pid for name, process in stack.processes.items()}
    sessions = [stack.session() for _ in range(CLIENTS + 3)]
    main, watch_session, late_session, hostile = sessions[0], sessions[1], sessions[2], sessions[3:]
    kills = kills or {}
    try:
        # microsecond stamps of the frames answered (a pose, or a refusal), and of those sent again
        answered, resent, lock = set(), set(), threading.Lock()
        last_map = threading.Event()  # the assembler's map of the whole stream went out

        def on_error(sample) -> None:
            service = str(sample.key_expr).rsplit("/", 1)[-1]
            error = messages.parse(messages.Error, sample.payload.to_bytes())
            stamp = round(messages.nanoseconds(error.input_timestamp) / 1e3)
            with lock:
                if error.key == KEYS.scan("camera") and stamp in resent:  # a repeat of a journaled frame
                    answered.add(stamp)
                    return
                outcome.refused[service] = outcome.refused.get(service, 0) + 1

        def on_pose(sample) -> None:
            pose = messages.parse(messages.Pose, sample.payload.to_bytes())
            with lock:
                answered.add(round(messages.seconds(pose.timestamp) * 1e6))
                outcome.poses.append(messages.pose_matrix(pose))

        def on_cloud(sample) -> None:
            try:
                cloud = messages.parse(messages.CloudMessage, sample.payload.to_bytes())
            except messages.MessageError:
                return
            if cloud.source == "assembler" and cloud.frames >= frames:
                last_map.set()

        subscribers = [
            main.declare_subscriber(KEYS.key("error", "*"), on_error),
            main.declare_subscriber(KEYS.pose, on_pose),
            main.declare_subscriber(KEYS.cloud, on_cloud),
        ]
        _, valid, count = folder_frames(folder, 0, frames, 3, imu=True)
        valid_frames = [message for _, message in valid]
        watched: list[dict] = []
        early = _watcher(watch_session, count, timeout, watched)
        publisher = declare_publisher(main, KEYS.scan("camera"), type(valid_frames[0]))
        for index, message in enumerate(valid_frames):
            batch = plan[index] if plan else []
            _send_hostile(hostile, batch[: len(batch) // 2], outcome)
            messages.stamp(message.timestamp)
            stamp = round(messages.nanoseconds(message.timestamp) / 1e3)
            publisher.put(message.SerializeToString())
            _send_hostile(hostile, batch[len(batch) // 2 :], outcome)
            if index in kills:
                _kill(stack, *kills[index])
            deadline, again = time.monotonic() + 60, time.monotonic() + 2.0
            # paced as a sensor the assembler keeps up with: none passed over (a pose's stamp went through a
            # float of seconds: to the microsecond, give or take one)
            while not answered & {stamp - 1, stamp, stamp + 1}:
                assert time.monotonic() < deadline, f"frame {index} got no pose; {stack.logs()}"
                if index in kills and time.monotonic() > again:
                    # the assembler died with the frame in hand: the same message again (refused as a
                    # repeat if it was journaled before the kill)
                    with lock:
                        resent.add(stamp)
                    publisher.put(message.SerializeToString())
                    again += 2.0
                time.sleep(0.01)
            # and a pause in which the assembler tries a map of the frames so far (0.5 s without a scan):
            # the maps it publishes, whose levelling each next one keeps unless it moved, are the same in
            # every run whatever the timing, a restart's pause included
            time.sleep(QUIET)
        tail = [h for batch in plan[len(valid_frames) :] for h in batch] if plan else []
        last_map.wait(timeout)
        # at once, as the last map reaches the features service, then spread while it is made
        _send_hostile(hostile, [h for h in tail if h.late], outcome)
        trickle = threading.Thread(target=_trickle, args=(hostile, [h for h in tail if not h.late], outcome))
        trickle.start()
        if frames in kills:
            _kill(stack, *kills[frames])
        early.join(timeout)
        trickle.join()
        late = _watcher(late_session, count, timeout, watched)
        late.join(timeout)
        outcome.watched = watched
        _settle(main, keys=KEYS)
        expected = sum(outcome.sent.values())
        deadline = time.monotonic() + 30
        while sum(outcome.refused.values()) < expected and time.monotonic() < deadline:
            time.sleep(0.1)
        for reply in main.get(KEYS.cloud, timeout=10):
            if reply.ok is not None:
                cloud = messages.parse(messages.CloudMessage, reply.ok.payload.to_bytes())
                outcome.cloud, outcome.frames = hashlib.sha256(cloud.data).hexdigest(), cloud.frames
        for reply in main.get(KEYS.affordance("*"), timeout=10):
            if reply.ok is not None:
                amap = messages.parse(messages.AffordanceMapMessage, reply.ok.payload.to_bytes())
                document = messages.map_document_of(amap)
                digest = hashlib.sha256(amap.confidence).hexdigest()
                outcome.maps[amap.affordance] = (amap.frames, digest, _places(document))
        for subscriber in subscribers:
            subscriber.undeclare()
        outcome.exited = {
            name: process.returncode if process.poll() is not None else "restarted"
            for name, process in stack.processes.items()
            if process.poll() is not None or process.pid != pids[name]
        }
    finally:
        for session in sessions:
            session.close()
        stack.stop()
    return outcome


def _kill(stack: Stack, service: str, delay: float) -> None:
    """SIGKILL `service` after `delay` seconds (mid-work, if it is working), and start it again."""
    time.sleep(delay)
    stack.kill(service)
    stack.restart(service)


def _trickle(sessions, hostile: list[Hostile], outcome: Outcome, seconds: float = 4.0) -> None:
    """The messages one client at a time, spread over `seconds`."""
    for index, item in enumerate(hostile):
        time.sleep(seconds / max(len(hostile), 1))
        _send_hostile(sessions[index % len(sessions) : index % len(sessions) + 1], [item], outcome)


def _send_hostile(sessions, batch: list[Hostile], outcome: Outcome) -> None:
    """The batch, dealt round the client sessions, each session putting its share at the same time."""
    if not batch:
        return
    for item in batch:
        outcome.sent[item.service] = outcome.sent.get(item.service, 0) + 1
    shares = [batch[k :: len(sessions)] for k in range(len(sessions))]
    threads = [
        threading.Thread(
            target=lambda s=s, share=share: [put(s, h.key, h.payload, h.encoding) for h in share]
        )
        for s, share in zip(sessions, shares)
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
