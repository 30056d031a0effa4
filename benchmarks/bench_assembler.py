"""Scan assembly on real depth frames: what a depth frame costs the assembler against bare KISS-ICP on the
same points, under the first settings it shipped with and today's defaults, side by side in one run, and
how far each trajectory is from the ground truth.

Microsoft 7-Scenes redkitchen, frames 0 to 299 (Kinect v1, 640 x 480, a 2.11 m hand-held path; in
../shared/data/sequences/). The depth images are decoded before anything is timed.

Per frame, four pipelines take their turn (the order rotates from frame to frame, so a noisy machine slows
them alike): for each of the two settings, bare KISS-ICP (`KissICP(kiss_config(settings))`, `register_frame`
only, on the points the assembler back-projected from that frame) and the assembler as its service runs it:
`Assembler.add`'s two steps (`back_project` of the 640 x 480 depth image, then `Assembler.register` with the
frame's gravity, as an IMU would report it), the journal (`AssemblerStore.append`) and the recording
(`set_time`, `log_scan` into an .rrd file). The table has, per pipeline, the median, 90th percentile and
mean of its ms per frame over the frames, then the median of each over the repeats; the ratio is the median
over the repeats of (assembler median / bare median). The overhead rows split the assembler's time:
back-projection, journal and recording timed apiece, registration beyond KISS-ICP as the difference of
medians.
`Assembler.aligned_map()` (done at each map publication, not per frame) is timed on the final map.

Trajectory error against the 7-Scenes ground truth (KinectFusion), positions anchored at the first frame.
The ground truth jumps 3.5 cm and 1.6 degrees between frames 121 and 122, a step the depth frames do not show
(point-to-plane ICP of frame 122 onto 121: 64 % of the points within 2 cm with the ground truth's step, 98.5 %
with its own 7 mm one; every other step of the sequence scores alike both ways), so every error after frame
121 carries it: a second table scores the two halves separately, each anchored at its own first frame.

With `--grid-noise` it also runs the assembler (each setting) on the frames as seen through a block grid
shifted by a pixel down, across or both: the same data, other block means; the spread of those trajectory
errors is how far a change of settings has to move them to mean anything.

    .venv/bin/python benchmarks/bench_assembler.py               # about 6 minutes on 2 quiet cores
    .venv/bin/python benchmarks/bench_assembler.py --grid-noise  # 3 minutes more
    .venv/bin/python benchmarks/bench_assembler.py --frames 100 --repeats 1
    .venv/bin/python benchmarks/bench_assembler.py --step 3 --hogs 2 --repeats 1   # a 10 Hz walk, busy robot
    .venv/bin/python benchmarks/bench_assembler.py --against MAX_POINTS_PER_VOXEL=20   # other settings beside

Three settings side by side: the first settings it shipped with, today's defaults, and the registration a
busy assembler uses (scans waiting in its inbox: one point per `busy_registration_voxels` registered; bare
KISS-ICP beside it registers as always, so its ratio is below 1).
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from affordcore.assembly.assembler import (  # noqa: E402
    Assembler,
    SensorFrame,
    kiss_config,
    trajectory_errors,
    within_range,
)
from affordcore.assembly.checkpoint import AssemblerStore  # noqa: E402
from affordcore.assembly.depth import DepthImage, back_project  # noqa: E402
from affordcore.assembly.sequence import INVALID_DEPTH, read_sequence  # noqa: E402
from affordcore.geometry.gravity import align_to_gravity  # noqa: E402
from affordcore.mapping.recording import close_recording, log_scan, open_recording, set_time  # noqa: E402
from affordcore.settings import AssemblerSettings, GravitySettings  # noqa: E402
from services.launch import cpu_hogs  # noqa: E402

SEQUENCE = (
    Path(__file__).resolve().parents[2]
    / "shared"
    / "data"
    / "sequences"
    / "7scenes_redkitchen_frames_000000-000299"
)
GROUND_TRUTH_JUMP = 122  # the first frame after the ground truth's unsupported 3.5 cm step (see above)
# the assembler's first settings, as explicit values (everything else as today's defaults)
BEFORE = {
    "pixel_step": 2,
    "block_stride": 1,
    "voxel_size": 0.05,
    "max_points_per_voxel": 20,
    "convergence": 1e-4,
}
# ... and the registration of a busy assembler (scans waiting: one point per 2.5 voxels registered)
BUSY = AssemblerSettings(registration_voxels=AssemblerSettings().busy_registration_voxels)
SETTINGS = {"before": AssemblerSettings(**BEFORE), "defaults": AssemblerSettings(), "busy": BUSY}


class Pipelines:
    """Bare KISS-ICP and the assembler's service path for one setting, with what they took."""

    def __init__(self, settings: AssemblerSettings, folder: Path):
        from kiss_icp.kiss_icp import KissICP

        self.settings = settings
        self.bare = KissICP(kiss_config(settings))
        self.assembler = Assembler(settings)
        self.store = AssemblerStore(folder / "state")
        self.recording = open_recording(folder / "assembler.rrd", [])
        self.points: list[int] = []  # points a frame, as back-projected
        self.seconds = {name: [] for name in ("bare", "ours", "back_project", "journal", "recording")}
        self.bare_poses: list[np.ndarray] = []
        self.poses: list[np.ndarray] = []
        self.records: list = []

    def back_project(self, image: DepthImage) -> np.ndarray:
        settings = self.settings
        return back_project(
            image, settings.pixel_step, settings.min_range, settings.max_range, settings.block_stride
        )

    def run_ours(self, image: DepthImage, gravity, stamp: float) -> None:
        seconds = self.seconds
        start = time.perf_counter()
        points, map_frame = self.assembler.depth_points(image)  # as Assembler.add does
        projected = time.perf_counter()
        record = self.assembler.register(points, stamp, gravity=gravity, map_frame=map_frame)
        registered = time.perf_counter()
        self.store.append(record)
        journaled = time.perf_counter()
        set_time(self.recording, stamp)
        log_scan(self.recording, self.assembler.registered_points, record.pose)
        end = time.perf_counter()
        seconds["ours"].append(end - start)
        seconds["back_project"].append(projected - start)
        seconds["journal"].append(journaled - registered)
        seconds["recording"].append(end - journaled)
        self.points.append(len(points))
        self.poses.append(record.pose)
        self.records.append(record)

    def run_bare(self, image: DepthImage) -> None:
        points = self.back_project(image)  # the same points as the assembler's, not timed
        start = time.perf_counter()
        self.bare.register_frame(points, np.zeros(len(points)))
        self.seconds["bare"].append(time.perf_counter() - start)
        self.bare_poses.append(self.bare.last_pose.copy())

    def close(self) -> None:
        self.store.close()
        close_recording(self.recording)


