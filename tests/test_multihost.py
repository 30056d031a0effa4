"""More than one host: sharded inference workers (services/shard.py) share many robots' fields, and a lost
worker's share is picked up by the others.

* ownership by rendezvous hashing: every worker agrees, a join moves units only to the newcomer, a leave
  only away from the leaver; robot selections are one key chunk and real robot names stay strict;
* two workers in threads on a loopback router: each unit mapped once, by its owner; a get answered once per
  unit; a worker that took its share and vanished without mapping it is replaced by the survivor, which
  fetches the fields again and maps exactly what is missing (slow);
* for real (slow, root): two network namespaces joined by a veth pair are two hosts, one router each (B's
  linked to A's), features of each robot and one inference worker per host, two robots publishing finished
  rooms across the link; a worker is killed with SIGKILL while it maps its share of a second room, and every
  map of both robots' newest rooms still comes out, and a late `afford watch` gets them all from the survivor.

Run as a script, this file is the observer the namespace test starts inside a namespace (`observe`).
"""

from __future__ import annotations

import json
import os
import queue
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
AFFORDANCES = ("sitting-relaxing", "sitting-working", "standing-working")


def _pair(robots, affordances=AFFORDANCES, victim_share: int = 2) -> tuple[str, str]:
    """Two worker ids (survivor, victim) such that the victim owns `victim_share` of each robot's units and
    the survivor the rest (a fixed, searched pair: the test does not depend on luck)."""
    from services.shard import owner

    for i in range(200):
        for j in range(200):
            if i == j:
                continue
            survivor, victim = f"w{i}", f"w{j}"
            shares = [
                sum(owner((survivor, victim), f"{robot}/{a}") == victim for a in affordances)
                for robot in robots
            ]
            if all(share == victim_share for share in shares):
                return survivor, victim
    raise AssertionError("no pair of worker ids splits the units as wanted")


# -- ownership and names -----------------------------------------------------------------------------------


def test_rendezvous_owners_move_only_to_a_newcomer_and_only_from_a_leaver():
    from services.shard import owner

    units = [f"r{r}/{a}" for r in range(40) for a in AFFORDANCES]
    three = ("alpha", "beta", "gamma")
    before = {unit: owner(three, unit) for unit in units}
    assert {unit: owner(reversed(three), unit) for unit in units} == before, "order of the view matters"
    counts = {w: list(before.values()).count(w) for w in three}
    assert min(counts.values()) >= 25, counts  # 120 units over 3 workers: each takes a fair share

    joined = {unit: owner((*three, "delta"), unit) for unit in units}
    moved = {unit for unit in units if joined[unit] != before[unit]}
    assert moved and all(joined[unit] == "delta" for unit in moved)

    left = {unit: owner(("alpha", "gamma"), unit) for unit in units}
    changed = {unit for unit in units if left[unit] != before[unit]}
    assert changed == {unit for unit in units if before[unit] == "beta"}


def test_robot_selections_are_one_chunk_and_robot_names_stay_strict():
    from services.shard import Selection, WorkerKeys
    from services.transport import Keys, robot_of, robot_pattern

    assert robot_pattern("*") == "*" and robot_pattern("lab-$*") == "lab-$*"
    for bad in ("**", "a/b", "@workers", "a*", "two words", "", "r#1"):
        with pytest.raises(ValueError):
            robot_pattern(bad)
    for bad in ("*", "lab-$*", "@workers"):
        with pytest.raises(ValueError, match="one non-empty key chunk"):
            Keys(bad)
    selection = Selection(("lab-$*", "r7"))
    assert selection.keys("fields") == ["afford/@v1/lab-$*/fields", "afford/@v1/r7/fields"]
    assert selection.includes("lab-3") and selection.includes("r7") and not selection.includes("r8")
    assert robot_of("afford/@v1/r1/fields") == "r1"
    assert robot_of("afford/@v1/@workers/g/w/status") is None and robot_of("(idle)") is None

    keys = WorkerKeys(Selection(("*",)), "inference-0a1b2c3d", "host-12")
    assert keys.member == "afford/@v1/@workers/inference-0a1b2c3d/host-12"
    assert keys.status("inference-host-12") == keys.member + "/status"
    assert (
        keys.error_of("inference-host-12", "afford/@v1/r1/fields") == "afford/@v1/r1/error/inference-host-12"
    )
    assert keys.error_of("inference-host-12", "(idle)") == keys.member + "/error"
    import zenoh

    # no robot key expression reaches the workers' keys (a verbatim @ chunk)
    assert not zenoh.KeyExpr("afford/@v1/*/status/*").intersects(zenoh.KeyExpr(keys.status("x")))
    assert not zenoh.KeyExpr("afford/@v1/**").intersects(zenoh.KeyExpr(keys.member))


