"""Benchmark of per-pose feature production (affordcore.geometry.features.iter_features) over a whole pose
grid.

What is measured, on a synthetic room built in code (walls 2.5 m high with a door gap, sofas, tables, desks,
counters and shelves spread over the floor, sampled with affordcore.example.box_surface_points, fixed seed):

1. Throughput. iter_features(..., reuse_buffer=True) over the whole pose grid of one affordance
   (10 m x 10 m room: 100 x 100 x 3 x 63 = 1,890,000 poses) for the paper's 10 cm cells (3030 features), 20 cm
   and 25 cm cells, plus a one-cell cube (33 features: joints and little else). Each chunk is only touched, so
   production is timed, not consumption. Median wall time over --repeats; "cpu/wall" (process CPU time over
   wall time) flags runs where other processes took the core, and "poses/cpu-s" is the throughput per CPU
   second, which such contention disturbs much less. Peak memory per layout: one pass in a fresh
   process that receives the fields from this one (so its high-water mark is not open3d's normal estimation)
   and reads ru_maxrss before it (baseline: interpreter, imports, fields) and after it. The process is forked
   from a forkserver started first thing, while this process is small: Linux keeps ru_maxrss across execve,
   so a "spawn" child or a subprocess of this (by then ~500 MB) process starts with the parent's high-water
   mark as its own and would report that, not its own peak.
2. Naive reference. A plain Python loop over ~300 random poses that places the 15 joints, reads every field
   by trilinear interpolation at each joint and normal-cube sample and rotates the normals into the skeleton
   frame: the obviously correct slow way. Its values must match the fast ones (max abs diff < 1e-4), and
   the headline is the fast/naive speed ratio measured in the same run.
3. Scaling. Square rooms of side 4, 7 and 10 m, 10 cm layout: seconds per million poses (flat if the cost is
   linear in the number of poses) and the split between building the fields (prepare_scene, timed once)
   and computing the features. The 10 m row reuses the measurement of section 1; the verdict uses CPU
   seconds, which other processes on the machine disturb less than wall seconds.
4. What dominates: the one-cell cube's time against the full layout's splits joints from the normal cube.

Run from the repository root:

    .venv/bin/python benchmarks/bench_features.py            # full run, about 5 minutes on 2 cores
    .venv/bin/python benchmarks/bench_features.py --quick    # smoke run on small rooms
    .venv/bin/python benchmarks/bench_features.py --repeats 5
"""

from __future__ import annotations

import argparse
import itertools
import math
import multiprocessing
import multiprocessing.forkserver
import os
import platform
import resource
import statistics
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np

from affordcore.example import box_surface_points
from affordcore.geometry.features import FeatureLayout, iter_features
from affordcore.geometry.fields import SceneFields
from affordcore.geometry.grid import PoseGrid
from affordcore.geometry.scene import Cloud
from affordcore.geometry.skeleton import Skeleton, get_skeleton
from affordcore.mapping.pipeline import PreparedScene, prepare_scene
from affordcore.settings import Settings

AFFORDANCE = "sitting-relaxing"
SEED = 7
POINTS_PER_M2 = 900.0
INSET = 0.03  # the room's outer faces sit this far inside [0, side] so the grid has exactly side / 0.1 cells
LAYOUTS = {  # label -> layout; the last one is the one-cell cube that isolates the joints
    "10 cm cells": FeatureLayout(cube_size=1.0, cell_size=0.10, voxel_resolution=0.1),
    "20 cm cells": FeatureLayout(cube_size=1.0, cell_size=0.20, voxel_resolution=0.1),
    "25 cm cells": FeatureLayout(cube_size=1.0, cell_size=0.25, voxel_resolution=0.1),
    "1 cell (joints)": FeatureLayout(cube_size=0.1, cell_size=0.1, voxel_resolution=0.1),
}
PAPER, TINY = "10 cm cells", "1 cell (joints)"

