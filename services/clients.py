"""The router and the two clients: `afford router`, `afford publish` (a cloud file, a depth-frame folder or a
scan folder onto the robot's keys) and `afford watch` (print what the services publish, save the maps)."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from affordwire import messages

from .transport import Keys, declare_publisher, encoding_of, open_session, schema_of, stop_on_signals


def run_router(
    listen: list[str], stop: threading.Event | None = None, zenoh_config: Path | None = None
) -> None:
    """A zenoh router on `listen` until SIGINT/SIGTERM, from the JSON5 `zenoh_config` when given (TLS, access
    control: docs/security.md). zenohd is not on pip or apt; docker uses eclipse/zenoh."""
    stop = stop or threading.Event()
    stop_on_signals(stop)
    session = open_session([], mode="router", listen=listen, base=zenoh_config)
    print(f"router listening on {', '.join(listen) or 'the endpoints of ' + str(zenoh_config)}", flush=True)
    try:
        stop.wait()
    finally:
        session.close()


# -- publish -------------------------------------------------------------------------------------------------


class NoSubscriber(RuntimeError):
    """Nobody listens on the key a client was about to publish on."""


@contextmanager
def connected(endpoints: list[str], mode: str, zenoh_config: Path | None = None) -> Iterator:
    """A zenoh session to the router(s) at `endpoints`, closed on leaving."""
    session = open_session(endpoints, mode, base=zenoh_config)
    try:
        yield session
    finally:
        session.close()


def _publisher(session, key: str, message_class, wait: float):
    """A publisher on `key`, once something subscribes to it (samples put before that are lost)."""
    publisher = declare_publisher(session, key, message_class)
    deadline = time.monotonic() + wait
    while not publisher.matching_status.matching:
        if time.monotonic() > deadline:
            publisher.undeclare()
            raise NoSubscriber(
                f"nothing subscribes to {key} after {wait:.0f} s: is the service for robot "
                f"{key.split('/')[2]!r} running and connected to the same router?"
            )
        time.sleep(0.05)
    return publisher


def _delivered(session, keys: Keys) -> None:
    """Return once what this session put has reached the robot's services: a put only queues a sample, and
    a session closed right after it can lose the last one (one frame in a hundred through a router). A
    query to the services' status travels behind the samples on the same links, so its replies come after
    them."""
    list(session.get(keys.key("status", "*"), timeout=10.0))


def publish_map(session, keys: Keys, cloud: messages.CloudMessage, wait: float) -> None:
    """A finished room on map/cloud, once the features service listens."""
    publisher = _publisher(session, keys.cloud, messages.CloudMessage, wait)
    publisher.put(cloud.SerializeToString())
    _delivered(session, keys)
    publisher.undeclare()


def publish_sequence(
    session,
    keys: Keys,
    frames,
    sensor: str,
    rate: float,
    wait: float,
    on_frame: Callable[[int], None] | None = None,
) -> int:
    """Publish (index, message) pairs on scan/<sensor> at `rate` Hz (0: as fast as the network takes them);
    each message without a timestamp is stamped when it is sent. Returns how many were sent."""
    publisher = None
    period = 1.0 / rate if rate > 0 else 0.0
    sent, start = 0, time.monotonic()
    try:
        for index, message in frames:
            if publisher is None:
                publisher = _publisher(session, keys.scan(sensor), type(message), wait)
                start = time.monotonic()
            delay = start + sent * period - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            if not message.HasField("timestamp"):  # a recording's messages keep the times they were taken
                messages.stamp(message.timestamp)
            publisher.put(message.SerializeToString(), encoding=encoding_of(type(message)))
            sent += 1
            if on_frame:
                on_frame(index)
        _delivered(session, keys)
    finally:
        if publisher is not None:
            publisher.undeclare()
    return sent


def sequence_messages(sequence, indices, with_gravity: bool = True, with_odometry: bool = True):
    """(index, DepthFrame or Scan) for each frame of an affordcore.assembly.sequence.Sequence, with the
    gravity direction an IMU would report when the folder has gravity-direction.txt and poses, and the
    robot's odometry as the pose guess when the frame has one (``<stem>.odometry.txt``)."""
    from affordcore.assembly.sequence import DEPTH_SCALE, INVALID_DEPTH

    for index in indices:
        if sequence.kind == "depth":
            message = messages.depth_frame_message(
                sequence.depth(index),
                sequence.intrinsics,
                DEPTH_SCALE,
                frame_id="camera",
                invalid_value=INVALID_DEPTH,
            )
        else:
            message = messages.Scan(frame_id="lidar")
            messages.pack_points(message, sequence.scan(index))
        gravity = sequence.gravity(index) if with_gravity else None
        if gravity is not None:
            messages.set_vector(message.gravity, gravity)
        guess = sequence.odometry(index) if with_odometry else None
        if guess is not None:
            messages.set_pose(message.pose_guess, guess, "odom", message.frame_id)
        yield index, message