def one_repeat(images: list[DepthImage], gravity: list, repeat: int) -> dict[str, Pipelines]:
    with tempfile.TemporaryDirectory() as folder:
        pipelines = {name: Pipelines(s, Path(folder) / name) for name, s in SETTINGS.items()}
        runs = [(pipeline, kind) for pipeline in pipelines.values() for kind in ("ours", "bare")]
        for index, (image, down) in enumerate(zip(images, gravity)):
            turn = (index + repeat) % len(runs)  # rotate which pipeline goes first
            for pipeline, kind in runs[turn:] + runs[:turn]:
                if kind == "ours":
                    pipeline.run_ours(image, down, index / 30)
                else:
                    pipeline.run_bare(image)
        for pipeline in pipelines.values():
            pipeline.close()
    return pipelines


def shifted(image: DepthImage, rows: int, columns: int) -> DepthImage:
    """The image without its first rows and columns (the blocks then straddle other pixels), its pinhole
    moved along: the same frame through a block grid shifted by a pixel (the noise of a trajectory error)."""
    intrinsics = image.intrinsics.copy()
    intrinsics[0, 2] -= columns
    intrinsics[1, 2] -= rows
    return DepthImage(image.pixels[rows:, columns:], intrinsics, image.scale, image.invalid_value)