def test_afford_serve_refuses_what_a_worker_cannot_be():
    def serve(*args: str) -> subprocess.CompletedProcess:
        command = [sys.executable, "-m", "affordcli", "serve", *args, "--connect", "tcp/127.0.0.1:9"]
        return subprocess.run(command, capture_output=True, text=True, timeout=120)

    for args, says in [
        (("features", "--robots", "*"), "features serves one robot (--robot); only inference shard"),
        (("inference",), "give either --robot NAME (one robot) or --robots PATTERN"),
        (("inference", "--robot", "r1", "--robots", "*"), "give either --robot NAME"),
        (
            ("inference", "--robot", "r1", "--worker", "w1"),
            "--worker and --shard-by are for a sharded worker",
        ),
        (("inference", "--robots", "**"), "robot selection '**' must be a robot name"),
        (("inference", "--robots", "*", "--shard-by", "room"), "shard unit 'room': choose one of"),
    ]:
        result = serve(*args)
        assert result.returncode == 2 and says in result.stderr, (args, result.stderr)


def test_a_keyed_inbox_keeps_the_newest_input_of_each_robot():
    from services.node import Inbound
    from services.shard import KeyedInbox

    inbox = KeyedInbox(limit=2, max_bytes=100)

    def item(key: str, payload: bytes) -> Inbound:
        return Inbound(key, "", "", payload, time.time())

    assert inbox.offer(item("a", b"1")) is None and inbox.offer(item("b", b"1")) is None
    assert inbox.offer(item("a", b"22")) is None  # supersedes a's first, keeps a's place in line
    assert "keys are waiting" in inbox.offer(item("c", b"1"))
    assert "MAX_QUEUE_BYTES" in inbox.offer(item("a", b"x" * 101))
    assert inbox.supersedes("a") and not inbox.supersedes("c")
    first, second = inbox.take(0.1), inbox.take(0.1)
    assert (first.key, first.payload, second.key) == ("a", b"22", "b")
    assert inbox.skipped == 1 and inbox.take(0.05) is None


# -- two workers in threads on a loopback router -----------------------------------------------------------


class _Worker:
    """A sharded inference worker in a thread (what `afford serve inference --robots '*' --worker ID`
    runs)."""

    def __init__(self, endpoint: str, worker: str, folder: Path):
        from affordcore.geometry.features import FeatureLayout
        from affordcore.learn.model import choose_models
        from services.inference import InferenceService
        from services.node import Node
        from services.settings import ServiceSettings
        from services.shard import Selection, WorkerKeys, group_of

        settings = ServiceSettings()
        models = choose_models([], [], FeatureLayout.from_settings(settings))
        selection = Selection(("*",))
        keys = WorkerKeys(
            selection, group_of("inference", selection, "affordance", [m.id for m in models]), worker
        )
        self.node = Node(
            f"inference-{worker}",
            keys.robot,
            [endpoint],
            settings,
            folder / f"inference-{worker}.rrd",
            affordances=list(AFFORDANCES),
            models=models,
            keys=keys,
        )
        self.service = InferenceService(self.node)
        self.hang: threading.Event | None = None  # set: the next input is taken and never mapped
        self.taken = threading.Event()
        handle = self.service.handle

        def gated(item) -> None:
            if self.hang is None:
                return handle(item)
            self.taken.set()
            self.hang.wait(60)

        self.service.handle = gated
        self.thread = threading.Thread(target=self.service.run, daemon=True)
        self.thread.start()

    def stop(self) -> None:
        self.node.stop_event.set()
        self.thread.join(60)
        assert not self.thread.is_alive()