# -- watch ---------------------------------------------------------------------------------------------------


def describe(key: str, schema: str, payload: bytes) -> str:
    """One line about a publication, for people watching the robot's keys."""
    classes = messages.MESSAGE_CLASSES
    if schema not in classes:
        return f"{key}: {len(payload):,} bytes ({schema or 'no schema'})"
    try:
        message = messages.parse(classes[schema], payload)
    except messages.MessageError as error:
        return f"{key}: {error}"
    name = classes[schema].DESCRIPTOR.name
    if name == "Status":
        state = messages.Status.State.Name(message.state)
        counts = f"taken {message.accepted}, rejected {message.rejected}, published {message.published}"
        return f"{key}: {state} {message.detail} ({counts})"
    if name == "Error":
        return f"{key}: REJECTED {refused_input(message)} on {message.key}: {message.reason}"
    if name == "AffordanceMap":
        first = message.skeletons[0] if message.skeletons else None
        best = (
            ""
            if first is None
            else f", best p {first.probability:.2f}"
            if first.HasField("probability")
            else f", best {first.score:.2f}"
        )
        poses = len(message.positives) // 20  # five float32 per pose
        places = len(message.skeletons)
        return f"{key}: {places} places, {poses:,} poses above the threshold{best} ({message.frames} frames)"
    if name == "NextViews":
        if not message.views:
            return f"{key}: no next view would settle anything ({message.frames} frames)"
        best = message.views[0]
        at = f"({best.pose.position.x:.2f}, {best.pose.position.y:.2f})"
        return (
            f"{key}: {len(message.views)} next views, the best at {at} facing "
            f"{np.degrees(best.heading):.0f} deg, {best.gain:.2f} bits ({message.frames} frames)"
        )
    if name == "SceneFields":
        grid = message.grid
        shape = f"{grid.nx} x {grid.ny} x {grid.nz}"
        return f"{key}: fields {shape} at {grid.resolution} m ({message.frames} frames)"
    if name == "Cloud":
        points = len(message.data) // max(message.point_stride, 1)
        return f"{key}: map of {points:,} points from {message.source} ({message.frames} frames)"
    if name == "Pose":
        p = message.position
        return f"{key}: sensor at ({p.x:.2f}, {p.y:.2f}, {p.z:.2f}) in {message.frame_id}"
    return f"{key}: {name} of {len(payload):,} bytes"


def refused_input(error) -> str:
    """What a refusal says it refused, in words: its source, its stamp and the scans it covered."""
    what = f"{error.input_source!r}" if error.input_source else "an input"
    if error.HasField("input_timestamp"):
        what += f" stamped {error.input_timestamp.seconds}.{error.input_timestamp.nanos:09d}"
    return what + (f" ({error.input_scans} scans)" if error.input_scans else "")