def grid_errors(images: list[DepthImage], gravity: list, truth: list[np.ndarray]) -> None:
    """Mean and worst position error of the assembler under each setting, for each shift of the block grid."""
    shifts = ((0, 0), (0, 1), (1, 0), (1, 1))
    print(
        "\nNoise of the trajectory error: the assembler with its block grid shifted by (rows, columns) "
        "pixels, mean / worst (cm)\n| settings | "
        + " | ".join(f"{shift}" for shift in shifts)
        + " |\n|---|"
        + "---:|" * len(shifts)
    )
    for name, settings in SETTINGS.items():
        cells = []
        for rows, columns in shifts:
            assembler = Assembler(settings)
            poses = [
                assembler.add(
                    SensorFrame("camera", index / 30, depth=shifted(image, rows, columns), gravity=g),
                    index / 30,
                ).pose
                for index, (image, g) in enumerate(zip(images, gravity))
            ]
            e = trajectory_errors(poses, truth)
            cells.append(f"{100 * e['mean_m']:.2f} / {100 * e['worst_m']:.1f}")
        print(f"| {name} | " + " | ".join(cells) + " |")


def ms(seconds: list[float], q: float = 0.5) -> float:
    return 1000 * float(np.quantile(seconds, q))


def error_cells(poses: list[np.ndarray], truth: list[np.ndarray]) -> str:
    e = trajectory_errors(poses, truth)
    return f"{100 * e['mean_m']:.2f} | {100 * e['worst_m']:.1f} | {e['final_rotation_deg']:.2f}"


def split_cells(poses: list[np.ndarray], truth: list[np.ndarray]) -> str:
    cells = []
    for low, high in ((0, GROUND_TRUTH_JUMP), (GROUND_TRUTH_JUMP, len(truth))):
        if high - low < 2:
            cells.append("- | - | -")
            continue
        anchor = np.linalg.inv(poses[low])
        e = trajectory_errors([anchor @ pose for pose in poses[low:high]], truth[low:high])
        cells.append(f"{100 * e['mean_m']:.1f} | {100 * e['worst_m']:.1f} | {e['final_rotation_deg']:.2f}")
    return " | ".join(cells)


def describe(settings: AssemblerSettings) -> str:
    return (
        f"{settings.pixel_step} x {settings.pixel_step} block means, every "
        f"{'' if settings.block_stride == 1 else f'{settings.block_stride}th '}block; voxel "
        f"{settings.voxel_size:g} m, {settings.max_points_per_voxel} points a voxel, ICP converged at "
        f"{settings.convergence:g}, registered on one point per {settings.registration_voxels:g} voxels"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=300, help="the first N frames of the sequence")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--grid-noise", action="store_true", help="also the trajectory errors with the block grid shifted"
    )
    parser.add_argument("--hogs", type=int, default=0, help="CPU hogs beside it (one per core: a busy robot)")
    parser.add_argument("--step", type=int, default=1, help="every n-th frame (3: a 10 Hz stream)")
    parser.add_argument(
        "--against", default="", help="AFFORD_ASSEMBLER__ settings: KEY=VALUE,... (two more rows: calm, busy)"
    )
    args = parser.parse_args()
    if args.against:  # the defaults with these settings, calm and with scans waiting, beside the others
        from bench_odometry import against_settings

        other = AssemblerSettings(**against_settings(args.against))
        SETTINGS[args.against] = other
        SETTINGS[f"{args.against}, busy"] = other.model_copy(
            update={"registration_voxels": other.busy_registration_voxels}
        )
    with cpu_hogs(args.hogs):
        run(args)