# Furniture in its own frame (x along its length, z up): lists of (low, high) boxes, metres.
_LEGS = [((x - 0.03, y - 0.03, 0.0), (x + 0.03, y + 0.03, 0.71)) for x in (-0.65, 0.65) for y in (-0.3, 0.3)]
FURNITURE = {
    "sofa": [
        ((-1.0, -0.45, 0.0), (1.0, 0.45, 0.42)),
        ((-1.0, 0.2, 0.42), (1.0, 0.45, 0.85)),
        ((-1.2, -0.45, 0.0), (-1.0, 0.45, 0.62)),
        ((1.0, -0.45, 0.0), (1.2, 0.45, 0.62)),
    ],
    "table": [((-0.6, -0.4, 0.71), (0.6, 0.4, 0.75)), ((-0.1, -0.1, 0.0), (0.1, 0.1, 0.71))],
    "desk": [((-0.7, -0.375, 0.71), (0.7, 0.375, 0.75)), ((-0.2, 0.25, 0.75), (0.2, 0.3, 1.1)), *_LEGS],
    "counter": [((-1.2, -0.3, 0.0), (1.2, 0.3, 0.92)), ((-1.2, -0.32, 0.92), (1.2, 0.32, 0.95))],
    "shelf": [((-0.6, -0.19, 0.0), (0.6, 0.19, 1.9))],
}


@dataclass(frozen=True)
class Config:
    side: float  # main room (m)
    scaling_sides: tuple[float, ...]
    naive_poses: int
    repeats: int


FULL = Config(10.0, (4.0, 7.0, 10.0), 300, 3)
QUICK = Config(2.0, (1.5, 2.0), 12, 1)


@dataclass
class Room:
    side: float
    n_points: int
    scene: PreparedScene
    grid: PoseGrid
    prepare_s: float


# ---------------------------------------------------------------- scene


def room_boxes(side: float, rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray]]:
    """Floor, four 2.5 m walls (a door gap with a lintel in the east wall) and furniture on ~2.5 m slots."""
    lo, hi, wall, door = INSET, side - INSET, 0.1, (side / 2 - 0.45, side / 2 + 0.45)
    boxes = [
        ((lo, lo, 0.0), (hi, hi, 0.0)),
        ((lo, lo, 0.0), (hi, lo + wall, 2.5)),
        ((lo, hi - wall, 0.0), (hi, hi, 2.5)),
        ((lo, lo, 0.0), (lo + wall, hi, 2.5)),
        ((hi - wall, lo, 0.0), (hi, door[0], 2.5)),
        ((hi - wall, door[1], 0.0), (hi, hi, 2.5)),
        ((hi - wall, door[0], 2.05), (hi, door[1], 2.5)),
    ]
    slots = max(1, round(side / 2.5))
    kinds = list(FURNITURE)
    for index, (i, j) in enumerate(itertools.product(range(slots), repeat=2)):
        centre = (np.array([i, j]) + 0.5) * side / slots + rng.uniform(-0.3, 0.3, 2)
        turned = rng.integers(2) == 1  # a quarter turn swaps the piece's x and y
        for low, high in FURNITURE[kinds[index % len(kinds)]]:
            low, high = np.array(low), np.array(high)
            if turned:
                low, high = low[[1, 0, 2]], high[[1, 0, 2]]
            low[:2] += centre
            high[:2] += centre
            boxes.append((np.clip(low, lo, hi), np.clip(high, lo, hi)))
    return [(np.array(low, dtype=float), np.array(high, dtype=float)) for low, high in boxes]


def build_room(side: float, skeleton: Skeleton, settings: Settings) -> Room:
    import open3d  # noqa: F401  (imported lazily by prepare_scene; import it untimed)
    import scipy.ndimage  # noqa: F401

    rng = np.random.default_rng(SEED)
    boxes = room_boxes(side, rng)
    points = np.concatenate([box_surface_points(low, high, POINTS_PER_M2, rng) for low, high in boxes])
    points += rng.normal(scale=0.003, size=points.shape)
    start = time.perf_counter()
    scene = prepare_scene(Cloud(points, source=f"synthetic {side:g} m room"), settings, gravity="none")
    prepare_s = time.perf_counter() - start
    grid = scene.pose_grid(skeleton, settings)
    cells = round(side / settings.grid.step)
    assert grid.shape == (3, 63, cells, cells), f"pose grid {grid.shape} for a {side} m room"
    return Room(side, len(points), scene, grid, prepare_s)


# ---------------------------------------------------------------- fast path