class _Features:
    """Stands in for each robot's features service: puts fields and answers a get with each robot's
    latest."""

    def __init__(self, session):
        from services.transport import put_message

        self.session, self.put_message, self.latest = session, put_message, {}
        self.queryable = session.declare_queryable("afford/@v1/*/fields", self._answer)

    def _answer(self, query) -> None:
        import zenoh

        from services.transport import encoding_of

        asked = zenoh.KeyExpr(str(query.key_expr))
        for key, message in list(self.latest.items()):
            if asked.intersects(zenoh.KeyExpr(key)):
                query.reply(key, message.SerializeToString(), encoding=encoding_of(type(message)))

    def publish(self, robot: str, fields, points, at: float):
        from affordwire import messages
        from services.transport import Keys

        message = messages.fields_message(fields, messages.cloud_message(points, np.eye(4), "test", at=at))
        self.latest[Keys(robot).fields] = message
        self.put_message(self.session, Keys(robot).fields, message)
        return messages.nanoseconds(message.cloud_timestamp)


class _Maps:
    """Every map published, as (robot/affordance, cloud stamp)."""

    def __init__(self, session):
        self.seen: list[tuple[str, int]] = []
        self._lock = threading.Lock()
        self.subscriber = session.declare_subscriber("afford/@v1/*/affordance/*", self._take)

    def _take(self, sample) -> None:
        from affordwire import messages

        message = messages.parse(messages.AffordanceMapMessage, sample.payload.to_bytes())
        unit = f"{str(sample.key_expr).split('/')[2]}/{message.affordance}"
        with self._lock:
            self.seen.append((unit, messages.nanoseconds(message.cloud_timestamp)))

    def of(self, stamps: dict[str, int]) -> list[str]:
        with self._lock:
            return sorted(unit for unit, stamp in self.seen if stamps[unit.split("/")[0]] == stamp)


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")  # the "killed" worker's
def test_two_workers_share_the_robots_and_the_survivor_maps_what_a_lost_worker_took(tmp_path):
    from conftest import eventually
    from test_services import _box_room_scan

    from affordcore.geometry.fields import compute_fields
    from affordcore.settings import VoxelSettings
    from services.launch import free_port
    from services.shard import owner
    from services.transport import open_session

    robots = ("mh1", "mh2")
    units = [f"{robot}/{a}" for robot in robots for a in AFFORDANCES]
    survivor_id, victim_id = _pair(robots, victim_share=1)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_session([], mode="router", listen=[endpoint])
    client = open_session([endpoint])
    rooms = {robot: _box_room_scan(np.random.default_rng(k)) for k, robot in enumerate(robots)}
    fields = {robot: compute_fields(points, VoxelSettings()) for robot, points in rooms.items()}
    workers = []
    try:
        features, maps = _Features(client), _Maps(client)
        survivor = _Worker(endpoint, survivor_id, tmp_path)
        workers.append(survivor)
        victim = _Worker(endpoint, victim_id, tmp_path)
        workers.append(victim)
        both = {survivor_id, victim_id}
        assert eventually(lambda: survivor.service.members.view() == victim.service.members.view() == both)

        # each unit mapped once, by its owner
        first = {
            robot: features.publish(robot, fields[robot], rooms[robot], 1_700_000_001.0) for robot in robots
        }
        assert eventually(lambda: maps.of(first) == units, timeout=90), maps.seen
        time.sleep(1.0)
        assert len(maps.seen) == len(units), f"a unit mapped twice: {maps.seen}"
        victim_units = [unit for unit in units if owner(both, unit) == victim_id]
        assert victim.node.counts["published"] == len(victim_units) == 2
        assert survivor.node.counts["published"] == len(units) - 2
        replies = [r.ok for r in client.get("afford/@v1/*/affordance/*", timeout=5) if r.ok is not None]
        assert sorted(str(r.key_expr) for r in replies) == sorted(
            f"afford/@v1/{u.split('/')[0]}/affordance/{u.split('/')[1]}" for u in units
        )

        # the victim takes its share of a new room and hangs; then its process is gone (session closed)
        release = victim.hang = threading.Event()
        second = {
            robot: features.publish(robot, fields[robot], rooms[robot], 1_700_000_002.0) for robot in robots
        }
        assert victim.taken.wait(60)
        assert eventually(lambda: len(maps.of(second)) == len(units) - 2, timeout=90), maps.seen
        time.sleep(1.0)
        assert maps.of(second) == sorted(set(units) - set(victim_units)), "the victim's share is not out"
        victim.node.stop_event.set()
        victim.node.session.close()  # its token goes as a killed process's does
        assert eventually(lambda: maps.of(second) == units, timeout=90), maps.seen
        assert survivor.service.recovered >= 1
        assert survivor.node.counts["published"] == len(units) - 2 + len(units)
        release.set()

        # a worker that leaves after its maps went out costs no work: nothing is missing
        published = survivor.node.counts["published"]
        third = _Worker(endpoint, "w-late", tmp_path)
        workers.append(third)
        assert eventually(lambda: survivor.service.members.view() == {survivor_id, "w-late"})
        third.stop()
        workers.remove(third)
        assert eventually(lambda: survivor.service.members.view() == {survivor_id})
        time.sleep(2.0)
        assert survivor.node.counts["published"] == published
    finally:
        for worker in workers:
            worker.node.stop_event.set()
        for worker in workers:
            worker.thread.join(30)
        client.close()
        router.close()


