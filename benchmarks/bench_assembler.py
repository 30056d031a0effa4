"""Scan assembly on real depth frames: what the assembler costs over bare KISS-ICP, and how far its trajectory
is from the ground truth.

Microsoft 7-Scenes redkitchen, frames 0 to 299 (Kinect v1, 640 x 480, a 2.11 m hand-held path; in
../shared/data/sequences/). Every frame is decoded and back-projected before anything is timed: by
`affordcore.depth.back_project` with the assembler's pixel step and range (the mean of each 2 x 2 block of
pixels, what the service does), and, for the rows that say so, every 2nd pixel (`every_nth_pixel`).

Cost, side by side in one run on the same points: bare KISS-ICP (`KissICP(KISSConfig)` with the assembler's
range and voxel, deskew off, `register_frame` only) against `Assembler.register` (the same registration, plus
the global map and the keyframes; the frames' gravity passed as an IMU would). Each repeat runs both over
every frame, in alternating order; the table has the median ms per frame of each repeat, then the median
over the repeats, and the median of the per-repeat ratios. `Assembler.aligned_map()` (done at each map
publication) is timed on the final map, with the frames' gravity (a floor search along it) and without (a
search over the candidate axes, what a sensor without an IMU gets).

Trajectory error against the 7-Scenes ground truth (KinectFusion), positions anchored at the first frame.
"KISSConfig defaults" is bare KISS-ICP with deskew off and max_range 4 m, everything else as KISSConfig has it
(min_range 0; voxel 0.04 m, the max_range / 100 kiss_icp's load_config derives), on every 2nd pixel. The
ground truth jumps 3.5 cm and 1.6 degrees between frames 121 and 122, a step the depth frames do not show
(point-to-plane ICP of frame 122 onto 121: 64 % of the points within 2 cm with the ground truth's step, 98.5 %
with its own 7 mm one; every other step of the sequence scores alike both ways), so every error after frame
121 carries it: a second table scores the two halves separately, each anchored at its own first frame.

    .venv/bin/python benchmarks/bench_assembler.py               # about 5 minutes on 2 cores
    .venv/bin/python benchmarks/bench_assembler.py --frames 100 --repeats 1
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from affordcore.assembly import Assembler, trajectory_errors  # noqa: E402
from affordcore.depth import DepthImage, back_project  # noqa: E402
from affordcore.gravity import align_to_gravity  # noqa: E402
from affordcore.sequence import INVALID_DEPTH, read_sequence  # noqa: E402
from affordcore.settings import AssemblerSettings, GravitySettings  # noqa: E402

SEQUENCE = (
    Path(__file__).resolve().parents[2]
    / "shared"
    / "data"
    / "sequences"
    / "7scenes_redkitchen_frames_000000-000299"
)
GROUND_TRUTH_JUMP = 122  # the first frame after the ground truth's unsupported 3.5 cm step (see above)


def every_nth_pixel(image: DepthImage, n: int, min_range: float, max_range: float) -> np.ndarray:
    """Every n-th pixel in each direction, as it is: blocks of one pixel on the strided image, whose pinhole
    is the original's scaled by 1/n (pixel u*n of the original is pixel u of the strided one)."""
    scale = np.diag([1 / n, 1 / n, 1.0])
    strided = DepthImage(image.pixels[::n, ::n], scale @ image.intrinsics, image.scale, image.invalid_value)
    return back_project(strided, 1, min_range, max_range)


def load_frames(folder: Path, frames: int, settings: AssemblerSettings) -> dict:
    """The first `frames` frames: block-mean points with the assembler's settings, every-2nd-pixel points with
    its range (and with KISS-ICP's default 0-4 m), the gravity an IMU would report, and the ground-truth
    poses."""
    sequence = read_sequence(folder)
    loaded = {"blocks": [], "pixels": [], "pixels 0-4 m": [], "gravity": [], "truth": []}
    for index in range(min(frames, len(sequence.frames))):
        image = DepthImage(sequence.depth(index), sequence.intrinsics, invalid_value=INVALID_DEPTH)
        loaded["blocks"].append(
            back_project(image, settings.pixel_step, settings.min_range, settings.max_range)
        )
        loaded["pixels"].append(
            every_nth_pixel(image, settings.pixel_step, settings.min_range, settings.max_range)
        )
        loaded["pixels 0-4 m"].append(every_nth_pixel(image, 2, 0.0, 4.0))
        loaded["gravity"].append(sequence.gravity(index))
        loaded["truth"].append(sequence.pose(index))
    return loaded


