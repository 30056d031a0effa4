"""`afford map` end to end, as a user runs it, on the 10 m x 10 m benchmark room: ASCII and binary PLY.

The room of bench_features.py (walls, door, sofas, tables, desks, counters, shelves; 470k points; 100 x 100
x 3 x 63 = 1.89 million poses per affordance), all three shipped models, written once as ASCII and binary PLY
to bench-data/map/. Each run is a fresh `afford map ROOM --out DIR --timings` process: wall time from the
command to its files (JSONs, PNGs, recording), its stages as the command reports them (--timings), CPU
seconds, the largest process's peak RSS and the whole process tree's peak PSS (shared pages split between the
processes sharing them; sampled every 50 ms). Medians over the repeats.

With ``--old PATH`` (a git worktree of an earlier commit: ``git worktree add /tmp/old-afford HEAD``) the same
command of that commit runs alternately with this one (its code on PYTHONPATH, the same venv), so the ratio
is measured side by side on the same machine state; the maps of both are compared (places, positive poses,
scores). ``--models DIR`` maps with the model files in DIR instead of the shipped ones, and ``--old-models
DIR`` runs the other side as this tree with those (two recipes' models side by side, no worktree).

Then, in this process, the library stages one by one (``--library``, default on): gravity alignment, voxel
fields, per affordance the scoring and map (`map_affordances`), outputs (`write_map_outputs`, serially), and,
side by side, one affordance scored by materialising every feature vector against applying the model to
the fields, and what each cascade's second stage adds.

    .venv/bin/python benchmarks/bench_map.py --old /tmp/old-afford     # about 4 minutes on 2 cores
    .venv/bin/python benchmarks/bench_map.py --repeats 1 --no-library
    .venv/bin/python benchmarks/bench_map.py --repeats 5 --no-library --large   # and a 20 m x 20 m room
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from bench_features import POINTS_PER_M2, SEED, room_boxes  # noqa: E402

from affordcore.example import box_surface_points  # noqa: E402
from affordcore.geometry.scene import Cloud  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
ROOMS = ROOT / "bench-data" / "map"
AFFORD = Path(sys.executable).parent / "afford"


def room_cloud(side: float = 10.0) -> Cloud:
    rng = np.random.default_rng(SEED)
    points = np.concatenate(
        [box_surface_points(low, high, POINTS_PER_M2, rng) for low, high in room_boxes(side, rng)]
    )
    return Cloud(points + rng.normal(scale=0.003, size=points.shape), source="10 m benchmark room")


LARGE = "binary, 20 m floor"  # the same kind of room on four times the floor


def room_files(large: bool = False) -> dict[str, Path]:
    """The benchmark room as ASCII and binary little-endian PLY (float32 x y z), and with `large` a 20 m x
    20 m room of the same furniture density as binary PLY, each written once."""
    from plyfile import PlyData

    files = {"ASCII": ROOMS / "room-ascii.ply", "binary": ROOMS / "room-binary.ply"}
    ROOMS.mkdir(parents=True, exist_ok=True)
    if not all(path.exists() for path in files.values()):
        element = _vertices(room_cloud())
        PlyData([element], text=True).write(str(files["ASCII"]))
        PlyData([element], byte_order="<").write(str(files["binary"]))
    if large:
        files[LARGE] = ROOMS / "room20-binary.ply"
        if not files[LARGE].exists():
            PlyData([_vertices(room_cloud(20.0))], byte_order="<").write(str(files[LARGE]))
    return files


def _vertices(cloud: Cloud):
    from plyfile import PlyElement

    vertices = np.empty(len(cloud), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    for k, axis in enumerate("xyz"):
        vertices[axis] = cloud.points[:, k]
    return PlyElement.describe(vertices, "vertex")


class TreeMemory:
    """The largest proportional set size (PSS: each shared page split between the processes that share it, so
    forked workers are not counted twice) of a process and its descendants together, sampled every
    `interval` seconds until `stop`."""

    def __init__(self, pid: int, interval: float = 0.05):
        import threading

        self.pid, self.interval, self.peak = pid, interval, 0
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()

    def _sample(self) -> None:
        import psutil

        while not self._done.wait(self.interval):
            try:
                root = psutil.Process(self.pid)
                total = 0
                for process in [root, *root.children(recursive=True)]:
                    try:
                        total += process.memory_full_info().pss
                    except (psutil.NoSuchProcess, psutil.AccessDenied, psutil.ZombieProcess):
                        pass  # a worker that ended between the listing and its reading
            except psutil.NoSuchProcess:
                return
            self.peak = max(self.peak, total)

    def stop(self) -> float:
        """The peak in MB."""
        self._done.set()
        self._thread.join()
        return self.peak / 2**20


def run_command(room: Path, out: Path, old: Path | None, models: Path | None = None) -> dict:
    """One `afford map` process: wall seconds, CPU seconds, peak RSS, the process tree's peak PSS, its
    --timings stages. `models`: a folder whose model files it maps with (default: the shipped ones)."""
    env = dict(os.environ)
    command = [str(AFFORD), "map", str(room), "--out", str(out), "-q"]
    for path in sorted(models.glob("*.model.json")) if models else []:
        command += ["--model", str(path)]
    if old is not None:
        env["PYTHONPATH"] = str(old)  # before the editable install of this tree
    else:
        command.append("--timings")
    with tempfile.TemporaryFile() as stdout, tempfile.TemporaryFile() as stderr:
        start = time.perf_counter()
        process = subprocess.Popen(command, stdout=stdout, stderr=stderr, env=env, cwd=old or ROOT)
        memory = TreeMemory(process.pid)
        _, status, usage = os.wait4(process.pid, 0)
        wall = time.perf_counter() - start
        tree_mb = memory.stop()
        process.returncode = os.waitstatus_to_exitcode(status)
        stdout.seek(0)
        stderr.seek(0)
        text, errors = stdout.read().decode(), stderr.read().decode()
    if process.returncode:
        raise SystemExit(f"{' '.join(command)} failed ({process.returncode}):\n{text}\n{errors}")
    stages = {m[1]: float(m[2]) for m in re.finditer(r"^timing: (.+): ([\d.]+) s$", errors, re.M)}
    return {
        "wall": wall,
        "cpu": usage.ru_utime + usage.ru_stime,
        "largest MB": usage.ru_maxrss / 1024,
        "tree MB": tree_mb,
        "stages": stages,
    }


def compare_maps(old: Path, new: Path) -> str:
    """Places, positive poses and scores of two output folders' JSON maps, in one line."""
    worst, notes = 0.0, []
    for path in sorted(old.glob("*.json")):
        a, b = json.loads(path.read_text()), json.loads((new / path.name).read_text())
        pose = ("x", "y", "z", "theta")
        for key in ("skeletons", "positives"):
            if [tuple(p[k] for k in pose) for p in a[key]] != [tuple(p[k] for k in pose) for p in b[key]]:
                notes.append(f"{path.stem}: {key} differ ({len(a[key])} against {len(b[key])})")
            worst = max([worst] + [abs(p["score"] - q["score"]) for p, q in zip(a[key], b[key])])
    same = "the same places and positive poses" if not notes else "; ".join(notes)
    files = sorted(p.name for p in old.iterdir() if p.suffix in (".json", ".png"))
    differ = [name for name in files if (old / name).read_bytes() != (new / name).read_bytes()]
    bytes_line = (
        f"files that differ: {', '.join(differ)}"
        if differ
        else f"all {len(files)} JSONs and PNGs the same bytes"
    )
    return f"{same}, scores within {worst:.1e}; {bytes_line}"


