"""What each scan style (affordcore/synth/styles.py) costs and how its points spread: seconds per room,
points, sensor origins, point spacing on flat surfaces against at edges, and the share of the floor under
tables and seats that holds a point (`scanner.floor_seen_share`). docs/synthetic-rooms.md quotes its table.

Room i is the one `afford synth --seed S` makes as room i (kinds living, office, workshop in turn), scanned
in every style from the same generator state, so the styles are compared on the same rooms.

Density: the points within 5 cm of a point, per m^2 of a 5 cm disc, median over the points 10 cm or more from
every box edge ("flat") and over those within 2 cm of one ("edge"); box edges are sampled every 5 mm. Medians
over rooms; the points and origins columns too.

    .venv/bin/python benchmarks/scan_styles.py --rooms 6 --seed 24   # about 3 minutes on 2 busy cores
"""

from __future__ import annotations

import argparse
import copy
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from affordcore.synth.dataset import SynthOptions  # noqa: E402
from affordcore.synth.rooms import generate_room  # noqa: E402
from affordcore.synth.scanner import floor_seen_share  # noqa: E402
from affordcore.synth.styles import STYLES, edge_samples, scan_in_style  # noqa: E402

RADIUS = 0.05  # m: points are counted within this of each point


def densities(points: np.ndarray, edges: cKDTree) -> tuple[float, float]:
    """(median points per m^2 on flat surfaces, at edges): the points within `RADIUS` of a point over the
    area of a disc that wide, medians over every 7th point (all points are counted)."""
    probes = points[::7]
    to_edge, _ = edges.query(probes, workers=-1)
    count = cKDTree(points).query_ball_point(probes, RADIUS, return_length=True, workers=-1)
    per_m2 = count / (np.pi * RADIUS**2)
    return float(np.median(per_m2[to_edge >= 0.10])), float(np.median(per_m2[to_edge <= 0.02]))


def measure_room(options: SynthOptions, index: int, seed) -> list[dict]:
    rng = np.random.default_rng(seed)
    room = generate_room(options.kinds[index % len(options.kinds)], rng, options.room_name(index))
    regime = "few" if rng.random() < options.few_views else "full"  # as dataset.make_room draws it
    edges = cKDTree(edge_samples(room.shell_boxes() + room.furniture_boxes()))
    rows = []
    for style in STYLES:
        start = time.perf_counter()
        scan = scan_in_style(style, room, copy.deepcopy(rng), regime)
        seconds = time.perf_counter() - start
        flat, edge = densities(scan.points, edges)
        seen, _ = floor_seen_share(room, scan.points)
        rows.append(
            {
                "style": style,
                "seconds": seconds,
                "points": len(scan.points),
                "origins": len(scan.origins),
                "flat_per_m2": flat,
                "edge_per_m2": edge,
                "floor_seen": seen,
            }
        )
        print(f"  {options.room_name(index)} {style}: {rows[-1]}", file=sys.stderr, flush=True)
    return rows


def _medians(rows: list[dict]):
    def median(key: str) -> float:
        return statistics.median(row[key] for row in rows if np.isfinite(row[key]))

    return median


def table(rows: list[dict]) -> str:
    lines = [
        "| style | s/room median | s/room max | points | origins | points/m^2 flat "
        "| points/m^2 edge | edge/flat | floor under tables seen |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for style in STYLES:
        mine = [row for row in rows if row["style"] == style]
        median = _medians(mine)
        lines.append(
            f"| {style} | {median('seconds'):.1f} | {max(r['seconds'] for r in mine):.1f} | "
            f"{median('points'):,.0f} | {median('origins'):.0f} | {median('flat_per_m2'):,.0f} | "
            f"{median('edge_per_m2'):,.0f} | {median('edge_per_m2') / median('flat_per_m2'):.1f} | "
            f"{100 * median('floor_seen'):.0f} % |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rooms", type=int, default=6)
    parser.add_argument("--seed", type=int, default=24)
    args = parser.parse_args()
    options = SynthOptions(args.rooms, args.seed)
    seeds = np.random.SeedSequence(args.seed).spawn(args.rooms)
    rows = [row for index, seed in enumerate(seeds) for row in measure_room(options, index, seed)]
    print(f"{args.rooms} rooms, seed {args.seed}; medians over rooms\n")
    print(table(rows))


if __name__ == "__main__":
    main()