def run(args) -> None:
    if not SEQUENCE.is_dir():
        print(f"skipped: the 7-Scenes redkitchen frames are not at {SEQUENCE} (see ../shared/data/README.md)")
        return
    sequence = read_sequence(SEQUENCE)
    indices = list(range(0, min(args.frames, len(sequence.frames)), args.step))
    count = len(indices)
    images = [
        DepthImage(sequence.depth(index), sequence.intrinsics, invalid_value=INVALID_DEPTH)
        for index in indices
    ]
    gravity = [sequence.gravity(index) for index in indices]
    truth = [sequence.pose(index) for index in indices]
    import kiss_icp.kiss_icp  # noqa: F401  (import cost is nobody's frame time)

    loaded_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    keys = ("median", "p90", "mean", "bare", "bare_p90", "bare_mean", "ratio")
    summary = {name: {key: [] for key in keys} for name in SETTINGS}
    parts = {
        name: {key: [] for key in ("back_project", "journal", "recording", "beyond")} for name in SETTINGS
    }
    cpu, first = [], None
    for repeat in range(args.repeats):
        cpu_start, wall_start = time.process_time(), time.perf_counter()
        pipelines = one_repeat(images, gravity, repeat)
        cpu.append((time.process_time() - cpu_start) / (time.perf_counter() - wall_start))
        for name, pipeline in pipelines.items():
            seconds, row = pipeline.seconds, summary[name]
            row["median"].append(ms(seconds["ours"]))
            row["p90"].append(ms(seconds["ours"], 0.9))
            row["bare"].append(ms(seconds["bare"]))
            row["bare_p90"].append(ms(seconds["bare"], 0.9))
            row["mean"].append(1000 * statistics.mean(seconds["ours"]))
            row["bare_mean"].append(1000 * statistics.mean(seconds["bare"]))
            row["ratio"].append(row["median"][-1] / row["bare"][-1])
            for key in ("back_project", "journal", "recording"):
                parts[name][key].append(ms(seconds[key]))
            registration = [  # Assembler.register alone
                total - projection - journal - recording
                for total, projection, journal, recording in zip(
                    seconds["ours"], seconds["back_project"], seconds["journal"], seconds["recording"]
                )
            ]
            parts[name]["beyond"].append(ms(registration) - ms(seconds["bare"]))
        first = first or pipelines

    print(
        f"7-Scenes redkitchen, {count} frames of 640 x 480 (every {args.step}), {os.cpu_count()} cores, "
        f"{args.hogs} CPU hogs beside it, {args.repeats} repeats, "
        f"cpu/wall {min(cpu):.2f}-{max(cpu):.2f} (2.0 would be both cores busy), load average "
        f"{os.getloadavg()[0]:.1f} at the end"
    )
    for name, settings in SETTINGS.items():
        print(f"{name}: {describe(settings)}, {settings.min_range:g}-{settings.max_range:g} m")
    print()
    print(
        "| settings | points a frame | bare KISS-ICP ms (median / p90 / mean) "
        "| assembler ms (median / p90 / mean) | ratio | ATE mean (cm) | worst (cm) | final rot. (deg) |\n"
        "|---|---:|---:|---:|---:|---:|---:|---:|"
    )
    for name in SETTINGS:
        row, pipeline = summary[name], first[name]
        print(
            f"| {name} | {statistics.mean(pipeline.points):,.0f} | "
            + " / ".join(f"{statistics.median(row[key]):.1f}" for key in ("bare", "bare_p90", "bare_mean"))
            + " | "
            + " / ".join(f"{statistics.median(row[key]):.1f}" for key in ("median", "p90", "mean"))
            + f" | {statistics.median(row['ratio']):.2f} | "
            f"{error_cells(pipeline.poses, truth)} |"
        )
    print(
        "\n| the assembler's own ms per frame (medians) | back-projection | registration beyond KISS-ICP "
        "| journal | recording | total | of bare KISS-ICP |\n|---|---:|---:|---:|---:|---:|---:|"
    )
    for name in SETTINGS:
        cells = [
            statistics.median(parts[name][key]) for key in ("back_project", "beyond", "journal", "recording")
        ]
        bare = statistics.median(summary[name]["bare"])
        print(
            f"| {name} | " + " | ".join(f"{cell:.2f}" for cell in cells) + f" | {sum(cells):.2f} | "
            f"{100 * sum(cells) / bare:.0f} % |"
        )

    assembler = first["defaults"].assembler
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
        f"\nAssembler.aligned_map() at the end (defaults; {len(map_points):,} points, {assembler.keyframes} "
        f"keyframes of {assembler.frames} frames): {1000 * statistics.median(with_gravity):.0f} ms with the "
        f"frames' gravity, {1000 * statistics.median(auto):.0f} ms with the floor search over candidate axes"
    )
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(
        f"peak memory {peak_mb:,.0f} MB (the whole process; {loaded_mb:,.0f} MB once the frames were loaded)"
    )
    if args.step == 1 and count > GROUND_TRUTH_JUMP + 1:  # the split is by frame number
        print(
            "\nTrajectories (first repeat), the ground truth split at its jump: "
            f"frames 0-{GROUND_TRUTH_JUMP - 1} and {GROUND_TRUTH_JUMP}-{count - 1}, each anchored at its own "
            "first frame"
        )
        print(
            "| trajectory | mean (cm) | worst (cm) | final rot. (deg) "
            "| mean (cm) | worst (cm) | final rot. (deg) |\n|---|---:|---:|---:|---:|---:|---:|"
        )
        for name in SETTINGS:
            print(f"| bare KISS-ICP, {name} | {split_cells(first[name].bare_poses, truth)} |")
            print(f"| assembler, {name} | {split_cells(first[name].poses, truth)} |")
    map_step(images, first["defaults"])
    if args.grid_noise:
        grid_errors(images, gravity, truth)