def command_table(args, files: dict[str, Path]) -> None:
    other = [("old", Path(args.old), None)] if args.old else []
    if args.old_models:  # main() refuses it beside --old
        other = [("old", None, Path(args.old_models))]
    sides = [("this tree", None, Path(args.models) if args.models else None)] + other
    runs: dict[tuple[str, str], list[dict]] = {}
    load_before = os.getloadavg()[0]
    agreement = {}
    with tempfile.TemporaryDirectory() as scratch:
        for repeat in range(args.repeats):
            for kind, room in files.items():
                order = sides if repeat % 2 == 0 else sides[::-1]  # alternate who goes first
                for side, old, models in order:
                    out = Path(scratch) / f"{side}-{kind}"
                    runs.setdefault((kind, side), []).append(run_command(room, out, old, models))
        for kind in files:
            if len(sides) > 1:
                folders = Path(scratch) / f"old-{kind}", Path(scratch) / f"this tree-{kind}"
                agreement[kind] = compare_maps(*folders)
    print(
        f"`afford map` on the 10 m room (470,552 points; 3 affordances, PNGs and recording), "
        f"{os.cpu_count()} cores, {args.repeats} repeats, medians; load average {load_before:.1f} before, "
        f"{os.getloadavg()[0]:.1f} after (above 0.5, other processes shared the cores)"
    )
    header = "| PLY | wall s | CPU s | largest process MB | process tree MB (PSS) |"
    if len(sides) > 1:
        header += " old commit wall s | old commit CPU s | old / new (wall) |"
    print(header + "\n|---|---:|---:|---:|---:|" + ("---:|---:|---:|" if len(sides) > 1 else ""))
    for kind in files:
        new = runs[(kind, "this tree")]
        row = (
            f"| {kind} | {statistics.median(r['wall'] for r in new):.2f} | "
            f"{statistics.median(r['cpu'] for r in new):.2f} | "
            f"{max(r['largest MB'] for r in new):.0f} | {max(r['tree MB'] for r in new):.0f} |"
        )
        if len(sides) > 1:
            old = runs[(kind, "old")]
            ratios = [o["wall"] / n["wall"] for o, n in zip(old, new)]
            row += (
                f" {statistics.median(r['wall'] for r in old):.2f} | "
                f"{statistics.median(r['cpu'] for r in old):.2f} | {statistics.median(ratios):.2f}x "
                f"({min(ratios):.2f}-{max(ratios):.2f}) |"
            )
        print(row)
    for kind, text in agreement.items():
        print(f"{kind}: maps against the old commit's: {text}")
    walls = {kind: statistics.median(r["wall"] for r in runs[(kind, "this tree")]) for kind in files}
    for kind, wall in walls.items():
        if kind == LARGE:
            ratio = wall / walls["binary"]
            memory = max(r["tree MB"] for r in runs[(kind, "this tree")]) / 1024
            print(
                f"{kind}: {wall:.2f} s, {ratio:.2f}x the 10 m room's (target at most 4x), "
                f"{memory:.2f} GB over its processes at their peak (PSS; target 2 GB)"
            )
            continue
        target = TARGET_SECONDS[kind]
        verdict = "met" if wall <= target else f"missed by {wall - target:.2f} s"
        print(f"{kind}: {wall:.2f} s against the {target:g} s target: {verdict}")
    print("\nstages as `afford map --timings` reports them (seconds, medians; workers run side by side):")
    kinds = list(files)
    print("| stage | " + " | ".join(kinds) + " |\n|---|" + "---:|" * len(kinds))
    stages = list(dict.fromkeys(s for kind in kinds for r in runs[(kind, "this tree")] for s in r["stages"]))
    for stage in stages:
        cells = []
        for kind in kinds:
            values = [r["stages"][stage] for r in runs[(kind, "this tree")] if stage in r["stages"]]
            cells.append(f"{statistics.median(values):.2f}" if values else "")
        print(f"| {stage} | " + " | ".join(cells) + " |")
    for kind in kinds:
        new = runs[(kind, "this tree")]
        inside = statistics.median(sum(v for s, v in r["stages"].items() if s in TOP_STAGES) for r in new)
        wall = statistics.median(r["wall"] for r in new)
        print(
            f"{kind}: the stages add up to {inside:.2f} s of the {wall:.2f} s: "
            "the rest is starting Python and importing (numpy, scipy, pydantic, typer)"
        )