def run_bare(
    points: list[np.ndarray], max_range: float, min_range: float, voxel_size: float
) -> tuple[list[np.ndarray], list[float]]:
    from kiss_icp.config import KISSConfig
    from kiss_icp.kiss_icp import KissICP

    config = KISSConfig()
    config.data.max_range, config.data.min_range, config.data.deskew = max_range, min_range, False
    config.mapping.voxel_size = voxel_size
    odometry = KissICP(config)
    poses, seconds = [], []
    for frame in points:
        start = time.perf_counter()
        odometry.register_frame(frame, np.zeros(len(frame)))
        seconds.append(time.perf_counter() - start)
        poses.append(odometry.last_pose.copy())
    return poses, seconds


def run_assembler(
    points: list[np.ndarray], gravity: list, settings: AssemblerSettings
) -> tuple[list[np.ndarray], list[float], Assembler]:
    assembler = Assembler(settings)
    poses, seconds = [], []
    for index, (frame, down) in enumerate(zip(points, gravity)):
        start = time.perf_counter()
        poses.append(assembler.register(frame, index / 30, gravity=down).pose)
        seconds.append(time.perf_counter() - start)
    return poses, seconds, assembler


def error_row(name: str, poses: list[np.ndarray], truth: list[np.ndarray], ms: float) -> str:
    e = trajectory_errors(poses, truth)
    return (
        f"| {name} | {e['frames']} | {e['path_m']:.2f} | {100 * e['mean_m']:.1f} | "
        f"{100 * e['worst_m']:.1f} | {e['final_rotation_deg']:.2f} | {ms:.0f} |"
    )