# -- a secured site ------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_in_a_secured_site_only_the_inference_identity_joins_the_workers(tmp_path):
    """The access control of `afford certs` lets a worker with the inference identity hold its tokens, status
    and maps, and drops a token another site identity declares in the workers' group (it would take a share
    of the units and never map them)."""
    from affordcore.example import example_room
    from affordcore.geometry.features import FeatureLayout
    from affordcore.geometry.scene import Cloud, save_cloud
    from affordcore.learn.model import choose_models
    from affordcore.settings import Settings
    from services.launch import Stack
    from services.security import Site, write_site
    from services.shard import Selection, group_of, owner

    site = tmp_path / "site"
    write_site(Site(sensors=["robot"], mappers=["mapper"], viewers=["viewer"]), site)
    settings = Settings()
    models = choose_models([], [], FeatureLayout.from_settings(settings))
    group = group_of("inference", Selection(("*",)), "affordance", [m.id for m in models])
    intruder = next(f"x{i}" for i in range(100) if owner(("s1", f"x{i}"), "sr1/sitting-relaxing") == f"x{i}")
    room = tmp_path / "room.npy"
    save_cloud(room, Cloud(example_room(seed=3).points))
    stack = Stack(tmp_path / "run", robot="sr1", site=site, services=("features",)).start()
    afford = [sys.executable, "-m", "affordcli"]
    worker = subprocess.Popen(
        [*afford, "serve", "inference", "--connect", stack.endpoint, "--robots", "*", "--worker", "s1"]
        + ["--zenoh-config", str(site / "inference.json5"), "--rrd", str(tmp_path / "s1.rrd")],
        stdout=open(tmp_path / "s1.log", "w"),  # noqa: SIM115
        stderr=subprocess.STDOUT,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    viewer, other = stack.session(identity="viewer"), stack.session(identity="robot")
    try:
        member = f"afford/@v1/@workers/{group}/s1"

        def tokens() -> set[str]:
            return {
                str(r.ok.key_expr)
                for r in other.liveliness().get("afford/@v1/@workers/**", timeout=2)  # through the router
                if r.ok is not None
            }

        deadline = time.monotonic() + 90
        while {member, member + "/status"} - tokens():
            assert worker.poll() is None and time.monotonic() < deadline, (tmp_path / "s1.log").read_text()
            time.sleep(0.5)
        forged = viewer.liveliness().declare_token(f"afford/@v1/@workers/{group}/{intruder}")
        time.sleep(1.0)
        assert f"afford/@v1/@workers/{group}/{intruder}" not in tokens()

        published = subprocess.run(
            [*afford, "publish", str(room), "--as-map", "--gravity", "none", "--connect", stack.endpoint]
            + ["--robot", "sr1", "--zenoh-config", str(site / "mapper.json5")],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert published.returncode == 0, published.stderr
        stamp = re.search(r"stamped (\d+\.\d{9})", published.stdout).group(1)
        watched = subprocess.run(
            [*afford, "watch", "--connect", stack.endpoint, "--robot", "sr1", "--since", stamp, "--quiet"]
            + ["--timeout", "120", "--zenoh-config", str(site / "viewer.json5")],
            capture_output=True, text=True, timeout=180,
        )  # fmt: skip
        assert watched.returncode == 0, watched.stdout + watched.stderr + (tmp_path / "s1.log").read_text()
        forged.undeclare()
        assert intruder not in (tmp_path / "s1.log").read_text(), "a viewer's token joined the workers"
    finally:
        viewer.close()
        other.close()
        worker.send_signal(signal.SIGTERM)
        code = worker.wait(30)
        stack.stop()
    assert code == 0, (tmp_path / "s1.log").read_text()


# -- two hosts: network namespaces ---------------------------------------------------------------------------

PREFIX = "afmh"  # every namespace and link this test makes starts with it; stale ones are removed at start
HOSTS = (f"{PREFIX}-a", f"{PREFIX}-b")
LINKS = (f"{PREFIX}-va", f"{PREFIX}-vb")
ADDRESSES = ("10.231.47.1", "10.231.47.2")  # a /30 of the test's own, inside its namespaces only
LOCAL = "tcp/127.0.0.1:7447"  # each host's router, as its processes reach it


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    result = subprocess.run(["ip", *args], capture_output=True, text=True, timeout=20)
    if check and result.returncode != 0:
        raise RuntimeError(f"ip {' '.join(args)}: {result.stderr.strip()}")
    return result


def _remove_hosts() -> None:
    listed = _ip("netns", "list", check=False).stdout.split()
    for name in listed:
        if name.startswith(f"{PREFIX}-"):
            _ip("netns", "del", name, check=False)  # takes its end of the veth pair, and so both ends
    for link in LINKS:
        _ip("link", "del", link, check=False)


def _make_hosts() -> None:
    for host in HOSTS:
        _ip("netns", "add", host)
    _ip("link", "add", LINKS[0], "type", "veth", "peer", "name", LINKS[1])
    for host, link, address in zip(HOSTS, LINKS, ADDRESSES, strict=True):
        _ip("link", "set", link, "netns", host)
        _ip("-n", host, "addr", "add", f"{address}/30", "dev", link)
        _ip("-n", host, "link", "set", link, "up")
        _ip("-n", host, "link", "set", "lo", "up")


def _why_no_namespaces() -> str | None:
    if os.geteuid() != 0:
        return "needs root to make network namespaces (ip netns)"
    if shutil.which("ip") is None:
        return "the ip command (iproute2) is not installed"
    probe = f"{PREFIX}-probe"
    made = _ip("netns", "add", probe, check=False)
    if made.returncode != 0:
        return f"ip netns is not available here: {made.stderr.strip()}"
    _ip("netns", "del", probe, check=False)
    return None


class _Processes:
    """Children in the namespaces, each with its log; all stopped at the end."""

    def __init__(self, folder: Path):
        self.folder, self.children = folder, {}
        self.env = {**os.environ, "PYTHONUNBUFFERED": "1", "AFFORD_SERVICE__STATUS_PERIOD": "1"}

    def start(self, name: str, host: str, *args: str, stdout=None) -> subprocess.Popen:
        command = ["ip", "netns", "exec", host, sys.executable, *args]  # ip execs: the pid is python's
        log = stdout or open(self.folder / f"{name}.log", "w")  # noqa: SIM115 - the child keeps it
        process = subprocess.Popen(
            command,
            stdout=log,
            stderr=subprocess.STDOUT if stdout is None else None,
            env=self.env,
            cwd=ROOT,
            text=True,
        )
        self.children[name] = process
        return process

    def afford(self, name: str, host: str, *args: str) -> subprocess.Popen:
        return self.start(name, host, "-m", "affordcli", *args)

    def run(self, host: str, *args: str, timeout: float) -> subprocess.CompletedProcess:
        command = ["ip", "netns", "exec", host, sys.executable, "-m", "affordcli", *args]
        return subprocess.run(
            command, capture_output=True, text=True, timeout=timeout, env=self.env, cwd=ROOT
        )

    def stop(self) -> None:
        for process in self.children.values():
            if process.poll() is None:
                process.send_signal(signal.SIGTERM)
        for process in self.children.values():
            try:
                process.wait(20)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()

    def logs(self) -> str:
        return "\n".join(f"--- {p.name}\n{p.read_text()[-2500:]}" for p in sorted(self.folder.glob("*.log")))


class _Events:
    """The observer's JSON lines, read on a thread."""

    def __init__(self, process: subprocess.Popen):
        self.queue: queue.Queue = queue.Queue()
        self.all: list[dict] = []
        threading.Thread(target=self._read, args=(process,), daemon=True).start()

    def _read(self, process) -> None:
        for line in process.stdout:
            if line.startswith("{"):
                self.queue.put(json.loads(line))

    def until(self, condition, timeout: float) -> dict | None:
        """Read events until one satisfies `condition` (returned) or `timeout` passes (None)."""
        deadline = time.monotonic() + timeout
        for event in self.all:
            if condition(event):
                return event
        while time.monotonic() < deadline:
            try:
                event = self.queue.get(timeout=0.2)
            except queue.Empty:
                continue
            self.all.append(event)
            if condition(event):
                return event
        return None

    def maps(self, stamps: dict[str, int]) -> set[str]:
        return {
            f"{e['robot']}/{e['affordance']}"
            for e in self.all
            if e["event"] == "map" and stamps.get(e["robot"]) == e["stamp"]
        }


def _publish(procs: _Processes, host: str, robot: str, room: Path) -> int:
    result = procs.run(
        host,
        "publish",
        str(room),
        "--as-map",
        "--gravity",
        "none",
        "--connect",
        LOCAL,
        "--robot",
        robot,
        timeout=90,
    )
    assert result.returncode == 0, result.stdout + result.stderr + procs.logs()
    seconds, nanos = re.search(r"stamped (\d+)\.(\d{9})", result.stdout).groups()
    return int(seconds) * 1_000_000_000 + int(nanos)


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_two_hosts_two_routers_a_worker_killed_mid_run_and_every_map_still_delivered(tmp_path):
    reason = _why_no_namespaces()
    if reason:
        pytest.skip(reason)
    from affordcore.example import example_room
    from affordcore.geometry.scene import Cloud, save_cloud
    from services.shard import owner

    robots = ("r1", "r2")
    units = {f"{robot}/{a}" for robot in robots for a in AFFORDANCES}
    survivor_id, victim_id = _pair(robots, victim_share=2)
    rooms = {}
    for k, robot in enumerate(robots):
        rooms[robot] = tmp_path / f"{robot}.npy"
        save_cloud(rooms[robot], Cloud(example_room(seed=k).points + [0.3 * k, 0, 0]))
    router_b = tmp_path / "router-b.json5"  # host B's router links to host A's
    router_b.write_text(json.dumps({"connect": {"endpoints": [f"tcp/{ADDRESSES[0]}:7447"]}}))

    _remove_hosts()
    procs = _Processes(tmp_path)
    started = time.monotonic()
    try:
        _make_hosts()
        a, b = HOSTS
        procs.afford("router-a", a, "router", "--listen", "tcp/0.0.0.0:7447")
        procs.afford("router-b", b, "router", "--listen", "tcp/0.0.0.0:7447", "--zenoh-config", str(router_b))
        observer = procs.start("observer", a, __file__, "observe", LOCAL, stdout=subprocess.PIPE)
        events = _Events(observer)
        assert events.until(lambda e: e["event"] == "ready", 60), procs.logs()
        # each robot publishes from the other host than its features: every cloud crosses the link
        procs.afford(
            "features-r1",
            a,
            "serve",
            "features",
            "--connect",
            LOCAL,
            "--robot",
            "r1",
            "--rrd",
            str(tmp_path / "features-r1.rrd"),
        )
        procs.afford(
            "features-r2",
            b,
            "serve",
            "features",
            "--connect",
            LOCAL,
            "--robot",
            "r2",
            "--rrd",
            str(tmp_path / "features-r2.rrd"),
        )
        workers = {survivor_id: a, victim_id: b}
        for worker, host in workers.items():
            procs.afford(
                f"inference-{worker}",
                host,
                "serve",
                "inference",
                "--connect",
                LOCAL,
                "--robots",
                "*",
                "--worker",
                worker,
                "--rrd",
                str(tmp_path / f"inference-{worker}.rrd"),
            )

        def ready(name: str):
            return lambda e: (
                e["event"] == "status" and e["service"] == name and e["state"] in ("READY", "BUSY")
            )

        for robot in robots:
            assert events.until(
                lambda e, r=robot: e["event"] == "alive" and e["key"] == f"afford/@v1/{r}/status/features", 90
            ), procs.logs()
        for worker in workers:
            assert events.until(ready(f"inference-{worker}"), 90), procs.logs()
        setup = time.monotonic() - started

        # round 1: each robot, from the other host, publishes a finished room; both workers take their share
        first = {"r1": _publish(procs, b, "r1", rooms["r1"]), "r2": _publish(procs, a, "r2", rooms["r2"])}
        assert events.until(lambda e: events.maps(first) == units, 90), (events.maps(first), procs.logs())
        round_one = time.monotonic() - started - setup
        for worker in workers:
            assert events.until(
                lambda e, w=worker: (
                    e["event"] == "status" and e["service"] == f"inference-{w}" and e["published"] >= 2
                ),
                10,
            ), f"worker {worker} took no share: {procs.logs()}"

        # round 2: new rooms; the victim is killed as soon as it works on one, before it maps its share
        victim_name = f"inference-{victim_id}"
        accepted = max(
            e["accepted"] for e in events.all if e["event"] == "status" and e["service"] == victim_name
        )
        publishers = [
            threading.Thread(target=lambda: second.__setitem__("r1", _publish(procs, b, "r1", rooms["r1"]))),
            threading.Thread(target=lambda: second.__setitem__("r2", _publish(procs, a, "r2", rooms["r2"]))),
        ]
        second: dict[str, int] = {}
        for thread in publishers:
            thread.start()
        busy = events.until(
            lambda e: (
                e["event"] == "status"
                and e["service"] == victim_name
                and e["state"] == "BUSY"
                and e["accepted"] > accepted
                and e["detail"].startswith("mapping")
            ),
            90,
        )
        assert busy, procs.logs()
        procs.children[victim_name].kill()
        killed_at = time.time()
        procs.children[victim_name].wait(10)
        for thread in publishers:
            thread.join(90)
        assert set(second) == set(robots)
        out_at_kill = events.maps(second)
        victim_units = {u for u in units if owner((survivor_id, victim_id), u) == victim_id}
        busy_robot = busy["detail"].rsplit(" of ", 1)[-1]
        assert {u for u in victim_units if u.startswith(busy_robot + "/")}.isdisjoint(out_at_kill)

        assert events.until(lambda e: events.maps(second) == units, 90), (events.maps(second), procs.logs())
        recovered = time.time() - killed_at
        after_kill = {
            f"{e['robot']}/{e['affordance']}"
            for e in events.all
            if e["event"] == "map" and e["stamp"] == second.get(e["robot"]) and e["t"] > killed_at
        }
        assert victim_units & after_kill, "the survivor took over none of the victim's units"
        assert events.until(lambda e: e["event"] == "left" and e["key"].endswith("/" + victim_id), 10)

        # a late watcher on host B gets every map of r1's newest room, answered by the survivor on host A
        stamp = second["r1"]
        since = f"{stamp // 1_000_000_000}.{stamp % 1_000_000_000:09d}"
        watched = procs.run(
            b,
            "watch",
            "--connect",
            LOCAL,
            "--robot",
            "r1",
            "--since",
            since,
            "--quiet",
            "--timeout",
            "20",
            timeout=60,
        )
        assert watched.returncode == 0, watched.stdout + watched.stderr + procs.logs()
        survivor = procs.children[f"inference-{survivor_id}"]
        survivor.send_signal(signal.SIGTERM)
        assert survivor.wait(30) == 0
        survivor_log = (tmp_path / f"inference-{survivor_id}.log").read_text()
        assert f"left: ['{victim_id}']" in survivor_log
        assert re.search(r"[1-9]\d* inputs fetched again after a worker left", survivor_log), survivor_log
        print(
            f"hosts ready in {setup:.1f} s; six maps of the first rooms in {round_one:.1f} s; every map of "
            f"the second rooms {recovered:.1f} s after the kill (victim {victim_id} on {b}, units "
            f"{sorted(victim_units)}; out before the kill: {sorted(out_at_kill)}); whole test "
            f"{time.monotonic() - started:.1f} s"
        )
    finally:
        procs.stop()
        _remove_hosts()


# -- the observer, run inside a namespace --------------------------------------------------------------------


def observe(endpoint: str) -> None:
    """Print, as JSON lines, the workers' statuses and tokens, the services' tokens and every map."""
    import zenoh

    sys.path.insert(0, str(ROOT))
    from affordwire import messages
    from services.transport import WORKERS, open_session

    lock = threading.Lock()

    def emit(**event) -> None:
        with lock:
            print(json.dumps(event), flush=True)

    def on_status(sample) -> None:
        if str(sample.key_expr).endswith("/status"):
            s = messages.parse(messages.Status, sample.payload.to_bytes())
            emit(
                event="status",
                service=s.service,
                state=messages.Status.State.Name(s.state),
                detail=s.detail,
                accepted=s.accepted,
                published=s.published,
            )

    def on_map(sample) -> None:
        message = messages.parse(messages.AffordanceMapMessage, sample.payload.to_bytes())
        emit(
            event="map",
            robot=str(sample.key_expr).split("/")[2],
            affordance=message.affordance,
            stamp=messages.nanoseconds(message.cloud_timestamp),
            t=time.time(),
        )

    def on_token(sample) -> None:
        alive = sample.kind == zenoh.SampleKind.PUT
        emit(event="alive" if alive else "left", key=str(sample.key_expr))

    session = open_session([endpoint], wait=60)
    session.declare_subscriber(f"{WORKERS}/**", on_status)
    session.declare_subscriber("afford/@v1/*/affordance/*", on_map)
    session.liveliness().declare_subscriber(f"{WORKERS}/**", on_token, history=True)
    session.liveliness().declare_subscriber("afford/@v1/*/status/*", on_token, history=True)
    emit(event="ready")
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    stop.wait()
    session.close()


if __name__ == "__main__" and sys.argv[1:2] == ["observe"]:
    observe(sys.argv[2])
