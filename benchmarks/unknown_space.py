"""Unknown is not empty: the shipped models' places on generated rooms with the sensor
positions each room was scanned from, with the rule that a place's body space must have been seen
(`visibility.min_seen`) at several shares, against no such rule.

Reads the data set and the shipped models' split of `benchmarks/accuracy.py` (the first `--rooms` rooms:
48 validation, 48 test by default), each room's ``<room>.origins.npy`` beside its cloud. The share is chosen
on the validation rooms (the most places with no more false skeletons than without the rule); the test rooms
report it, per scan style. Also: how much of each room the sensors saw (free, unknown), and what carving
costs.

    .venv/bin/python benchmarks/unknown_space.py        # about 15 minutes on 2 cores
    .venv/bin/python benchmarks/unknown_space.py --carving-only --old /tmp/old-afford   # side by side

`--old PATH`: a checkout of another commit (`git worktree add --detach /tmp/old-afford <commit>`) whose
carving runs alternately with this one's on the same lattice and positions; the table says how many voxels
each calls free and how many states differ.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent / "studies"))
from which_place_evidence_survives_a_scan_change import (  # noqa: E402  (the shipped models' split)
    STYLES,
    add_split_arguments,
    shipped_split,
)

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_split_arguments(parser)
    parser.add_argument("--shares", type=float, nargs="+", default=[0.0, 0.05, 0.1, 0.2, 0.4])
    parser.add_argument("--carving-only", action="store_true", help="only the carving's cost on the kitchen")
    parser.add_argument("--old", type=Path, help="a checkout of another commit to time the carving against")
    parser.add_argument("--repeats", type=int, default=3, help="carving runs per setting (medians)")
    args = parser.parse_args()

    print_carving_cost(args.repeats, args.old)
    if args.carving_only:
        return

    rooms, part, style, costs = load(args)
    print(f"{os.cpu_count()} cores; {len(rooms)} rooms with their sensor positions")
    print_seen(rooms, style, costs)
    results = score(rooms, args.shares)
    print_places(results, part, style, args.shares)


def print_carving_cost(repeats: int = 3, old: Path | None = None) -> None:
    """What the features service pays per live map: carving the real kitchen's lattice (../shared, when
    present) from a straight walk of 100 positions at 1.5 m, at several `visibility.max_origins`; with `old`,
    that checkout's carving too, the two taking turns (CPU seconds: other processes move wall time)."""
    from affordcore.geometry.scene import load_cloud
    from affordcore.geometry.visibility import voxel_states
    from affordcore.mapping.pipeline import prepare_scene
    from affordcore.settings import Settings

    kitchen = ROOT.parent / "shared" / "data" / "rooms" / "7scenes_redkitchen_fused_zup_DERIVED.ply"
    if not kitchen.exists():
        print("(no ../shared: the kitchen's carving cost is not measured)")
        return
    settings = Settings()
    fields = prepare_scene(load_cloud(kitchen), settings, "none").fields
    low, high = np.array(fields.footprint[:2]), np.array(fields.footprint[2:])
    along = np.linspace(0.3, 0.7, 100)[:, None]
    walk = np.column_stack([low + (high - low) * along, np.full(100, 1.5)])
    carvers = {"this": voxel_states} | ({} if old is None else {"old": _old_voxel_states(old)})
    print(
        f"carving the kitchen's {fields.lattice.shape} lattice from a 100-position walk, "
        f"{os.cpu_count()} cores, CPU seconds, median of {repeats}:"
    )
    print(
        "| max_origins | "
        + " | ".join(carvers)
        + (" | old / this | free: this / old | voxels whose state differs |" if old else " |")
    )
    print("|---:|" + "---:|" * (len(carvers) + 3 * bool(old)))
    for most in (8, 16, 32):
        chosen = settings.visibility.model_copy(update={"max_origins": most})
        seconds: dict[str, list[float]] = {name: [] for name in carvers}
        states = {}
        for _ in range(repeats):
            for name, carve in carvers.items():
                start = time.process_time()
                states[name] = carve(fields.occupancy, fields.lattice, walk, chosen)
                seconds[name].append(time.process_time() - start)
        medians = [float(np.median(seconds[name])) for name in carvers]
        compared = f" {medians[1] / medians[0]:.2f}x | {_state_change(states)} |" if old else ""
        print(f"| {most} | " + " | ".join(f"{m:.2f}" for m in medians) + " |" + compared)


