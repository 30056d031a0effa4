"""Sharded inference: maps per minute for N robots with 1 and with 2 inference workers (services/shard.py), on
this machine.

    .venv/bin/python benchmarks/bench_multihost.py [--robots 1 2 4] [--workers 1 2] [--repeats 3]

A router and K workers (`afford serve inference --robots '*' --worker ID`) run as processes on loopback; this
process stands in for every robot's features service: each round it puts the fields of the built-in example
room (6 m x 5 m, three affordances) for N robots at once, with a new cloud stamp, and answers gets with them.
A round's time runs from the first put to the last of the N x 3 maps; maps per minute = N x 3 / that time.
Medians over `repeats` rounds per configuration (after one warm-up round), each configuration on fresh
processes; also each worker's resident memory after its rounds. The workers run at the default priority
(AFFORD_SERVICE__DOWNSTREAM_NICE=0: niced, on a shared machine, they would measure the other jobs) and share
the machine's cores: K workers on C cores are bounded by C.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
import psutil  # noqa: E402

from affordwire import messages  # noqa: E402
from services.launch import free_port, python_call  # noqa: E402
from services.transport import encoding_of, open_session, put_message  # noqa: E402

AFFORDANCES = ("sitting-relaxing", "sitting-working", "standing-working")


def example_fields() -> messages.SceneFieldsMessage:
    from affordcore.example import example_room
    from affordcore.geometry.fields import compute_fields
    from affordcore.settings import Settings

    points = example_room(seed=0).points.astype(np.float32)
    fields = compute_fields(points, Settings().voxel)
    return messages.fields_message(fields, messages.cloud_message(points, np.eye(4), "bench"))


class Fleet:
    """Stands in for N robots' features services: puts fields, answers gets, and times the maps."""

    def __init__(self, session, robots: list[str], fields: messages.SceneFieldsMessage):
        self.session, self.robots, self.fields = session, robots, fields
        self.latest: dict[str, messages.SceneFieldsMessage] = {}
        self.wanted: set[str] = set()
        self.stamp = 0
        self.done = threading.Event()
        self._lock = threading.Lock()
        session.declare_queryable("afford/@v1/*/fields", self._answer)
        session.declare_subscriber("afford/@v1/*/affordance/*", self._take)

    def _answer(self, query) -> None:
        import zenoh

        asked = zenoh.KeyExpr(str(query.key_expr))
        for key, message in list(self.latest.items()):
            if asked.intersects(zenoh.KeyExpr(key)):
                query.reply(key, message.SerializeToString(), encoding=encoding_of(type(message)))

    def _take(self, sample) -> None:
        message = messages.parse(messages.AffordanceMapMessage, sample.payload.to_bytes())
        with self._lock:
            if messages.nanoseconds(message.cloud_timestamp) == self.stamp:
                self.wanted.discard(str(sample.key_expr))
                if not self.wanted:
                    self.done.set()

    def round(self, timeout: float = 600.0) -> float:
        """Put every robot's fields with a new stamp; seconds until every map of them is out."""
        message = messages.SceneFieldsMessage()
        message.CopyFrom(self.fields)
        messages.stamp(message.cloud_timestamp)
        with self._lock:
            self.stamp = messages.nanoseconds(message.cloud_timestamp)
            self.wanted = {f"afford/@v1/{r}/affordance/{a}" for r in self.robots for a in AFFORDANCES}
            self.done.clear()
        start = time.monotonic()
        for robot in self.robots:
            key = f"afford/@v1/{robot}/fields"
            self.latest[key] = message
            put_message(self.session, key, message)
        if not self.done.wait(timeout):
            raise RuntimeError(f"maps missing after {timeout} s: {sorted(self.wanted)}")
        return time.monotonic() - start


def run(robots: int, workers: int, repeats: int, fields, folder: Path) -> tuple[list[float], list[float]]:
    """Round times (s) and each worker's resident memory (MB) for `robots` robots and `workers` workers."""
    import subprocess

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    # the workers at the default priority: on a shared machine, niced workers would measure the other jobs
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "AFFORD_SERVICE__DOWNSTREAM_NICE": "0"}
    children = []
    log = open(folder / f"bench-{robots}-{workers}.log", "w")  # noqa: SIM115 - the children keep it
    children.append(
        subprocess.Popen(
            python_call("services.clients:run_router", [endpoint]), stdout=log, stderr=log, env=env
        )
    )
    session = open_session([endpoint])
    names = [f"robot{k + 1}" for k in range(robots)]
    fleet = Fleet(session, names, fields)
    try:
        for k in range(workers):
            call = python_call(
                "services.registry:run_service", "inference", None, [endpoint],
                rrd=str(folder / f"w{k}.rrd"), robots=["*"], worker=f"w{k}",
            )  # fmt: skip
            children.append(subprocess.Popen(call, stdout=log, stderr=log, env=env))
        key = "afford/@v1/@workers/**"
        deadline = time.monotonic() + 120
        while len([r for r in session.liveliness().get(key, timeout=2) if r.ok is not None]) < 2 * workers:
            if time.monotonic() > deadline:
                raise RuntimeError(f"workers not up; see {log.name}")
            time.sleep(0.5)  # each worker: its status token and its membership token
        time.sleep(1.0)  # every worker has heard of every other
        fleet.round()  # warm-up: imports, first allocations
        times = [fleet.round() for _ in range(repeats)]
        rss = [psutil.Process(c.pid).memory_info().rss / 2**20 for c in children[1:]]
        return times, rss
    finally:
        session.close()
        for child in reversed(children):
            child.terminate()
        for child in children:
            child.wait(60)
        log.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, nargs="+", default=[1, 2, 4])
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    fields = example_fields()
    load = [os.getloadavg()[0]]  # the machine's other work: two workers need two free cores to double
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for robots in args.robots:
            for workers in args.workers:
                times, rss = run(robots, workers, args.repeats, fields, Path(folder))
                median = statistics.median(times)
                rows.append((robots, workers, median, times, rss))
                load.append(os.getloadavg()[0])
                print(f"{robots} robots, {workers} workers: {median:.2f} s per round", flush=True)
    print(
        f"\n{os.cpu_count()} cores; the built-in example room's fields (6 m x 5 m, "
        f"{len(fields.SerializeToString()) / 2**20:.1f} MB) for N robots at once, three affordances each; "
        f"medians of {args.repeats} rounds; load average (1 min) {min(load):.1f}-{max(load):.1f} in the run\n"
    )
    print(
        "| robots | workers | maps | round (s) | maps per minute | s per map | x 1 worker | worker RSS (MB) |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|---|")
    single = {robots: median for robots, workers, median, _, _ in rows if workers == 1}
    for robots, workers, median, times, rss in rows:
        maps = robots * len(AFFORDANCES)
        speedup = f"{single[robots] / median:.2f}" if robots in single else "-"
        runs, memory = ", ".join(f"{t:.1f}" for t in times), ", ".join(f"{m:.0f}" for m in rss)
        print(
            f"| {robots} | {workers} | {maps} | {median:.2f} ({runs}) | {maps / median * 60:.0f} | "
            f"{median / maps:.2f} | {speedup} | {memory} |"
        )


if __name__ == "__main__":
    main()