def map_step(images: list[DepthImage], defaults: Pipelines) -> None:
    """What a keyframe costs the global map, the first-point map it replaced and today's side by side on the
    same keyframes at the same poses (the defaults' first repeat), taking turns: before, the registration's
    block means thinned to one point per map voxel (KISS-ICP's voxel_down_sample: the first point) into a
    VoxelHashMap of one point per voxel; today, the blocks back-projected again without those across depth
    edges, moved, reduced to sums per cell and merged into the running means (`VoxelMeans`)."""
    from kiss_icp.mapping import VoxelHashMap

    from affordcore.assembly.voxelmap import VoxelMeans

    settings = AssemblerSettings()
    maps = {
        "before": VoxelHashMap(settings.map_voxel, max_distance=np.inf, max_points_per_voxel=1),
        "today": VoxelMeans(settings.map_voxel),
    }
    keyframes = [
        (image, record.pose)
        for image, record in zip(images, defaults.records)
        if record.map_points is not None
    ]
    seconds = {name: [] for name in maps}
    for index, (image, pose) in enumerate(keyframes):
        for name in sorted(maps, reverse=index % 2 == 1):  # taking turns at going first
            step = _map_before if name == "before" else _map_today
            seconds[name].append(step(maps[name], image, pose, settings))
    print(
        f"\nThe global map per keyframe ({len(keyframes)} keyframes of {len(images)} frames, the defaults' "
        "poses):\n| map | ms median | p90 | total ms | map points |\n|---|---:|---:|---:|---:|"
    )
    for name, times in seconds.items():
        size = len(maps[name].point_cloud())
        print(f"| {name} | {ms(times):.1f} | {ms(times, 0.9):.1f} | {1000 * sum(times):.0f} | {size:,} |")


def _map_before(voxel_map, image: DepthImage, pose: np.ndarray, settings: AssemblerSettings) -> float:
    """Seconds the first-point map (one point per voxel, the first seen) took for a keyframe."""
    from kiss_icp.voxelization import voxel_down_sample

    # the registration's block means, already made for registration: not the map's cost
    blocks = back_project(image, settings.pixel_step, settings.min_range, settings.max_range)
    start = time.perf_counter()
    thinned = voxel_down_sample(blocks, settings.map_voxel)
    voxel_map.add_points(thinned @ pose[:3, :3].T + pose[:3, 3])
    return time.perf_counter() - start


def _map_today(voxel_map, image: DepthImage, pose: np.ndarray, settings: AssemblerSettings) -> float:
    """Seconds today's map takes for a keyframe (`Assembler.register`'s keyframe step, and `apply`'s)."""
    from affordcore.geometry.cells import cell_sums

    start = time.perf_counter()
    low, high, spread = settings.min_range, settings.max_range, settings.map_edge_spread
    points = within_range(back_project(image, settings.pixel_step, low, high, max_spread=spread), settings)
    _, sums, counts = cell_sums(points @ pose[:3, :3].T + pose[:3, 3], settings.map_voxel)
    voxel_map.add_points(sums / counts[:, None], counts)
    return time.perf_counter() - start


if __name__ == "__main__":
    main()
