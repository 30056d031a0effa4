"""Scan assembly on real depth frames: what the assembler costs over bare KISS-ICP, and how far its trajectory
is from the ground truth.

Microsoft 7-Scenes redkitchen, frames 0 to 299 (Kinect v1, 640 x 480; ../shared/data/sequences/...). Every
frame is decoded and back-projected before anything is timed (`depth_frame_message` and `depth_points`, the
path a DepthFrame takes through the assembler service, with the assembler's pixel step and range limits).

Cost, side by side in one run on the same points: bare KISS-ICP (`KissICP(KISSConfig)` with the assembler's
range and voxel, `register_frame` only) against `Assembler.register` (the same registration, plus the depth-edge
filter's equivalent nothing -- points are already made -- the global map and the keyframes). Each repeat runs
both over every frame, in alternating order; the table has the median ms per frame of each repeat, then the
median over the repeats, and the ratio assembler / bare. `Assembler.aligned_map()` (the gravity alignment
done at each map publication) is timed on the final map.

Trajectory error against the 7-Scenes ground truth (KinectFusion), positions anchored at the first frame:
bare KISS-ICP with KISSConfig defaults except deskew off and max_range 4 m (voxel 0.04 m, max_range / 100 as
kiss_icp's load_config derives it; min_range 0), on every 2nd pixel, and the assembler with its defaults.
The ground truth jumps 3.5 cm and 1.6 degrees between frames 121 and 122, a step the depth frames do not show
(with the ground-truth step, point-to-plane ICP puts 64 % of frame 122 within 2 cm of frame 121; with its own
7 mm step, 99 %; every other step of the sequence scores alike both ways). No odometry follows that jump, so
every error after frame 121 carries it: a second table scores the two halves separately, each anchored at its
own first frame.

    .venv/bin/python benchmarks/bench_assembler.py               # about 4 minutes on 2 cores
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
from affordcore.assembly import Assembler, drop_depth_edges, trajectory_errors  # noqa: E402
from affordcore.messages import depth_frame_message, depth_points  # noqa: E402
from affordcore.sequence import INVALID_DEPTH, read_sequence  # noqa: E402
from affordcore.settings import AssemblerSettings  # noqa: E402

SEQUENCE = Path(__file__).resolve().parents[2] / "shared" / "data" / "sequences" / "7scenes_redkitchen_frames_000000-000299"
GROUND_TRUTH_JUMP = 122  # the first frame after the ground truth's unsupported 3.5 cm step (see above)


def load_frames(folder: Path, frames: int, settings: AssemblerSettings) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """(points with the assembler's settings, points of every 2nd pixel within 0-4 m for bare KISS-ICP with its
    defaults, ground-truth poses) of the first `frames` frames."""
    sequence = read_sequence(folder)
    ours, kiss_defaults, truth = [], [], []
    for index in range(min(frames, len(sequence.frames))):
        depth = sequence.depth(index)
        message = depth_frame_message(depth, sequence.intrinsics, invalid_value=INVALID_DEPTH)
        kiss_defaults.append(depth_points(message, 2, 0.0, 4.0))
        if settings.depth_edge > 0:
            message = depth_frame_message(drop_depth_edges(depth, settings.depth_edge), sequence.intrinsics, invalid_value=INVALID_DEPTH)
        ours.append(depth_points(message, settings.pixel_step, settings.min_range, settings.max_range))
        truth.append(sequence.pose(index))
    return ours, kiss_defaults, truth


def bare_kiss(max_range: float, min_range: float, voxel_size: float):
    from kiss_icp.config import KISSConfig
    from kiss_icp.kiss_icp import KissICP

    config = KISSConfig()
    config.data.max_range, config.data.min_range, config.data.deskew = max_range, min_range, False
    config.mapping.voxel_size = voxel_size
    return KissICP(config)


def run_bare(points: list[np.ndarray], max_range: float, min_range: float, voxel_size: float) -> tuple[list[np.ndarray], list[float]]:
    odometry = bare_kiss(max_range, min_range, voxel_size)
    poses, seconds = [], []
    for frame in points:
        start = time.perf_counter()
        odometry.register_frame(frame, np.zeros(len(frame)))
        seconds.append(time.perf_counter() - start)
        poses.append(odometry.last_pose.copy())
    return poses, seconds


def run_assembler(points: list[np.ndarray], settings: AssemblerSettings) -> tuple[list[np.ndarray], list[float], Assembler]:
    assembler = Assembler(settings)
    poses, seconds = [], []
    for index, frame in enumerate(points):
        start = time.perf_counter()
        poses.append(assembler.register(frame, index / 30))
        seconds.append(time.perf_counter() - start)
    return poses, seconds, assembler


def error_row(name: str, poses: list[np.ndarray], truth: list[np.ndarray], ms: float) -> str:
    e = trajectory_errors(poses, truth)
    return (f"| {name} | {e['frames']} | {e['path_m']:.2f} | {100 * e['mean_m']:.1f} | {100 * e['worst_m']:.1f} | "
            f"{e['final_rotation_deg']:.2f} | {ms:.0f} |")


def split_row(name: str, poses: list[np.ndarray], truth: list[np.ndarray]) -> str:
    cells = []
    for low, high in ((0, GROUND_TRUTH_JUMP), (GROUND_TRUTH_JUMP, len(truth))):
        if high - low < 2:
            cells.append("| - | - | -")
            continue
        anchor = np.linalg.inv(poses[low])
        e = trajectory_errors([anchor @ pose for pose in poses[low:high]], truth[low:high])
        cells.append(f"| {100 * e['mean_m']:.1f} | {100 * e['worst_m']:.1f} | {e['final_rotation_deg']:.2f}")
    return f"| {name} " + " ".join(cells) + " |"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=300, help="the first N frames of the sequence")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    if not SEQUENCE.is_dir():
        print(f"skipped: the 7-Scenes redkitchen frames are not at {SEQUENCE} (see ../shared/data/README.md)")
        return
    settings = AssemblerSettings()
    points, kiss_default_points, truth = load_frames(SEQUENCE, args.frames, settings)
    import kiss_icp  # noqa: F401  (import cost is nobody's frame time)

    loaded_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    bare_ms, ours_ms, ratio, cpu = [], [], [], []
    for repeat in range(args.repeats):
        cpu_start, wall_start = time.process_time(), time.perf_counter()
        runs = {}
        for which in (("bare", "ours") if repeat % 2 == 0 else ("ours", "bare")):
            if which == "bare":
                runs["bare"] = run_bare(points, settings.max_range, settings.min_range, settings.voxel_size)
            else:
                runs["ours"] = run_assembler(points, settings)
        cpu.append((time.process_time() - cpu_start) / (time.perf_counter() - wall_start))
        bare_ms.append(1000 * statistics.median(runs["bare"][1]))
        ours_ms.append(1000 * statistics.median(runs["ours"][1]))
        ratio.append(ours_ms[-1] / bare_ms[-1])
        if repeat == 0:
            bare_poses, ours_poses, assembler = runs["bare"][0], runs["ours"][0], runs["ours"][2]
    aligned = []
    for _ in range(args.repeats):
        start = time.perf_counter()
        map_points, _ = assembler.aligned_map()
        aligned.append(time.perf_counter() - start)

    print(f"7-Scenes redkitchen, {len(points)} frames, {statistics.mean(len(p) for p in points):,.0f} points a frame "
          f"(every {settings.pixel_step}. pixel, {settings.min_range:g}-{settings.max_range:g} m), {os.cpu_count()} cores, "
          f"{args.repeats} repeats, cpu/wall {min(cpu):.2f}-{max(cpu):.2f} (2.0 would be both cores busy)")
    print(f"assembler defaults: {settings.model_dump()}\n")
    print("| per frame (median over frames, then over repeats) | ms |\n|---|---:|")
    print(f"| bare KISS-ICP (voxel {settings.voxel_size:g} m, register_frame) | {statistics.median(bare_ms):.1f} |")
    print(f"| Assembler.register (KISS-ICP + global map + keyframes) | {statistics.median(ours_ms):.1f} |")
    print(f"| ratio assembler / bare | {statistics.median(ratio):.2f} |")
    print(f"| Assembler.aligned_map() at the end ({len(map_points):,} points, {assembler.keyframes} keyframes) | "
          f"{1000 * statistics.median(aligned):.0f} |")
    print(f"\npeak memory {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:,.0f} MB (the whole process; "
          f"{loaded_mb:,.0f} MB once the frames were loaded)\n")

    default_poses, default_seconds = run_bare(kiss_default_points, 4.0, 0.0, 0.04)
    names = {
        "bare KISS-ICP, KISSConfig defaults (deskew off, max_range 4, voxel 0.04)": (default_poses, default_seconds),
        f"bare KISS-ICP at the assembler's settings (voxel {settings.voxel_size:g})": (bare_poses, None),
        "assembler, defaults": (ours_poses, None),
    }
    print("| trajectory | frames | path (m) | mean (cm) | worst (cm) | final rotation (deg) | ms/frame |\n|---|---:|---:|---:|---:|---:|---:|")
    for name, (poses, seconds) in names.items():
        ms = 1000 * statistics.median(seconds) if seconds else (statistics.median(bare_ms) if poses is bare_poses else statistics.median(ours_ms))
        print(error_row(name, poses, truth, ms))
    print(f"\nThe same trajectories, the ground truth split at its jump (frames 0-{GROUND_TRUTH_JUMP - 1} and "
          f"{GROUND_TRUTH_JUMP}-{len(truth) - 1}, each anchored at its first frame):")
    print("| trajectory | mean (cm) | worst (cm) | final rot. (deg) | mean (cm) | worst (cm) | final rot. (deg) |\n|---|---:|---:|---:|---:|---:|---:|")
    for name, (poses, _) in names.items():
        print(split_row(name, poses, truth))


if __name__ == "__main__":
    main()
