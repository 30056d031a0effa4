"""Differential fuzzing of the whole stream, longer than the test: the same valid stream into fresh stacks,
clean twice (run-to-run noise) and then once per seed with hostile messages interleaved on every input key
(tests/stream_fuzz.py says how they are made and sent). Prints one row per run: hostile messages sent and
refusals seen per service, whether the assembler's map and every affordance's map equal the clean run's to
the bit, whether both watches took the whole stream's maps, and any process that exited.

    .venv/bin/python benchmarks/fuzz_stream.py [--seeds 5] [--hostile 600] [--frames 15]

About a minute per run on 2 cores. Streams the generated living room of tests/conftest.py's walk.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

import numpy as np  # noqa: E402
from conftest import living_e2e_room  # noqa: E402
from stream_fuzz import AFFORDANCES, hostile_plan, hostile_pool, run_stream  # noqa: E402

from affordcore.synth.dataset import write_sequence  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--hostile", type=int, default=600, help="hostile messages per fuzzed run")
    parser.add_argument("--frames", type=int, default=15)
    args = parser.parse_args()
    print(
        f"{os.cpu_count()} cores; {args.frames} frames per stream, {args.hostile} hostile messages per run\n"
    )
    with tempfile.TemporaryDirectory() as tmp:
        room, rng = living_e2e_room()
        folder = Path(tmp) / "walk.sequence"
        write_sequence(room, rng, folder, "depth", frames=3 * args.frames)
        header = (
            "| run | sent (a / f / i) | refused (a / f / i) | map equal | maps equal | watches | exited | s |"
        )
        print(header)
        print("|---|---|---|---|---|---|---|---|")
        clean = None
        for run in ["clean", "clean again", *[f"seed {s}" for s in range(args.seeds)]]:
            plan = None
            if run.startswith("seed"):
                seed_rng = np.random.default_rng(int(run.split()[1]))
                plan = hostile_plan(
                    seed_rng, hostile_pool(seed_rng, args.hostile // 4), args.frames, args.hostile
                )
            started = time.monotonic()
            outcome = run_stream(folder, Path(tmp) / run.replace(" ", "-"), args.frames, plan)
            clean = clean or outcome
            services = ("assembler", "features", "inference")
            watches = all(
                w["done"] and {n: w.get(n) for n in AFFORDANCES} == {n: clean.maps[n][2] for n in AFFORDANCES}
                for w in outcome.watched
            )
            print(
                f"| {run} | {' / '.join(str(outcome.sent.get(s, 0)) for s in services)} "
                f"| {' / '.join(str(outcome.refused.get(s, 0)) for s in services)} "
                f"| {outcome.cloud == clean.cloud} | {outcome.maps == clean.maps} "
                f"| {watches} ({len(outcome.watched)}) | {outcome.exited or 'none'} "
                f"| {time.monotonic() - started:.0f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