class MapWatcher:
    """Collects the affordance maps of one robot; `done` once every wanted affordance has a map of a cloud no
    older than `since` (nanoseconds since the epoch; `watch` sets it to the newest cloud the features service
    has when 0) that covers at least `min_frames` scans: scans the assembler received, fused or skipped to
    keep up (a busy assembler skips scans, and a map of every one published would never come).

    A refusal ends the watch only when it answers the cloud waited for (`refused` says why): the cloud
    stamped `since`, or, waiting for `min_frames` scans, a cloud of the assembler's covering them. Another
    client's refused cloud is shown, and the watch goes on. So does an assembler that has had every scan and
    no map to give of them (`gave_up` says why)."""

    def __init__(
        self,
        keys: Keys,
        affordances: list[str],
        min_frames: int,
        out: Path | None,
        echo: Callable[[str], None] = print,
        since: int = 0,
    ):
        self.keys, self.wanted, self.min_frames = keys, set(affordances), min_frames
        self.out, self.echo, self.since = out, echo, since
        self.received: dict[str, dict] = {}
        self.refused: str | None = None  # why the cloud waited for was refused
        self.refused_cloud = ""  # ... and which cloud that was, in words
        self.gave_up: str | None = None
        self.newest_covered = 0  # scans covered by the newest map seen: what a timeout reports
        self.done = threading.Event()
        self._lock = threading.Lock()

    def on_sample(self, sample, live: bool = True) -> None:
        """A sample on the robot's keys; `live` False: a reply to a get, from before the watch began."""
        key, schema, payload = str(sample.key_expr), schema_of(sample), sample.payload.to_bytes()
        self.echo(describe(key, schema, payload))
        if schema == messages.schema_name(messages.AffordanceMapMessage):
            self._take_map(payload)
        elif schema == messages.schema_name(messages.Error) and "/error/features" in key:
            self._take_refusal(payload, live)
        elif schema == messages.schema_name(messages.Status) and key == self.keys.status("assembler"):
            self._take_assembler_status(payload)

    def _take_map(self, payload: bytes) -> None:
        try:
            message = messages.parse(messages.AffordanceMapMessage, payload)
            document = messages.map_document_of(message)
        except messages.MessageError as error:
            self.echo(f"unreadable map: {error}")
            return
        if messages.nanoseconds(message.cloud_timestamp) < self.since:
            return  # the answer to an older cloud than the one waited for
        covered = covered_scans(message)
        self.newest_covered = max(self.newest_covered, covered)
        if covered < self.min_frames:
            self.echo(
                f"  (a map of {message.frames} fused of {covered} scans received; waiting for the map that "
                f"covers {self.min_frames})"
            )
            return
        with self._lock:
            self.received[message.affordance] = document
            if self.out is not None:
                self.out.mkdir(parents=True, exist_ok=True)
                (self.out / f"{message.affordance}.json").write_text(json.dumps(document) + "\n")
            if self.wanted <= set(self.received):
                self.done.set()

    def _take_refusal(self, payload: bytes, live: bool) -> None:
        try:
            error = messages.parse(messages.Error, payload)
        except messages.MessageError:
            return
        if self.answers_ours(error, live):
            self.refused_cloud = refused_input(error)
            self.refuse(error.reason)
        else:
            self.echo("  (not the cloud waited for: the watch goes on)")

    def answers_ours(self, error, live: bool = True) -> bool:
        """Whether a cloud's refusal answers the cloud waited for: the one stamped `since` exactly (as
        `afford publish --as-map` printed it, or the newest at the start); waiting for `min_frames` scans,
        also a later cloud of the assembler that covers them, if refused while the watch ran (one kept from
        before is an earlier stream's)."""
        if not error.HasField("input_timestamp"):
            return False  # it names no cloud: nobody's answer
        stamp = messages.nanoseconds(error.input_timestamp)
        if self.since and stamp == self.since:
            return True
        return (
            live
            and self.min_frames > 0
            and stamp >= self.since
            and error.input_source == "assembler"
            and error.input_scans >= self.min_frames
        )

    def _take_assembler_status(self, payload: bytes) -> None:
        """The assembler has every scan waited for settled (taken, refused or passed over) and says its map of
        them makes no output (`Status.no_output`, cleared by each scan it takes): no later map will cover
        them unless more scans come."""
        try:
            status = messages.parse(messages.Status, payload)
        except messages.MessageError:
            return
        # messages refused on arrival are no scans (another client's garbage): the maps do not count them
        settled = status.accepted + status.rejected - status.refused_on_arrival + status.skipped
        if self.min_frames and settled >= self.min_frames and status.no_output:
            self.gave_up = (
                f"the assembler has settled all {settled} scans and has no map of them ({status.no_output}); "
                "publish scans that see the floor, or more of them (a slower --rate leaves it fewer to skip)"
            )
            self.done.set()

    def refuse(self, reason: str) -> None:
        self.refused = reason
        self.done.set()

    @property
    def missing(self) -> list[str]:
        return sorted(self.wanted - set(self.received))

    def waiting_for(self) -> str:
        """What the watch still waits for, in words."""
        what = f"maps of {', '.join(self.missing)}"
        if self.min_frames:
            what += f" covering {self.min_frames} scans (the newest map seen covers {self.newest_covered})"
        return what


def covered_scans(message) -> int:
    """How many of the scans published a map covers: those the assembler received, fused or skipped (a
    service older than that count says only how many it fused)."""
    return max(message.frames, message.scans_received)


def newest_cloud(session, keys: Keys, timeout: float = 5.0) -> int:
    """Nanoseconds of the newest cloud the robot's features service has received and not refused, taken or
    waiting; 0 when it has none, or does not answer."""
    for reply in session.get(keys.status("features"), timeout=timeout):
        if reply.ok is None or schema_of(reply.ok) != messages.schema_name(messages.Status):
            continue
        try:
            status = messages.parse(messages.Status, reply.ok.payload.to_bytes())
        except messages.MessageError:
            continue
        return messages.nanoseconds(status.newest_input)
    return 0