def run_features(fields: SceneFields, grid: PoseGrid, skeleton: Skeleton, layout: FeatureLayout, keep=None):
    """One pass over the whole grid: (wall s, CPU s, rows of the sorted pose indices `keep`)."""
    kept = np.empty((0 if keep is None else len(keep), layout.n_features), dtype=np.float32)
    touched = 0.0
    start, cpu = time.perf_counter(), time.process_time()
    for chunk in iter_features(fields, skeleton, grid, layout, reuse_buffer=True):
        touched += float(chunk.values[-1, -1])  # consume cheaply: production is what is timed
        if keep is not None:
            a, b = np.searchsorted(keep, [chunk.start, chunk.stop])
            kept[a:b] = chunk.values[keep[a:b] - chunk.start]
    return time.perf_counter() - start, time.process_time() - cpu, kept


def time_features(room: Room, skeleton: Skeleton, layout: FeatureLayout, repeats: int, keep=None):
    """(sorted wall seconds of `repeats` passes, their total CPU seconds, kept rows of the first pass).

    CPU / wall well under 100 % means other processes took the core: wall timings are then pessimistic.
    """
    args = (room.scene.fields, room.grid, skeleton, layout)
    runs = [run_features(*args, keep)] + [run_features(*args) for _ in range(repeats - 1)]
    wall = [run[0] for run in runs]
    return sorted(wall), sum(run[1] for run in runs), runs[0][2]


def _maxrss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux


def _memory_probe(*args) -> tuple[float, float]:
    """In a fresh process: (high-water RSS with the fields loaded, high-water RSS after one full pass), MB."""
    baseline = _maxrss_mb()
    run_features(*args)
    return baseline, _maxrss_mb()


def peak_memory(room: Room, skeleton: Skeleton, layout: FeatureLayout) -> tuple[float, float]:
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("forkserver")) as pool:
        return pool.submit(_memory_probe, room.scene.fields, room.grid, skeleton, layout).result()


# ---------------------------------------------------------------- naive reference


def trilinear(field: np.ndarray, origin: np.ndarray, res: float, point) -> np.ndarray:
    """Field at a point, interpolated between the 8 voxel centres (origin + index * res) around it."""
    u = [(point[a] - origin[a]) / res for a in range(3)]
    base = [math.floor(v) for v in u]
    frac = [v - b for v, b in zip(u, base)]
    value = 0.0
    for corner in itertools.product((0, 1), repeat=3):
        weight = math.prod(f if c else 1.0 - f for c, f in zip(corner, frac))
        i, j, k = (b + c for b, c in zip(base, corner))
        value = value + weight * field[i, j, k].astype(float)
    return value


def naive_features(room: Room, skeleton: Skeleton, layout: FeatureLayout, pose) -> list[float]:
    """One pose's feature vector, the slow obvious way (same definition and order as
    affordcore.geometry.features)."""
    fields = room.scene.fields
    origin, res = fields.lattice.origin, fields.lattice.resolution
    x, y, z, theta = (float(v) for v in pose)
    c, s = math.cos(theta), math.sin(theta)

    def world(h):  # [x, y, z] + R_z(theta) h
        return (x + c * h[0] - s * h[1], y + s * h[0] + c * h[1], z + h[2])

    joints = [world(h) for h in skeleton.joints.tolist()]
    values = [float(trilinear(fields.distance, origin, res, p)) for p in joints]
    values += [float(trilinear(fields.occupancy, origin, res, p)) for p in joints]
    cube, cell = layout.cube_size, layout.cell_size
    cells = round(cube / cell)
    per = max(1, round(cell / layout.voxel_resolution))  # samples per cell and axis, at about voxel spacing
    for index in itertools.product(range(cells), repeat=3):  # C order over the skeleton's x, y, z
        total = np.zeros(3)
        for sub in itertools.product(range(per), repeat=3):
            offset = [-cube / 2 + (i + (m + 0.5) / per) * cell for i, m in zip(index, sub)]
            n = trilinear(fields.normals, origin, res, world(offset))
            total += (c * n[0] + s * n[1], -s * n[0] + c * n[1], n[2])  # R_z(theta)^T n
        values += (total / per**3).tolist()
    return values


def naive_check(room, skeleton, layout, poses, fast_rows) -> tuple[float, float]:
    """(naive poses/s, max abs difference to the fast rows) for the sampled poses."""
    start = time.perf_counter()
    naive = np.array([naive_features(room, skeleton, layout, pose) for pose in poses])
    seconds = time.perf_counter() - start
    diff = float(np.abs(naive - fast_rows).max())
    assert diff < 1e-4, f"naive and fast features differ by {diff:g}"
    return len(poses) / seconds, diff


# ---------------------------------------------------------------- report


