"""Latency of the services: from the last scan published to the map, the fields and every affordance map built
from all the scans, with the router and the three services as separate processes on this machine.

    .venv/bin/python benchmarks/bench_services.py [--frames 100] [--step 3] [--rate 30] [--repeats 3]

Streams the real 7-Scenes kitchen frames (../shared) when present, else a generated living room's. Each
repeat starts a fresh stack. Prints per-stage latency medians and the assembler's own frame rate.
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

from affordcore.assembly.sequence import read_sequence  # noqa: E402
from affordcore.learn.model import shipped_models  # noqa: E402
from affordwire import messages  # noqa: E402
from services.clients import publish_sequence, sequence_messages  # noqa: E402
from services.launch import Stack  # noqa: E402
from services.transport import Keys, open_session, schema_of  # noqa: E402

KITCHEN = ROOT.parent / "shared" / "data" / "sequences" / "7scenes_redkitchen_frames_000000-000299"


def generated_sequence(folder: Path, frames: int) -> Path:
    import numpy as np

    from affordcore.synth.dataset import write_sequence
    from affordcore.synth.rooms import generate_room

    rng = np.random.default_rng(3)
    write_sequence(generate_room("living", rng, "bench"), rng, folder, "depth", frames)
    return folder


class Arrivals:
    """When the first output built from every accepted scan arrived on each key. The assembler may pass
    over frames it cannot keep up with (AFFORD_SERVICE__MAX_LAG), so "every accepted scan" is the number of
    poses it published, known once the stream has ended."""

    def __init__(self, affordances: list[str]):
        self.wanted = {f"affordance/{name}" for name in affordances} | {"map/cloud", "fields"}
        self.poses = 0
        self.first: dict[tuple[str, int], float] = {}  # (key, frames) -> first arrival
        self.lock = threading.Lock()

    def on_sample(self, sample) -> None:
        now = time.monotonic()
        key = str(sample.key_expr).split("/", 3)[3]
        if key == "map/pose":
            with self.lock:
                self.poses += 1
            return
        classes = {"map/cloud": messages.CloudMessage, "fields": messages.SceneFieldsMessage}
        cls = classes.get(key, messages.AffordanceMapMessage if key.startswith("affordance/") else None)
        if cls is None or schema_of(sample) != messages.schema_name(cls):
            return
        frames = messages.parse(cls, sample.payload.to_bytes()).frames
        with self.lock:
            self.first.setdefault((key, frames), now)

    def wait(self, timeout: float) -> dict[str, float] | None:
        """{key: first arrival of its output from every accepted scan}, or None after `timeout` s."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self.lock:
                done = {key: self.first.get((key, self.poses)) for key in self.wanted}
            if all(done.values()):
                return done
            time.sleep(0.05)
        return None


def one_run(folder: Path, indices: list[int], rate: float, workdir: Path) -> dict[str, float]:
    sequence = read_sequence(folder)
    affordances = list(shipped_models())
    arrivals = Arrivals(affordances)
    with Stack(workdir) as stack:
        keys = Keys(stack.robot)
        session = open_session([stack.endpoint])
        subscriber = session.declare_subscriber(keys.key("**"), arrivals.on_sample)
        try:
            start = time.monotonic()
            publish_sequence(session, keys, sequence_messages(sequence, indices), "camera", rate, wait=30)
            last_scan = time.monotonic()
            arrived = arrivals.wait(600)
            if arrived is None:
                raise RuntimeError(
                    f"outputs of all {arrivals.poses} accepted scans missing after 600 s\n{stack.logs()}"
                )
        finally:
            subscriber.undeclare()
            session.close()
    result = {key: at - last_scan for key, at in arrived.items()}
    result["publishing (s)"] = last_scan - start
    result["frames taken (of those published)"] = arrivals.poses
    result["every map"] = max(v for k, v in result.items() if k.startswith("affordance/"))
    result["every map, after the last map/cloud"] = result["every map"] - result["map/cloud"]
    return result


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--step", type=int, default=3)
    parser.add_argument("--rate", type=float, default=30.0)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = (
            KITCHEN if KITCHEN.is_dir() else generated_sequence(Path(tmp) / "seq", args.frames * args.step)
        )
        indices = list(range(0, len(read_sequence(folder).frames), args.step))[: args.frames]
        runs = [one_run(folder, indices, args.rate, Path(tmp) / f"run{k}") for k in range(args.repeats)]
    source = "7-Scenes redkitchen (real)" if folder == KITCHEN else "generated living room"
    print(
        f"\n{source}: {len(indices)} frames (every {args.step} of the sequence) at {args.rate:g} Hz, "
        f"{args.repeats} runs, "
        f"{os.cpu_count()} cores; services as processes on one machine\n"
    )
    print("| from the last scan published to ... | median (s) | runs (s) |\n|---|---:|---|")
    for key in runs[0]:
        values = [run[key] for run in runs]
        print(f"| {key} | {statistics.median(values):.2f} | {', '.join(f'{v:.2f}' for v in values)} |")


if __name__ == "__main__":
    main()