TARGET_SECONDS = {"ASCII": 2.0, "binary": 1.5}  # afford map of this room, command to files
TOP_STAGES = ("load the cloud", "gravity alignment", "voxel fields", "maps and outputs (wall)")


# --- the library, stage by stage ------------------------------------------------------------------------


def _clock() -> np.ndarray:
    """(wall, CPU) seconds now: the CPU column holds on a busy machine, where the wall one does not."""
    return np.array([time.perf_counter(), time.process_time()])


def one_run(cloud: Cloud, settings, models) -> tuple[dict[str, np.ndarray], object]:
    """Each stage's (wall, CPU) seconds, and the prepared scene."""
    from affordcore.geometry.gravity import align_to_gravity
    from affordcore.mapping.outputs import write_map_outputs
    from affordcore.mapping.pipeline import map_affordances, prepare_scene

    seconds = {}
    start = _clock()
    alignment = align_to_gravity(cloud.points, "auto", settings.gravity)
    seconds["gravity alignment (auto: floor search over 3 axes)"] = _clock() - start
    start = _clock()
    scene = prepare_scene(cloud.transformed(alignment.world_from_input), settings, "none")
    seconds["voxel fields (occupancy, distance, normals)"] = _clock() - start
    clock = [_clock()]

    def lap(affordance: str, _map) -> None:  # map_affordances reports each affordance as it is done
        seconds[f"score + map {affordance} ({_map.grid.size / 1e6:.2f} M poses)"] = _clock() - clock[0]
        clock[0] = _clock()

    maps = map_affordances(scene.fields, scene.layout, models, settings, on_map=lap)
    seconds["cloud in to maps computed (no outputs)"] = sum(seconds.values())
    with tempfile.TemporaryDirectory() as out:
        start = _clock()
        write_map_outputs(scene, maps, models, Path(out), Path(out) / "map.rrd")
        seconds["JSON + PNG + Rerun outputs, one process"] = _clock() - start
    return seconds, scene