def fmt(value) -> str:
    if isinstance(value, str):
        return value
    if isinstance(value, float) and abs(value) < 1000:
        return f"{value:.3g}" if abs(value) < 10 else f"{value:.1f}"
    return f"{value:,.0f}"


def table(title: str, headers: list[str], rows: list[list]) -> None:
    cells = [headers] + [[fmt(v) for v in row] for row in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    lines = [
        "  ".join(v.ljust(w) if i == 0 else v.rjust(w) for i, (v, w) in enumerate(zip(r, widths)))
        for r in cells
    ]
    print("\n".join([f"\n{title}", lines[0], "  ".join("-" * w for w in widths), *lines[1:]]))


@dataclass
class Measured:
    seconds: list[float]  # sorted, one per repeat
    cpu_seconds: float  # total over the repeats
    kept: np.ndarray  # fast rows of the naive sample
    base_mb: float
    peak_mb: float
    n_poses: int

    @property
    def median(self) -> float:
        return statistics.median(self.seconds)

    @property
    def speed(self) -> float:
        return self.n_poses / self.median

    @property
    def cpu_share(self) -> float:
        return self.cpu_seconds / sum(self.seconds)

    @property
    def cpu_speed(self) -> float:
        return self.n_poses * len(self.seconds) / self.cpu_seconds


def throughput(room: Room, skeleton: Skeleton, repeats: int, keep: np.ndarray) -> dict[str, Measured]:
    results = {}
    for label, layout in LAYOUTS.items():
        seconds, cpu_seconds, kept = time_features(room, skeleton, layout, repeats, keep)
        memory = peak_memory(room, skeleton, layout)
        results[label] = Measured(seconds, cpu_seconds, kept, *memory, room.grid.size)
    table(
        f"1. iter_features(reuse_buffer=True) over all {room.grid.size:,} poses",
        [
            "layout",
            "features",
            "poses/s",
            "s",
            "min-max s",
            "cpu/wall",
            "poses/cpu-s",
            "out GB/s",
            "base MB",
            "peak MB",
            "+MB",
        ],
        [
            [
                label,
                LAYOUTS[label].n_features,
                m.speed,
                m.median,
                f"{m.seconds[0]:.2f}-{m.seconds[-1]:.2f}",
                f"{m.cpu_share:.0%}",
                m.cpu_speed,
                m.speed * LAYOUTS[label].n_features * 4 / 1e9,
                m.base_mb,
                m.peak_mb,
                m.peak_mb - m.base_mb,
            ]
            for label, m in results.items()
        ],
    )
    return results


def reference(room: Room, skeleton: Skeleton, poses: np.ndarray, results: dict[str, Measured]) -> dict:
    ratios, rows = {}, []
    for label, layout in LAYOUTS.items():
        naive_speed, diff = naive_check(room, skeleton, layout, poses, results[label].kept)
        fast = results[label].speed
        ratios[label] = fast / naive_speed
        rows.append([label, len(poses), naive_speed, fast, f"{ratios[label]:,.0f}x", f"{diff:.1e}"])
    table(
        f"2. Naive per-pose Python reference on {len(poses)} random poses (values asserted equal)",
        ["layout", "poses", "naive poses/s", "fast poses/s", "fast/naive", "max |diff|"],
        rows,
    )
    return ratios


def scaling(room: Room, main: Measured, sides, skeleton: Skeleton, settings: Settings, repeats: int) -> tuple:
    """Wall and CPU seconds per million poses per room side; the main room reuses its section-1 timing."""
    rows, wall_per_m, cpu_per_m = [], [], []
    for side in sides:
        other = room if side == room.side else build_room(side, skeleton, settings)
        if other is room:
            seconds, cpu_seconds = main.seconds, main.cpu_seconds
        else:
            seconds, cpu_seconds, _ = time_features(other, skeleton, LAYOUTS[PAPER], repeats)
        features_s = statistics.median(seconds)
        wall_per_m.append(features_s / other.grid.size * 1e6)
        cpu_per_m.append(cpu_seconds / len(seconds) / other.grid.size * 1e6)
        cpu_share = f"{cpu_seconds / sum(seconds):.0%}"
        fields_share = f"{other.prepare_s / (other.prepare_s + features_s):.0%}"
        rows.append(
            [
                f"{side:g} m",
                other.grid.size,
                other.prepare_s,
                features_s,
                cpu_share,
                wall_per_m[-1],
                cpu_per_m[-1],
                fields_share,
            ]
        )
    table(
        f"3. Scaling with room area ({PAPER}; fields = prepare_scene, timed once)",
        [
            "room",
            "poses",
            "fields s",
            "features s",
            "cpu/wall",
            "s / M poses",
            "cpu-s / M poses",
            "fields share",
        ],
        rows,
    )
    return wall_per_m, cpu_per_m


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="small rooms, one repeat, a few naive poses")
    parser.add_argument("--repeats", type=int, default=None, help="timed passes (default 3; 1 with --quick)")
    args = parser.parse_args()
    multiprocessing.forkserver.ensure_running()  # while this process is small; see the module docstring
    cfg = QUICK if args.quick else FULL
    repeats = args.repeats or cfg.repeats
    began = time.perf_counter()
    settings, skeleton = Settings(), get_skeleton(AFFORDANCE)
    room = build_room(cfg.side, skeleton, settings)
    if not args.quick:
        assert room.grid.size == 100 * 100 * 3 * 63 == 1_890_000, room.grid.size
    lattice = room.scene.fields.lattice
    print(f"bench_features: {'QUICK' if args.quick else 'full'} run, {repeats} repeat(s), medians reported")
    print(
        f"machine: {os.cpu_count()} cores (os.cpu_count), {platform.machine()}, Python "
        f"{platform.python_version()}, numpy {np.__version__}, load {os.getloadavg()[0]:.2f} at start"
    )
    print(
        f"room: {cfg.side:g} m x {cfg.side:g} m synthetic, {room.n_points:,} points, seed {SEED}; "
        f"fields {lattice.shape} voxels of {lattice.resolution:g} m "
        f"({room.scene.fields.nbytes / 2**20:.0f} MB), prepare_scene {room.prepare_s:.1f} s"
    )
    print(
        f"pose grid ({AFFORDANCE}): z x theta x X x Y = {' x '.join(map(str, room.grid.shape))} "
        f"= {room.grid.size:,} poses"
    )

    keep = np.sort(np.random.default_rng(SEED).choice(room.grid.size, cfg.naive_poses, replace=False))
    results = throughput(room, skeleton, repeats, keep)
    ratios = reference(room, skeleton, room.grid.poses(keep), results)
    wall_per_m, cpu_per_m = scaling(room, results[PAPER], cfg.scaling_sides, skeleton, settings, repeats)

    paper, coarse, tiny = results[PAPER], results["25 cm cells"], results[TINY]
    joints_share = tiny.median / paper.median
    spread, wall_spread = (max(v) / min(v) - 1 for v in (cpu_per_m, wall_per_m))
    sides = ", ".join(f"{side:g}" for side in cfg.scaling_sides)
    print("\nWhat dominates")
    print(
        f"- Headline: the slab method is {ratios[PAPER]:,.0f}x the naive per-pose loop ({PAPER}, "
        f"{paper.speed:,.0f} vs {paper.speed / ratios[PAPER]:,.1f} poses/s), with the same values."
    )
    print(
        f"- {PAPER}: the normal cube is {1 - joints_share:.0%} of feature time; joints plus per-slab "
        f"set-up {joints_share:.0%} (measured as the one-cell cube, {LAYOUTS[TINY].n_features} features)."
    )
    print(
        f"- Coarser cells: 20 cm runs {results['20 cm cells'].speed / paper.speed:.1f}x and 25 cm "
        f"{coarse.speed / paper.speed:.1f}x the 10 cm speed; "
        f"feature memory +{paper.peak_mb - paper.base_mb:.0f} MB (10 cm) vs "
        f"+{coarse.peak_mb - coarse.base_mb:.0f} MB (25 cm) over the fields."
    )
    print(
        f"- Cost per pose is {'flat' if spread < 0.15 else 'NOT flat'} in room area: "
        f"CPU seconds per million poses vary by {spread:.0%} over the {sides} m rooms "
        f"(wall seconds by {wall_spread:.0%})."
    )
    print(
        f"- One affordance on the {cfg.side:g} m room: features {paper.median:.1f} s vs fields "
        f"{room.prepare_s:.1f} s (the fields are shared by all affordances)."
    )
    print(f"\ntotal wall time {time.perf_counter() - began:.0f} s, load {os.getloadavg()[0]:.2f} at the end")


if __name__ == "__main__":
    main()