def watch(session, keys: Keys, watcher: MapWatcher, timeout: float) -> bool:
    """Print everything under the robot's keys and collect maps until `watcher` is done or `timeout` passes.
    Without a `since` of its own, the watcher waits for maps of the newest cloud the features service has
    (never an older cloud's, which the inference service still answers with). Maps published before the
    watch began are fetched with a get (a late joiner catches up), and so are the refusals the services still
    keep: a cloud refused before the watch began ends it as one refused during it."""
    import zenoh

    watcher.since = watcher.since or newest_cloud(session, keys, min(timeout, 5.0))
    watcher.echo(f"waiting for {watcher.waiting_for()}")
    subscriber = session.declare_subscriber(keys.key("**"), watcher.on_sample)

    def on_liveliness(sample) -> None:
        watcher.echo(
            f"{sample.key_expr}: service {'joined' if sample.kind == zenoh.SampleKind.PUT else 'left'}"
        )

    alive = session.liveliness().declare_subscriber(keys.key("status", "*"), on_liveliness, history=True)
    try:
        # every refusal kept, not the latest per key (zenoh's default consolidation): they share their key
        kept = session.get(
            keys.key("error", "*"), timeout=min(timeout, 5.0), consolidation=zenoh.ConsolidationMode.NONE
        )
        for reply in [*kept, *session.get(keys.key("affordance", "*"), timeout=min(timeout, 5.0))]:
            if reply.ok is not None:
                watcher.on_sample(reply.ok, live=False)
        return watcher.done.wait(timeout)
    finally:
        alive.undeclare()
        subscriber.undeclare()


def reset_robot(
    session, keys: Keys, operator: str, reason: str, timeout: float
) -> tuple[list[str], list[str]]:
    """Ask the robot's services to forget its map and state (control/reset) and wait until each says it did
    (its Status.last_reset is this reset's stamp): (services reset, services that did not say so in time).
    Under a secured site only an operator identity may put it: a put the router denies reaches nobody."""
    from .launch import query_status
    from .security import SERVICES

    reset = messages.Reset(operator=operator, reason=reason)
    messages.stamp(reset.timestamp)
    publisher = _publisher(session, keys.reset, messages.Reset, min(timeout, 10.0))
    publisher.put(reset.SerializeToString())
    publisher.undeclare()
    deadline, done = time.monotonic() + timeout, []
    while time.monotonic() < deadline:
        statuses = query_status(session, keys.robot)
        done = [
            name for name in SERVICES if name in statuses and statuses[name].last_reset == reset.timestamp
        ]
        if len(done) == len(SERVICES):
            break
        time.sleep(0.2)
    return done, [name for name in SERVICES if name not in done]


def load_as_map(path: Path, gravity: str, settings) -> tuple[messages.CloudMessage, list[str]]:
    """A finished room scan from a file, brought to the world frame by the library's one path (thinned when
    huge, gravity-aligned), so map/cloud always holds world-frame points; and the warnings to show."""
    from affordcore.geometry.scene import load_cloud
    from affordcore.mapping.pipeline import parse_gravity, to_world

    cloud = load_cloud(path)
    world = to_world(cloud, settings, parse_gravity(gravity))
    points = world.cloud.points.astype(np.float32)
    message = messages.cloud_message(
        points, world.alignment.world_from_input, source=path.name, origins=world.cloud.origins
    )
    return message, cloud.notes + world.warnings  # points not finite, dropped; thinning


def scan_message(path: Path, sensor: str) -> messages.Scan:
    """One cloud file as a single Scan (points in the sensor frame)."""
    from affordcore.geometry.scene import load_cloud

    scan = messages.Scan(frame_id=sensor)
    messages.pack_points(scan, load_cloud(path).points)
    return scan


def folder_frames(folder: Path, first: int, frames: int, step: int, imu: bool, odometry: bool = True):
    """(sequence, its frames to publish as (index, message) pairs, how many) of a recorded folder."""
    from affordcore.assembly.sequence import read_sequence

    sequence = read_sequence(folder)
    indices = list(range(first, len(sequence.frames), step))[: frames or None]
    if not indices:
        raise ValueError(f"{folder}: no frames from {first} (it has {len(sequence.frames)})")
    return sequence, sequence_messages(sequence, indices, imu, odometry), len(indices)


def watch_maps(
    endpoints: list[str],
    mode: str,
    keys: Keys,
    watcher: MapWatcher,
    timeout: float,
    zenoh_config: Path | None = None,
) -> bool:
    """`watch` over a session of its own."""
    with connected(endpoints, mode, zenoh_config) as session:
        return watch(session, keys, watcher, timeout)
