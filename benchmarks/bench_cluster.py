"""Rooms per minute in local processes and on a Ray cluster, side by side in one run.

Two steps of the learning loop, each over the same rooms: generating and scanning them (`afford synth`'s
`synth.batch.synthesize`, default depth scanner and styles), then featurising them (each room's voxel fields
and one affordance's sampled feature rows into a fresh room cache: `load_rooms`, `example_set`). Locally they
run in `--workers` processes; on Ray in the tasks of a cluster started here (`affordcli.cluster.
local_ray_cluster`: a head and a worker node of one CPU each, unless --address names a running cluster).
Settings as they are; medians over `--repeats`, local and Ray alternating.

    .venv/bin/python benchmarks/bench_cluster.py --rooms 8 --repeats 1
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from contextlib import nullcontext
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rooms", type=int, default=8)
    parser.add_argument("--seed", type=int, default=5)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--workers", type=int, default=2, help="local processes")
    parser.add_argument("--affordance", default="sitting-relaxing")
    parser.add_argument("--address", help="a running Ray cluster (default: start one on this machine)")
    args = parser.parse_args()

    from affordcli.cluster import local_ray_cluster

    load = os.getloadavg()
    with nullcontext(args.address) if args.address else local_ray_cluster((1, 1)) as address:
        seconds: dict[tuple[str, str], list[float]] = {}
        for repeat in range(args.repeats):
            for where in ("local", "ray"):
                with tempfile.TemporaryDirectory(prefix="bench-cluster-") as folder:
                    for step, took in run(args, Path(folder), address if where == "ray" else None).items():
                        seconds.setdefault((step, where), []).append(took)
                        print(f"repeat {repeat + 1}, {where}, {step}: {took:.1f} s", flush=True)
    print()
    print(
        f"{args.rooms} rooms, seed {args.seed}; {os.cpu_count()} cores, load {load[0]:.1f} at the start and "
        f"{os.getloadavg()[0]:.1f} at the end; local: {args.workers} processes; Ray: "
        + (f"cluster at {args.address}" if args.address else "a head and a worker node of 1 CPU each here")
        + f"; medians over {args.repeats} repeat(s)"
    )
    print()
    print("| step | local: rooms / min | Ray: rooms / min | Ray / local |")
    print("|---|---:|---:|---:|")
    for step in ("generate and scan", "fields and examples"):
        local, ray = (args.rooms * 60 / statistics.median(seconds[step, w]) for w in ("local", "ray"))
        print(f"| {step} | {local:.1f} | {ray:.1f} | {ray / local:.2f} |")


def run(args, folder: Path, address: str | None) -> dict[str, float]:
    """Seconds of each step, in local processes or (with `address`) on the Ray cluster there."""
    from affordcli.cluster import cluster_jobs
    from affordcore.geometry.features import FeatureLayout
    from affordcore.learn.cache import RoomCache
    from affordcore.learn.examples import Task, data_set_rooms, example_set, load_rooms
    from affordcore.settings import ClusterSettings, LearnSettings, Settings
    from affordcore.synth.batch import synthesize
    from affordcore.synth.dataset import SynthOptions

    settings = Settings(learn=LearnSettings(workers=args.workers), cluster=ClusterSettings(address=address))
    cache = RoomCache(folder / "cache")
    took = {}
    with cluster_jobs(settings):
        start = time.perf_counter()
        synthesize(SynthOptions(args.rooms, args.seed), folder / "rooms", args.workers)
        took["generate and scan"] = time.perf_counter() - start
        start = time.perf_counter()
        rooms = load_rooms(data_set_rooms(folder / "rooms"), settings, cache=cache)
        task = Task(args.affordance, settings, FeatureLayout.from_settings(settings))
        example_set(rooms, task, cache=cache)
        took["fields and examples"] = time.perf_counter() - start
    return took


if __name__ == "__main__":
    main()
