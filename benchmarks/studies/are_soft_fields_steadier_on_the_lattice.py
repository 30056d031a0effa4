"""How much a pose's features change when the room moves against the voxel lattice: binary and soft fields.

The fields' lattice is anchored in the world, so the same room moved by a fraction of a voxel is voxelised
differently (docs/accuracy.md, "Where the room sits on the grid"). Here each room is moved by a quarter, a
half and three quarters of a voxel (in x, and half as much in y), and the features of the same poses relative
to the room (the pose grid moved with it) are compared with the room's as given: a field that depended only on
the room would give the same features. Per feature block (distance, collision, normal cube), the mean
absolute change over 20,000 poses of the room's grid, as a percentage of the block's spread (its standard
deviation over the same poses); then the fields' time. Rooms: the 10 m benchmark room and the generated rooms
of benchmarks/grid_shift.py (made once).

    .venv/bin/python benchmarks/studies/are_soft_fields_steadier_on_the_lattice.py   # 2 min, 2 cores
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: bench_map, grid_shift
from bench_map import room_cloud  # noqa: E402
from grid_shift import generated_rooms  # noqa: E402

STYLES = ("binary", "soft")
BLOCKS = {"distance": slice(0, 15), "collision": slice(15, 30), "normal cube": slice(30, None)}


def room_changes(cloud, skeleton, settings, fractions, rng) -> tuple[dict[str, np.ndarray], float]:
    """({block: (shifts,) mean absolute change / spread}, seconds the fields as given took)."""
    from affordcore.geometry.features import features_at
    from affordcore.mapping.pipeline import pose_grid, prepare_scene

    timings: dict[str, float] = {}
    given = prepare_scene(cloud, settings, "none", timings)
    grid = pose_grid(given.fields, skeleton, settings)
    poses = rng.choice(grid.size, min(20_000, grid.size), replace=False)
    reference = features_at(given.fields, skeleton, grid, given.layout, poses)
    spread = {name: reference[:, part].std() for name, part in BLOCKS.items()}
    changes = {name: [] for name in BLOCKS}
    for fraction in fractions:
        dx, dy = fraction * settings.voxel.resolution, fraction * settings.voxel.resolution / 2
        moved = prepare_scene(cloud.transformed(_translation(dx, dy)), settings, "none")
        shifted = dataclasses.replace(grid, x=grid.x + dx, y=grid.y + dy)
        difference = np.abs(features_at(moved.fields, skeleton, shifted, moved.layout, poses) - reference)
        for name, part in BLOCKS.items():
            changes[name].append(difference[:, part].mean() / spread[name])
    return {name: np.array(v) for name, v in changes.items()}, timings["voxel fields"]


def _translation(dx: float, dy: float) -> np.ndarray:
    transform = np.eye(4)
    transform[:2, 3] = dx, dy
    return transform


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--generated", type=int, default=8, help="generated rooms beside the benchmark room")
    parser.add_argument("--affordance", default="sitting-working", help="whose skeleton is placed")
    args = parser.parse_args()
    from affordcore.geometry.scene import load_cloud
    from affordcore.learn.model import load_model, shipped_models
    from affordcore.settings import Settings

    skeleton = load_model(shipped_models()[args.affordance]).as_skeleton()
    rooms = {"10 m benchmark room": room_cloud()}
    if args.generated:
        folder = generated_rooms(args.generated, 29)
        rooms |= {path.stem: load_cloud(path) for path in sorted(folder.glob("*.ply"))[: args.generated]}
    fractions = (0.25, 0.5, 0.75)
    print(
        f"features of the same {args.affordance} poses with the room moved against the lattice by a fraction "
        f"of a voxel: mean absolute change, % of the block's spread ({len(rooms)} rooms; {os.cpu_count()} "
        "cores)\n"
    )
    shift_names = [f"{f:g} voxel" for f in fractions]
    header = " | ".join(f"{block}, {shift}" for block in BLOCKS for shift in shift_names)
    print(f"| fields | {header} | fields' seconds (median) |")
    print("|---|" + "---:|" * (len(BLOCKS) * len(fractions) + 1))
    for style in STYLES:
        settings = Settings(voxel={"fields": style})
        rng = np.random.default_rng(0)
        per_room, seconds = [], []
        for cloud in rooms.values():
            changes, took = room_changes(cloud, skeleton, settings, fractions, rng)
            per_room.append(changes)
            seconds.append(took)
        cells = " | ".join(
            f"{100 * np.mean([room[block][k] for room in per_room]):.1f}"
            for block in BLOCKS
            for k in range(len(fractions))
        )
        print(f"| {style} | {cells} | {statistics.median(seconds):.2f} |")


if __name__ == "__main__":
    main()