def materialised(scene, model, settings) -> tuple[float, float, float]:
    """Seconds to score one affordance by features @ w and by applying w to the fields (side by side), and
    the largest difference between the two."""
    from affordcore.geometry.features import iter_features
    from affordcore.mapping.inference import score_poses

    skeleton = model.as_skeleton()
    grid = scene.pose_grid(skeleton, settings)
    start = time.perf_counter()
    scores = np.empty(grid.size, dtype=np.float32)
    weights = model.weights.astype(np.float32)
    for chunk in iter_features(
        scene.fields, skeleton, grid, scene.layout, settings.features.chunk_mb, reuse_buffer=True
    ):
        scores[chunk.start : chunk.stop] = chunk.values @ weights + model.bias
    slow = time.perf_counter() - start
    start = time.perf_counter()
    fast = score_poses(scene.fields, skeleton, grid, scene.layout, model.weights, model.bias).ravel()
    seconds = time.perf_counter() - start
    return slow, seconds, float(np.max(np.abs(fast - scores)) / max(1e-9, float(np.max(np.abs(scores)))))


def second_stage(scene, models, settings, repeats: int) -> list[tuple[str, int, float]]:
    """(affordance, poses rescored, seconds) of each cascade's second stage: the model's scoring less its
    first stage's alone, timed alternately, median over `repeats`."""
    import dataclasses

    from affordcore.mapping.maps import RULED_OUT
    from affordcore.mapping.pipeline import score_model

    rows = []
    for model in (m for m in models if m.rescorer):
        first = dataclasses.replace(model, rescorer=None)
        extra = []
        for _ in range(repeats):
            start = time.perf_counter()
            score_model(first, scene.fields, scene.layout, settings)
            middle = time.perf_counter()
            _, scores = score_model(model, scene.fields, scene.layout, settings)
            extra.append((time.perf_counter() - middle) - (middle - start))
        rows.append((model.affordance, int(np.count_nonzero(scores > RULED_OUT)), statistics.median(extra)))
    return rows


def library_table(args, files: dict[str, Path]) -> None:
    import rerun  # noqa: F401  (import costs are the command's table's, not the stages')

    from affordcore.geometry.scene import load_cloud
    from affordcore.learn.model import load_model, shipped_models
    from affordcore.mapping.plots import pyplot
    from affordcore.settings import Settings

    pyplot()
    settings = Settings()
    paths = sorted(Path(args.models).glob("*.model.json")) if args.models else shipped_models().values()
    models = [load_model(path) for path in paths]
    loads = {kind: [] for kind in files}
    for _ in range(args.repeats):
        for kind, path in files.items():
            start = time.perf_counter()
            cloud = load_cloud(path)
            loads[kind].append(time.perf_counter() - start)
    runs, cpu = [], []
    for _ in range(args.repeats):
        cpu_start, wall_start = time.process_time(), time.perf_counter()
        seconds, scene = one_run(cloud, settings, models)
        cpu.append((time.process_time() - cpu_start) / (time.perf_counter() - wall_start))
        runs.append(seconds)
    print(
        f"\nthe library in one process, stage by stage: {len(cloud):,} points, {os.cpu_count()} cores, "
        f"{args.repeats} repeats, cpu/wall {min(cpu):.2f}-{max(cpu):.2f}"
    )
    print("| stage | wall s (median) | CPU s (median) |\n|---|---:|---:|")
    for kind, values in loads.items():
        print(f"| load the {kind} PLY | {statistics.median(values):.2f} | |")
    for stage in runs[0]:
        wall, cpu_seconds = (statistics.median(float(r[stage][k]) for r in runs) for k in (0, 1))
        print(f"| {stage} | {wall:.2f} | {cpu_seconds:.2f} |")
    slow, fast, difference = materialised(scene, models[0], settings)
    print(
        f"\n{models[0].affordance}: features materialised then w . f: {slow:.2f} s; "
        f"applied to the fields: {fast:.2f} s "
        f"({slow / fast:.1f}x); largest difference {difference:.1e} of the largest score"
    )
    stages = second_stage(scene, models, settings, args.repeats)
    for affordance, rescored, seconds in stages:
        print(f"{affordance}: the second stage rescores {rescored:,} poses in {seconds:.2f} s")
    print(f"peak memory {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:,.0f} MB (this process)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--old", help="a worktree of the commit to compare against, run side by side")
    parser.add_argument("--library", action=argparse.BooleanOptionalAction, default=True)
    parser.add_argument("--large", action="store_true", help="a 20 m x 20 m room too (the command only)")
    parser.add_argument("--models", help="a folder of model files to map with (default: the shipped ones)")
    parser.add_argument(
        "--old-models", help="the other side: this tree with the model files of this folder (not with --old)"
    )
    args = parser.parse_args()
    if args.old and args.old_models:
        parser.error("--old and --old-models each name the other side: give one")
    files = room_files(args.large)
    command_table(args, files)
    if args.library:
        from threadpoolctl import threadpool_limits

        with threadpool_limits(1, user_api="blas"):  # as afford map runs (affordcli/room.py)
            library_table(args, {kind: path for kind, path in files.items() if kind != LARGE})


if __name__ == "__main__":
    main()