def split_row(name: str, poses: list[np.ndarray], truth: list[np.ndarray]) -> str:
    cells = []
    for low, high in ((0, GROUND_TRUTH_JUMP), (GROUND_TRUTH_JUMP, len(truth))):
        if high - low < 2:
            cells.append("- | - | -")
            continue
        anchor = np.linalg.inv(poses[low])
        e = trajectory_errors([anchor @ pose for pose in poses[low:high]], truth[low:high])
        cells.append(f"{100 * e['mean_m']:.1f} | {100 * e['worst_m']:.1f} | {e['final_rotation_deg']:.2f}")
    return f"| {name} | " + " | ".join(cells) + " |"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=300, help="the first N frames of the sequence")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    if not SEQUENCE.is_dir():
        print(f"skipped: the 7-Scenes redkitchen frames are not at {SEQUENCE} (see ../shared/data/README.md)")
        return
    settings = AssemblerSettings()
    frames = load_frames(SEQUENCE, args.frames, settings)
    points, truth = frames["blocks"], frames["truth"]
    import kiss_icp.kiss_icp  # noqa: F401  (import cost is nobody's frame time)

    loaded_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    bare_ms, ours_ms, ratio, cpu = [], [], [], []
    for repeat in range(args.repeats):
        cpu_start, wall_start = time.process_time(), time.perf_counter()
        runs = {}
        for which in ("bare", "ours") if repeat % 2 == 0 else ("ours", "bare"):
            if which == "bare":
                runs["bare"] = run_bare(points, settings.max_range, settings.min_range, settings.voxel_size)
            else:
                runs["ours"] = run_assembler(points, frames["gravity"], settings)
        cpu.append((time.process_time() - cpu_start) / (time.perf_counter() - wall_start))
        bare_ms.append(1000 * statistics.median(runs["bare"][1]))
        ours_ms.append(1000 * statistics.median(runs["ours"][1]))
        ratio.append(ours_ms[-1] / bare_ms[-1])
        if repeat == 0:
            bare_poses, ours_poses, assembler = runs["bare"][0], runs["ours"][0], runs["ours"][2]
    with_gravity, auto = [], []
    for _ in range(args.repeats):
        start = time.perf_counter()
        map_points, _ = assembler.aligned_map()
        with_gravity.append(time.perf_counter() - start)
        start = time.perf_counter()
        try:
            align_to_gravity(assembler.map_points(), "auto", GravitySettings())  # aligned_map without an IMU
        except ValueError:
            pass
        auto.append(time.perf_counter() - start)

    print(
        f"7-Scenes redkitchen, {len(points)} frames, "
        f"{statistics.mean(len(p) for p in points):,.0f} points a frame "
        f"({settings.pixel_step} x {settings.pixel_step} block means, "
        f"{settings.min_range:g}-{settings.max_range:g} m), "
        f"{os.cpu_count()} cores, {args.repeats} repeats, cpu/wall {min(cpu):.2f}-{max(cpu):.2f} "
        "(2.0 would be both cores busy)"
    )
    print(f"assembler defaults: {', '.join(f'{k} {v:g}' for k, v in settings.model_dump().items())}\n")
    print("| per frame (median over the frames, then over the repeats) | ms |\n|---|---:|")
    print(
        f"| bare KISS-ICP (voxel {settings.voxel_size:g} m, register_frame) | "
        f"{statistics.median(bare_ms):.1f} |"
    )
    print(f"| Assembler.register (KISS-ICP + global map + keyframes) | {statistics.median(ours_ms):.1f} |")
    print(f"| ratio assembler / bare | {statistics.median(ratio):.2f} |")
    print(
        f"| Assembler.aligned_map() at the end, gravity from the frames ({len(map_points):,} points, "
        f"{assembler.keyframes} keyframes of {assembler.frames} frames) | "
        f"{1000 * statistics.median(with_gravity):.0f} |"
    )
    print(
        "| the same alignment without gravity (floor search over the candidate axes) | "
        f"{1000 * statistics.median(auto):.0f} |"
    )
    print(
        f"\npeak memory {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:,.0f} MB "
        "(the whole process; "
        f"{loaded_mb:,.0f} MB once the frames were loaded)\n"
    )

    default_poses, default_seconds = run_bare(frames["pixels 0-4 m"], 4.0, 0.0, 0.04)
    pixel_poses, pixel_seconds, _ = run_assembler(frames["pixels"], frames["gravity"], settings)
    rows = [
        (
            "bare KISS-ICP, KISSConfig defaults, every 2nd pixel",
            default_poses,
            1000 * statistics.median(default_seconds),
        ),
        (
            f"bare KISS-ICP, voxel {settings.voxel_size:g}, block means",
            bare_poses,
            statistics.median(bare_ms),
        ),
        ("assembler defaults, every 2nd pixel", pixel_poses, 1000 * statistics.median(pixel_seconds)),
        ("assembler defaults, block means (back_project)", ours_poses, statistics.median(ours_ms)),
    ]
    print(
        "| trajectory | frames | path (m) | mean (cm) | worst (cm) | final rotation (deg) | ms/frame |\n"
        "|---|---:|---:|---:|---:|---:|---:|"
    )
    for name, poses, ms in rows:
        print(error_row(name, poses, truth, ms))
    print(
        "\nThe same trajectories, the ground truth split at its jump: "
        f"frames 0-{min(GROUND_TRUTH_JUMP, len(truth)) - 1} "
        f"and {GROUND_TRUTH_JUMP}-{len(truth) - 1}, each anchored at its own first frame"
    )
    print(
        "| trajectory | mean (cm) | worst (cm) | final rot. (deg) "
        "| mean (cm) | worst (cm) | final rot. (deg) |\n"
        "|---|---:|---:|---:|---:|---:|---:|"
    )
    for name, poses, _ in rows:
        print(split_row(name, poses, truth))


if __name__ == "__main__":
    main()
