"""The assembler's map cloud against the fused room, without the labels: what chose its settings.

For each source of benchmarks/bench_live.py (the real 7-Scenes kitchen and generated `afford synth
--sequences` rooms), every --step-th depth frame is made into a map cloud at the true poses, the ways the
assembler's map could make it: every pixel (a reference), the first-point map (2 x 2 block means, the
first point per 2 cm voxel) and today's (block means, running mean per voxel) with blocks across a depth edge
left out at several `map_edge_spread`s. Each is compared with the room's fused cloud in 10 cm cells, the size
of the fields: cells the map fills that the room leaves empty (surfaces that are not there: flying pixels, the
blocks that straddle an edge) and cells of the room within reach of the frames that the map misses.

A second table runs the assembler itself (its own poses, the frames' gravity as an IMU would report it) and
says how level the map it publishes is: the tilt of its floor plane, and for generated rooms (their z is
true up) the angle between the published z and the true up, levelled on the frames' gravity alone
(`floor_level_max_deg` 0, as the assembler first did) and on the floor found under it (today).

    .venv/bin/python benchmarks/studies/which_map_cloud_matches_the_fused_room.py  # kitchen + 3 walks, 10 min
    .venv/bin/python benchmarks/studies/which_map_cloud_matches_the_fused_room.py --generated 0   # kitchen
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_live import KITCHEN, Source, add_source_arguments, sources  # noqa: E402

from affordcore.assembly.assembler import Assembler, SensorFrame, within_range  # noqa: E402
from affordcore.assembly.depth import DepthImage, back_project  # noqa: E402
from affordcore.assembly.sequence import read_sequence  # noqa: E402
from affordcore.assembly.voxelmap import VoxelMeans  # noqa: E402
from affordcore.geometry.gravity import align_to_gravity  # noqa: E402
from affordcore.geometry.scene import load_cloud  # noqa: E402
from affordcore.settings import AssemblerSettings, Settings  # noqa: E402

CELL = 0.10  # the fields' voxel
SPREADS = (0.0, 0.02, 0.05, 0.1)


def cells(points: np.ndarray) -> set[tuple[int, int, int]]:
    return set(map(tuple, np.floor(points / CELL).astype(np.int64)))


def grown(keys: set) -> set:
    """The cells and their 26 neighbours."""
    steps = [(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)]
    return {(a + i, b + j, c + k) for a, b, c in keys for i, j, k in steps}


def moved(cloud: np.ndarray, pose: np.ndarray) -> np.ndarray:
    return cloud @ pose[:3, :3].T + pose[:3, 3]


def map_clouds(
    images: list[DepthImage], poses: list[np.ndarray], a: AssemblerSettings
) -> dict[str, np.ndarray]:
    """The map clouds of the frames at their poses, every frame a keyframe."""
    from kiss_icp.voxelization import voxel_down_sample

    low, high = a.min_range, a.max_range
    clouds = {
        "every pixel (reference)": np.vstack(
            [moved(back_project(i, 1, low, high), p) for i, p in zip(images, poses)]
        )
    }
    first = [
        moved(voxel_down_sample(back_project(i, a.pixel_step, low, high), a.map_voxel), p)
        for i, p in zip(images, poses)
    ]
    clouds["before: first point per voxel"] = voxel_down_sample(np.vstack(first), a.map_voxel)
    for spread in SPREADS:
        means = VoxelMeans(a.map_voxel)
        for image, pose in zip(images, poses):
            blocks = back_project(image, a.pixel_step, low, high, max_spread=spread)
            means.add_points(moved(within_range(blocks, a), pose))
        clouds[f"means, edge spread {spread:g}"] = means.point_cloud()
    return clouds


def levelling(source: Source, indices: list[int], settings: Settings, generated: bool) -> list[str]:
    """Rows of how level the assembler's published map is, on the gravity alone and on its floor."""
    sequence = read_sequence(source.sequence)
    rows = []
    for limit in (0.0, settings.assembler.floor_level_max_deg):
        assembler = Assembler(settings.assembler.model_copy(update={"floor_level_max_deg": limit}))
        for index in indices:
            stamp = 1.0 + index / 30
            image = DepthImage(sequence.depth(index), sequence.intrinsics)
            assembler.add(SensorFrame("camera", stamp, depth=image, gravity=sequence.gravity(index)), stamp)
        try:
            points, world_from_odom = assembler.aligned_map(settings)
        except ValueError as error:
            rows.append(f"| {source.name} | {limit:g} | no map: {str(error)[:70]} | - |")
            continue
        only_z = settings.gravity.model_copy(update={"up_candidates": ["+z"]})
        floor = align_to_gravity(points, "auto", only_z)
        true_up = "-"
        if generated:  # the room's z is true up; the odometry frame is the first frame's camera
            odom_from_room = np.linalg.inv(source.room_from_truth @ sequence.pose(indices[0]))
            up = world_from_odom[:3, :3] @ odom_from_room[:3, :3] @ [0.0, 0.0, 1.0]
            true_up = f"{np.degrees(np.arccos(np.clip(up[2], -1, 1))):.2f}"
        rows.append(f"| {source.name} | {limit:g} | {floor.tilt_deg:.2f} | {true_up} |")
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    add_source_arguments(parser)  # bench_live.py's: the same sequences
    args = parser.parse_args()
    settings = Settings()
    a = settings.assembler
    print(
        f"Every {args.step}th frame at the true poses, {os.cpu_count()} cores; 10 cm cells against the fused "
        "room\n\n| source | map cloud | points | cells the room leaves empty "
        "| room cells within reach missed |\n|---|---|---:|---:|---:|"
    )
    levels = []
    with tempfile.TemporaryDirectory() as tmp:
        for source in sources(args, Path(tmp) / "generated"):
            sequence = read_sequence(source.sequence)
            indices = list(range(0, len(sequence.frames), args.step))
            images = [DepthImage(sequence.depth(i), sequence.intrinsics) for i in indices]
            poses = [source.room_from_truth @ sequence.pose(i) for i in indices]
            room = cells(load_cloud(source.room.with_suffix(".ply")).points)
            clouds = map_clouds(images, poses, a)
            reach = room & grown(cells(clouds["every pixel (reference)"]))
            for name, cloud in clouds.items():
                mine = cells(cloud)
                counts = f"{len(cloud):,} | {len(mine - room):,} | {len(reach - mine):,}"
                print(f"| {source.name} | {name} | {counts} |", flush=True)
            levels += levelling(source, indices, settings, generated=source.sequence != KITCHEN)
    print(
        "\nThe assembler's published map (its own poses, the frames' gravity): the tilt of its floor plane "
        "(deg), and for generated rooms the angle of its z from true up (deg)\n\n"
        "| source | floor_level_max_deg | floor tilt | z from true up |\n|---|---:|---:|---:|"
    )
    print("\n".join(levels))


if __name__ == "__main__":
    main()
