"""Which way is up: automatic gravity alignment on generated rooms of every scan style, each in three frames.

`afford map` (and `afford align`) levels a cloud of unknown convention by looking for a floor along +z, +y and
-y and choosing among the valid ones by their floor evidence (docs/geometry.md). Generated rooms are z-up, so
each is presented z-up, y-up and as a camera frame (y down) and the choice is checked: right, the ceiling
taken for the floor (up the wrong way along the right axis), a wall taken for it, or no floor found. Rooms
come from a data set of `afford synth` (default: the accuracy benchmark's, generated there if absent); the
real rooms are not used.

    .venv/bin/python benchmarks/studies/does_gravity_alignment_find_up.py   # 240 rooms x 3 frames, 4 min
    .venv/bin/python benchmarks/studies/does_gravity_alignment_find_up.py --rooms 60
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

# each frame as the rotation taking the room's z-up coordinates into it, and the axis that is up there
FRAMES = {
    "+z": np.eye(3),
    "+y": np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]),
    "-y": np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]),
}


OPPOSITE = {"+y": "-y", "-y": "+y", "+z": "-z"}


def choices(path: Path) -> dict[str, list[str]]:
    """For each frame, searched without and with the sensor positions (the room's `.origins.npy`): "right",
    "ceiling" (the right axis the wrong way up), "wall" (another axis) or "no floor"."""
    from affordcore.geometry.gravity import NoFloorError, align_to_gravity
    from affordcore.geometry.scene import load_cloud

    cloud = load_cloud(path)
    out: dict[str, list[str]] = {"without": [], "with": []}
    for up, rotation in FRAMES.items():
        for known, origins in (("without", None), ("with", cloud.origins)):
            try:
                at = None if origins is None else origins @ rotation.T
                chosen = align_to_gravity(cloud.points @ rotation.T, origins=at).up_axis
            except NoFloorError:
                out[known].append("no floor")
                continue
            out[known].append("right" if chosen == up else "ceiling" if chosen == OPPOSITE[up] else "wall")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", type=Path, default=ROOT / "bench-data" / "accuracy")
    parser.add_argument("--rooms", type=int, default=240, help="the first N rooms of the data set")
    parser.add_argument("--seed", type=int, default=1, help="the data set's seed, when it is generated here")
    args = parser.parse_args()
    if not (args.data / "summary.json").is_file():
        from affordcore.synth.batch import synthesize
        from affordcore.synth.dataset import SynthOptions

        synthesize(SynthOptions(rooms=args.rooms, seed=args.seed), args.data)
    rooms = json.loads((args.data / "summary.json").read_text())["rooms"][: args.rooms]
    paths = [args.data / f"{room['room']}.ply" for room in rooms]
    with ProcessPoolExecutor(os.cpu_count()) as pool:
        results = list(pool.map(choices, paths, chunksize=4))
    counts: dict[tuple[str, str], Counter] = {}
    for room, outcome in zip(rooms, results):
        for style in (room["style"], "every style"):
            for known, chosen in outcome.items():
                counts.setdefault((style, known), Counter()).update(chosen)
    print(f"{len(rooms)} rooms of {args.data}, each z-up, y-up and y-down; {os.cpu_count()} cores")
    print("Each cell: without / with the sensor positions (`afford map` uses them when the cloud has them)\n")
    print("| scan style | clouds | up right | the ceiling taken for the floor | a wall | no floor found |")
    print("|---|---:|---:|---:|---:|---:|")
    styles = sorted({style for style, _ in counts}, key=lambda style: style == "every style")
    for style in styles:
        without, known = counts[(style, "without")], counts[(style, "with")]
        cells = " | ".join(f"{without[k]} / {known[k]}" for k in ("right", "ceiling", "wall", "no floor"))
        print(f"| {style} | {sum(without.values())} | {cells} |")


if __name__ == "__main__":
    main()
