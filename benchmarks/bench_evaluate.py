"""`afford evaluate` at its defaults, as a user runs it, on generated rooms: this tree against an older one.

The data set is `afford synth --rooms N --seed S` (12 and 1: the command docs/learning.md quotes), made once
in bench-data/evaluate/. Each run is a fresh `afford evaluate --data ROOMS --folds 3 --out DIR -q` process
with a fresh room cache (`AFFORD_LEARN__CACHE_DIR` in a temporary folder), so every run computes the rooms'
fields and examples as a first run does. Measured: wall seconds, CPU seconds of the process tree, the
largest process's peak RSS, the tree's summed RSS (sampled every second: a lower bound on its peak) and the
1-minute load average sampled through the run (the machine may be shared: the load says with how much).

With ``--old PATH`` (a git worktree of an earlier commit: ``git worktree add --detach /tmp/old-afford
COMMIT``) that commit's command runs alternately with this one's (its code on PYTHONPATH, the same venv), and
their results.json are compared run by run (same folds, same learners: F1 equal, or how far apart).

    .venv/bin/python benchmarks/bench_evaluate.py --old /tmp/old-afford     # about 20 minutes on 2 cores
    .venv/bin/python benchmarks/bench_evaluate.py --repeats 3
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "bench-data" / "evaluate"
AFFORD = Path(sys.executable).parent / "afford"


def data_set(rooms: int, seed: int) -> Path:
    """The generated rooms, made once (`afford synth` makes only the missing ones)."""
    folder = DATA / f"rooms-{rooms}-seed{seed}"
    if not (folder / "summary.json").exists():
        command = [str(AFFORD), "synth", "--rooms", str(rooms), "--seed", str(seed), "--out", str(folder)]
        subprocess.run(command, check=True, stdout=subprocess.DEVNULL, env=_env(None), cwd=ROOT)
    return folder


def _env(code: Path | None, **extra: str) -> dict:
    env = dict(os.environ, **extra)
    env["PYTHONPATH"] = str(code or ROOT)  # before the venv's editable install
    return env


class Sampler(threading.Thread):
    """The process tree's summed RSS and the load average, every `period` seconds, while the run lasts."""

    def __init__(self, pid: int, period: float = 1.0):
        super().__init__(daemon=True)
        self.pid, self.period, self.done = pid, period, threading.Event()
        self.tree_mb, self.loads = 0.0, []

    def run(self) -> None:
        import psutil

        root = psutil.Process(self.pid)
        while not self.done.wait(self.period):
            try:
                tree = [root, *root.children(recursive=True)]
                rss = sum(p.memory_info().rss for p in tree if p.is_running())
            except psutil.Error:
                continue
            self.tree_mb = max(self.tree_mb, rss / 2**20)
            self.loads.append(os.getloadavg()[0])


def run_evaluate(rooms: Path, out: Path, code: Path | None, folds: int) -> dict:
    """One `afford evaluate` process with a fresh room cache: wall, CPU, memory, load."""
    with tempfile.TemporaryDirectory() as cache:
        env = _env(code, AFFORD_LEARN__CACHE_DIR=cache)
        command = [
            str(AFFORD),
            "evaluate",
            "--data",
            str(rooms),
            "--folds",
            str(folds),
            "--out",
            str(out),
            "-q",
        ]
        with tempfile.TemporaryFile() as log:
            start = time.perf_counter()
            process = subprocess.Popen(
                command, stdout=log, stderr=subprocess.STDOUT, env=env, cwd=code or ROOT
            )
            sampler = Sampler(process.pid)
            sampler.start()
            _, status, usage = os.wait4(process.pid, 0)
            wall = time.perf_counter() - start
            sampler.done.set()
            sampler.join()
            if os.waitstatus_to_exitcode(status):
                log.seek(0)
                raise SystemExit(f"{' '.join(command)} failed:\n{log.read().decode()[-3000:]}")
    loads = sampler.loads or [os.getloadavg()[0]]
    return {
        "wall": wall,
        "cpu": usage.ru_utime + usage.ru_stime,
        "largest MB": usage.ru_maxrss / 1024,
        "tree MB": sampler.tree_mb,
        "load": (min(loads), statistics.median(loads), max(loads)),
    }


def compare_results(old: Path, new: Path) -> str:
    """How the two evaluations' runs (affordance, learner, fold) agree, in one line."""

    def runs(folder: Path) -> dict:
        document = json.loads((folder / "results.json").read_text())
        return {(r["affordance"], r["learner"], r["fold"], r["ratio"]): r["f1"] for r in document["runs"]}

    a, b = runs(old), runs(new)
    if a.keys() != b.keys():
        return f"different runs: {sorted(set(a) ^ set(b))[:5]}"
    differ = {key: abs(a[key] - b[key]) for key in a if a[key] != b[key]}
    if not differ:
        return f"all {len(a)} runs' F1 the same"
    learners = sorted({key[1] for key in differ})
    return (
        f"{len(a) - len(differ)} of {len(a)} runs' F1 the same; {len(differ)} differ "
        f"({', '.join(learners)}), by at most {max(differ.values()):.3f}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--old", help="a worktree of an earlier commit to run side by side")
    parser.add_argument("--rooms", type=int, default=12)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--folds", type=int, default=3)
    parser.add_argument("--repeats", type=int, default=1)
    args = parser.parse_args()
    rooms = data_set(args.rooms, args.seed)
    sides = [("this tree", None)] + ([("old", Path(args.old).resolve())] if args.old else [])
    results: dict[str, list[dict]] = {}
    with tempfile.TemporaryDirectory() as scratch:
        for repeat in range(args.repeats):
            for side, code in sides if repeat % 2 == 0 else sides[::-1]:  # alternate who goes first
                out = Path(scratch) / f"{side}-{repeat}"
                results.setdefault(side, []).append(run_evaluate(rooms, out, code, args.folds))
                print(f"{side}, run {repeat + 1}: {results[side][-1]['wall']:.0f} s", file=sys.stderr)
        agreement = (
            compare_results(Path(scratch) / "old-0", Path(scratch) / "this tree-0") if args.old else ""
        )
    print(
        f"`afford evaluate --data ROOMS --folds {args.folds}` (defaults: 7 learners x 3 affordances) on "
        f"`afford synth --rooms {args.rooms} --seed {args.seed}`, a fresh room cache each run; "
        f"{os.cpu_count()} cores, {args.repeats} run(s) each, medians\n"
    )
    print("| code | wall min | CPU min | largest process MB | tree MB (sampled) | load: min / median / max |")
    print("|---|---:|---:|---:|---:|---|")
    for side, runs in results.items():
        median = {
            key: statistics.median(r[key] for r in runs) for key in ("wall", "cpu", "largest MB", "tree MB")
        }
        loads = [r["load"] for r in runs]
        load = " ; ".join(f"{lo:.1f} / {mid:.1f} / {hi:.1f}" for lo, mid, hi in loads)
        print(
            f"| {side} | {median['wall'] / 60:.1f} | {median['cpu'] / 60:.1f} | "
            f"{median['largest MB']:,.0f} | {median['tree MB']:,.0f} | {load} |"
        )
    if args.old:
        old, new = (statistics.median(r["wall"] for r in results[s]) for s in ("old", "this tree"))
        print(f"\nwall time, old / this tree: {old / new:.2f}x; results: {agreement}")


if __name__ == "__main__":
    main()
