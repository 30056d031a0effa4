"""How much floor under tables and seats a room scan sees, under each viewpoint regime.

    .venv/bin/python -m affordcore.synth.coverage --rooms 6 --seed 0

makes the rooms `afford synth --rooms N --seed S` makes (room i from the i-th child of SeedSequence(S), kinds
in turn), scans each one twice from the same scanner seed, once from spots spread over the whole floor
(``full``) and once from a few viewpoints (``few``), and prints per room the share of the floor cells under
table tops and seats that hold a floor point (`scanner.floor_seen_share`), and which regime `afford synth`
draws for that room.
"""

from __future__ import annotations

import argparse
import copy
import time

import numpy as np

from .dataset import SynthOptions
from .rooms import generate_room
from .scanner import VIEW_REGIMES, floor_seen_share, scan_room


def measure(options: SynthOptions) -> list[dict]:
    rows = []
    for index, seed in enumerate(np.random.SeedSequence(options.seed).spawn(options.rooms)):
        rng = np.random.default_rng(seed)
        name = options.room_name(index)
        room = generate_room(options.kinds[index % len(options.kinds)], rng, name)
        drawn = "few" if rng.random() < options.few_views else "full"  # as dataset.make_room draws it
        labelled = sum(any(anchor.labelled for anchor in piece.anchors) for piece in room.pieces)
        labels = len(room.labels()["labels"])
        row = {"room": name, "drawn": drawn, "labelled": labelled, "labels": labels}
        for regime in VIEW_REGIMES:
            start = time.perf_counter()
            points, _ = scan_room(room, copy.deepcopy(rng), regime=regime)
            share, cells = floor_seen_share(room, points)
            row[regime] = {
                "seen": share,
                "points": len(points),
                "seconds": time.perf_counter() - start,
                "not_scanned": len(room.unseen_pieces(points)),
                # a piece's labels, and those of places whose own support the scan missed
                "labels_lost": labels - len(room.labels(points)["labels"]),
            }
            row["cells"] = cells
        rows.append(row)
    return rows


def table(rows: list[dict]) -> str:
    lines = [
        "| room | floor cells under tops/seats | seen, full | seen, few | drawn by `afford synth` |",
        "|---|---:|---:|---:|---|",
    ]
    for row in rows:
        lines.append(
            f"| {row['room']} | {row['cells']} | {row['full']['seen']:.0%} | {row['few']['seen']:.0%} "
            f"| {row['drawn']} |"
        )
    for regime in VIEW_REGIMES:
        seen = [row[regime]["seen"] for row in rows if row["cells"]]
        weights = [row["cells"] for row in rows if row["cells"]]
        lines.append(
            f"\n{regime}: mean {np.mean(seen):.0%}, area-weighted {np.average(seen, weights=weights):.0%}, "
            f"{np.mean([row[regime]['points'] for row in rows]):,.0f} points, "
            f"{np.mean([row[regime]['seconds'] for row in rows]):.1f} s per scan, "
            f"{sum(row[regime]['not_scanned'] for row in rows)} of {sum(row['labelled'] for row in rows)} "
            f"labelled pieces not scanned, {sum(row[regime]['labels_lost'] for row in rows)} of "
            f"{sum(row['labels'] for row in rows)} labels lost to regions not scanned"
        )
    drawn = [row[row["drawn"]]["seen"] for row in rows if row["cells"]]
    lines.append(f"\nas drawn by `afford synth`: mean {np.mean(drawn):.0%}")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rooms", type=int, default=6)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--kinds", default="living,office,workshop")
    args = parser.parse_args()
    print(table(measure(SynthOptions(args.rooms, args.seed, tuple(args.kinds.split(","))))))


if __name__ == "__main__":
    main()