def _state_change(states: dict[str, np.ndarray]) -> str:
    """Free voxels of this carving and the old one's, and the share of voxels whose state differs."""
    from affordcore.geometry.visibility import FREE

    this, old = states["this"], states["old"]
    differ = float((this != old).mean())
    return f"{int((this == FREE).sum()):,} / {int((old == FREE).sum()):,} | {100 * differ:.2f} %"


def _old_voxel_states(checkout: Path):
    """`voxel_states` of the checkout at `checkout` (its visibility module, loaded beside this one's)."""
    import importlib.util

    path = checkout / "affordcore" / "geometry" / "visibility.py"
    spec = importlib.util.spec_from_file_location("affordcore.geometry._old_visibility", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.voxel_states


def load(args):
    from affordcore.geometry.scene import load_origins, origins_file
    from affordcore.geometry.visibility import FREE, UNKNOWN, voxel_states
    from affordcore.learn.examples import load_room
    from affordcore.settings import Settings

    settings = Settings()
    files, part, style = shipped_split(args)
    rooms, costs = [], {}
    for name in part:
        room = load_room(files[name], settings)
        fields = room.fields
        if fields.visibility is None:
            raise SystemExit(f"{name}: no sensor positions beside the cloud ({name}.origins.npy)")
        origins = load_origins(origins_file(files[name].cloud))
        start = time.perf_counter()  # the carving again, alone, to time it
        voxel_states(fields.occupancy, fields.lattice, origins, settings.visibility)
        costs[name] = {
            "seconds": time.perf_counter() - start,
            "origins": len(origins),
            "voxels": fields.occupancy.size,
            "free": float((fields.visibility == FREE).mean()),
            "unknown": float((fields.visibility == UNKNOWN).mean()),
        }
        rooms.append(room)
    return rooms, part, style, costs


def print_seen(rooms, style, costs) -> None:
    """Per scan style: the lattice's share free and unknown, and what carving it costs."""
    print(
        "\n| style | rooms | sensor positions (median) | voxels (median) | free | unknown "
        "| carving s (median / max) |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|")
    for s in STYLES:
        mine = [costs[r.name] for r in rooms if style[r.name] == s]
        if not mine:
            continue
        seconds = [c["seconds"] for c in mine]
        print(
            f"| {s} | {len(mine)} | {np.median([c['origins'] for c in mine]):.0f} | "
            f"{np.median([c['voxels'] for c in mine]):,.0f} | {np.mean([c['free'] for c in mine]):.2f} | "
            f"{np.mean([c['unknown'] for c in mine]):.2f} | "
            f"{np.median(seconds):.2f} / {np.max(seconds):.2f} |"
        )


def score(rooms, shares):
    """{(affordance, share, room): (found, labels, false)} under the shipped models and their own cuts."""
    from affordcore.geometry.features import FeatureLayout
    from affordcore.learn.model import load_model, shipped_models
    from affordcore.learn.thresholds import room_scores
    from affordcore.settings import Settings

    results = {}
    for share in shares:
        settings = Settings()
        settings.visibility.min_seen = share
        layout = FeatureLayout.from_settings(settings)
        for name, path in shipped_models().items():
            model = load_model(path, layout)
            for room in rooms:
                c = room_scores(model, room, layout, settings).model_candidates(model)
                found, _, false = c.places(
                    model.places.probability(c.evidence), model.places.cut, settings.map.nms_radius
                )
                results[name, share, room.name] = (found, c.matches.shape[0], false)
    return results


def print_places(results, part, style, shares) -> None:
    print("\nplaces found / labelled, false skeletons per room (shipped models, each its own place cut)")
    groups = {"validation": ("validation", None), "test": ("test", None)}
    groups.update({f"test {s}": ("test", s) for s in STYLES})
    print("| affordance | min_seen | " + " | ".join(groups) + " |")
    print("|---|---:|" + "---|" * len(groups))
    for affordance in sorted({key[0] for key in results}):
        for share in shares:
            cells = []
            for wanted, wanted_style in groups.values():
                rows = [
                    value
                    for (a, s, room), value in results.items()
                    if a == affordance
                    and s == share
                    and part[room] == wanted
                    and wanted_style in (None, style[room])
                ]
                found, labels, false = np.sum(rows, axis=0) if rows else (0, 0, 0)
                cells.append(f"{found}/{labels}, {false / max(1, len(rows)):.2f}")
            print(f"| {affordance} | {share:.2f} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
