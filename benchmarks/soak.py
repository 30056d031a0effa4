"""Soak: depth frames at 15 Hz for 10 minutes into the router and the three services as processes, with the
default settings (a late frame is passed over, never two in a row). Per minute: frames sent, taken, passed
over (skipped) and refused by the assembler, how far behind the sensor its poses come out (lag: a pose's
arrival minus its frame's stamp), maps published, and each process's resident memory.

    .venv/bin/python benchmarks/soak.py [--minutes 10] [--rate 15] [--hogs 2]

Streams the real 7-Scenes kitchen frames (../shared) back and forth (0..299, 298..1, ...: the camera never
jumps, and the room stays the same size, so memory should stay flat), else a generated living room's.
Prints a markdown table (docs/services.md, "Soak").
"""

from __future__ import annotations

import argparse
import itertools
import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from affordwire import messages  # noqa: E402
from services.clients import publish_sequence, sequence_messages  # noqa: E402
from services.launch import Stack, cpu_hogs  # noqa: E402
from services.transport import Keys, open_session  # noqa: E402

KITCHEN = ROOT.parent / "shared" / "data" / "sequences" / "7scenes_redkitchen_frames_000000-000299"
SERVICES = ("assembler", "features", "inference")


def back_and_forth(folder: Path):
    """(index, message) for ever: the frames forward, then backward, then forward again."""
    from affordcore.assembly.sequence import read_sequence

    sequence = read_sequence(folder)
    frames = [message for _, message in sequence_messages(sequence, range(len(sequence.frames)))]
    order = list(range(len(frames))) + list(range(len(frames) - 2, 0, -1))
    for index in itertools.cycle(order):
        frames[index].ClearField("timestamp")  # publish_sequence stamps it at sending, each time round
        yield index, frames[index]


class Minute:
    """What one minute saw."""

    def __init__(self):
        self.lags: list[float] = []
        self.maps = 0


class Observer:
    """Lags of the assembler's poses and the maps it publishes, minute by minute."""

    def __init__(self, start: float):
        self.start, self.minutes = start, {}
        self.lock = threading.Lock()

    def minute(self) -> Minute:
        return self.minutes.setdefault(int((time.monotonic() - self.start) // 60), Minute())

    def on_pose(self, sample) -> None:
        pose = messages.parse(messages.Pose, sample.payload.to_bytes())
        lag = time.time() - (pose.timestamp.seconds + pose.timestamp.nanos * 1e-9)
        with self.lock:
            self.minute().lags.append(lag)

    def on_cloud(self, _sample) -> None:
        with self.lock:
            self.minute().maps += 1


def status(session, keys: Keys) -> messages.Status:
    for reply in session.get(keys.status("assembler"), timeout=5):
        if reply.ok is not None:
            return messages.parse(messages.Status, reply.ok.payload.to_bytes())
    raise RuntimeError("the assembler did not answer a get on its status")


def rss_mb(stack: Stack) -> dict[str, float]:
    import psutil

    return {
        name: psutil.Process(stack.processes[name].pid).memory_info().rss / 2**20
        for name in (*SERVICES, "router")
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--rate", type=float, default=15.0)
    parser.add_argument("--hogs", type=int, default=0, help="processes keeping a core busy meanwhile")
    args = parser.parse_args()
    print(f"{os.cpu_count()} cores, {args.hogs} CPU hogs, {args.rate:g} Hz for {args.minutes:g} minutes")

    with tempfile.TemporaryDirectory() as tmp, cpu_hogs(args.hogs):
        folder = KITCHEN
        if not folder.is_dir():
            from bench_services import generated_sequence

            folder = generated_sequence(Path(tmp) / "room.sequence", 120)
        stack = Stack(Path(tmp) / "run").start()
        keys = Keys(stack.robot)
        session = open_session([stack.endpoint])
        observer = Observer(time.monotonic())
        subscribers = [
            session.declare_subscriber(keys.pose, observer.on_pose),
            session.declare_subscriber(keys.cloud, observer.on_cloud),
        ]
        rows, sent, stop = [], [0], threading.Event()
        frames = itertools.takewhile(lambda _: not stop.is_set(), back_and_forth(folder))

        def on_frame(_index: int) -> None:
            sent[0] += 1

        publisher = threading.Thread(
            target=publish_sequence,
            args=(session, keys, frames, "camera", args.rate, 30.0, on_frame),
            daemon=True,
        )
        publisher.start()
        previous, previous_sent = status(session, keys), 0
        try:
            for minute in range(int(args.minutes)):
                time.sleep(max(0.0, observer.start + 60 * (minute + 1) - time.monotonic()))
                now, memory, count = status(session, keys), rss_mb(stack), sent[0]
                with observer.lock:
                    seen = observer.minutes.get(minute, Minute())
                    lags = sorted(seen.lags)
                rows.append(
                    {
                        "minute": minute + 1,
                        "sent": count - previous_sent,
                        "taken": now.accepted - previous.accepted,
                        "skipped": now.skipped - previous.skipped,
                        "refused": now.rejected - previous.rejected,
                        "lag_median": statistics.median(lags) if lags else float("nan"),
                        "lag_max": lags[-1] if lags else float("nan"),
                        "maps": seen.maps,
                        **{f"rss_{name}": mb for name, mb in memory.items()},
                    }
                )
                print(_row(rows[-1]), flush=True)
                previous, previous_sent = now, count
        finally:
            stop.set()
            publisher.join(30)
            for subscriber in subscribers:
                subscriber.undeclare()
            session.close()
            codes = stack.stop()
    print()
    print(f"{args.rate:g} Hz depth frames, {args.minutes:g} min, {os.cpu_count()} cores, exit codes {codes}")
    print(_header())
    for row in rows:
        print(_row(row))


def _header() -> str:
    columns = ["minute", "sent", "taken", "skipped", "refused", "lag median (s)", "lag max (s)", "maps"]
    columns += [f"RSS {name} (MB)" for name in (*SERVICES, "router")]
    return "| " + " | ".join(columns) + " |\n|" + "---|" * len(columns)


def _row(row: dict) -> str:
    cells = [row["minute"], row["sent"], row["taken"], row["skipped"], row["refused"]]
    cells += [f"{row['lag_median']:.2f}", f"{row['lag_max']:.2f}", row["maps"]]
    cells += [f"{row[f'rss_{name}']:.0f}" for name in (*SERVICES, "router")]
    return "| " + " | ".join(map(str, cells)) + " |"


if __name__ == "__main__":
    main()
