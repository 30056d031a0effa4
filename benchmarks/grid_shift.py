"""How much the places a map finds depend on where the room happens to sit on the pose grid, or on a floor
found a little off.

A robot's map of a room lands on the 10 cm / 0.1 rad pose grid wherever its frame puts it. Each room here is
mapped as given and again moved rigidly by less than one step of the grid (translated by a quarter, a half and
three quarters of the 10 cm step, turned by half a theta step either way about its centre), its labels and
sensor positions moved with it, and each map's places matched against the moved labels (DESIGN.md's place
tolerances). Every shifted room is the same room: a model whose places move between them is deciding on
where the grid falls, not on the room. Per room and affordance the table has the places found (and false
skeletons) at each shift; the totals per shift say how far a place count of one benchmark run can move for
this reason alone. With `--floor`, the room is instead lifted or lowered by 1-3 cm and tilted by 0.5-1
degree about its centre and mapped as levelled (`--gravity none`): what a floor found that far off does to
the places.

Rooms: `afford synth` rooms of a seed no model saw (written once to bench-data/grid-shift), or any folder of
labelled rooms (`--rooms DIR`). The real rooms of ../shared/data/rooms are a test set: report them
(`--rooms ../shared/data/rooms`), never choose anything on them.

    .venv/bin/python benchmarks/grid_shift.py                          # 8 generated rooms, about 2 minutes
    .venv/bin/python benchmarks/grid_shift.py --rooms ../shared/data/rooms
    .venv/bin/python benchmarks/grid_shift.py --rooms bench-data/accuracy --held-out   # 8 minutes
    .venv/bin/python benchmarks/grid_shift.py --loose   # places matched within 0.3 m and 0.5 rad (DESIGN.md)
    .venv/bin/python benchmarks/grid_shift.py --real [--floor]   # the real validation rooms (../shared)

With `--held-out`, only the rooms the models hold out as their test rooms (the `held_out_test_rooms` their
files record; for the shipped models bench-data/accuracy, where `accuracy.py` generates their data set): the
rooms behind the models' figures in docs/accuracy.md. `--models DIR` maps with other model files (trained
with the settings of this process's environment, AFFORD_*).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
GENERATED = ROOT / "bench-data" / "grid-shift"


def shifts(step: float, theta_step: float) -> dict[str, tuple[float, float, float]]:
    """name: (dx, dy, turn in radians), all under one step of the grid."""
    return {
        "as given": (0.0, 0.0, 0.0),
        "+1/4 step": (step / 4, step / 4, 0.0),
        "+1/2 step": (step / 2, step / 2, 0.0),
        "+3/4 step": (3 * step / 4, step / 4, 0.0),
        "+1/2 turn": (0.0, 0.0, theta_step / 2),
        "-1/2 turn": (0.0, 0.0, -theta_step / 2),
    }


FLOOR_OFF = {  # name: (lift in metres, tilt in degrees about the x axis through the room's centre)
    "as given": (0.0, 0.0),
    "-3 cm": (-0.03, 0.0),
    "-1 cm": (-0.01, 0.0),
    "+1 cm": (0.01, 0.0),
    "+3 cm": (0.03, 0.0),
    "0.5 deg": (0.0, 0.5),
    "1 deg": (0.0, 1.0),
}


def floor_off(centre: np.ndarray, lift: float, tilt_deg: float) -> np.ndarray:
    """The room lifted by `lift` and tilted by `tilt_deg` about the x axis through `centre`."""
    angle = np.radians(tilt_deg)
    transform = np.eye(4)
    transform[1:3, 1:3] = [[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]]
    transform[:3, 3] = centre - transform[:3, :3] @ centre + np.array([0.0, 0.0, lift])
    return transform


def moved(step: float, theta_step: float) -> dict:
    """name: the transform of a room moved by one of `shifts`, given its centre."""
    return {
        name: (lambda centre, change=change: moved_by(centre, *change))
        for name, change in shifts(step, theta_step).items()
    }


def lifted() -> dict:
    """name: the transform of a room with its floor off by one of `FLOOR_OFF`, given its centre."""
    return {
        name: (lambda centre, change=change: floor_off(centre, *change)) for name, change in FLOOR_OFF.items()
    }


def moved_by(centre: np.ndarray, dx: float, dy: float, turn: float) -> np.ndarray:
    """The rigid transform turning by `turn` about the vertical through `centre`, then moving by (dx, dy)."""
    from affordcore.geometry.skeleton import rotation_z

    transform = np.eye(4)
    transform[:3, :3] = rotation_z(turn)
    transform[:3, 3] = centre - transform[:3, :3] @ centre + np.array([dx, dy, 0.0])
    return transform


def generated_rooms(count: int, seed: int) -> Path:
    """`count` rooms of every scan style and kind, made once (afford synth is resumable)."""
    command = [sys.executable, "-m", "affordcli", "synth", "--rooms", str(count), "--seed", str(seed)]
    subprocess.run(command + ["--out", str(GENERATED), "--quiet"], check=True, cwd=ROOT)
    return GENERATED


def room_places(
    cloud_path: Path,
    models: list,
    settings,
    named: dict,
    tolerances: dict | None = None,
    labels_path: Path | None = None,
) -> dict[str, dict[str, tuple]]:
    """{affordance: {shift: (found, labelled, false)}} for one room (`tolerances`: `match_places`' own, or
    other ones; `named`: name -> the room's transform, given its centre: `moved`'s or `lifted`'s)."""
    from affordcore.geometry.scene import load_cloud
    from affordcore.labels import load_labels, match_places
    from affordcore.mapping.pipeline import map_affordances, prepare_scene

    cloud = load_cloud(cloud_path)  # with the sensor positions of a <room>.origins.npy beside it
    labels = load_labels(labels_path or cloud_path.with_name(cloud_path.stem + ".labels.json"))
    centre = np.append(np.median(cloud.points[:, :2], axis=0), 0.0)
    found: dict[str, dict[str, tuple]] = {model.affordance: {} for model in models}
    for name, moving in named.items():
        transform = moving(centre)
        scene = prepare_scene(cloud.transformed(transform), settings, "none")
        moved = labels.moved(transform)
        for affordance, amap in map_affordances(scene.fields, scene.layout, models, settings).items():
            match = match_places(moved, affordance, amap.skeletons[:, [0, 1, 3]], **(tolerances or {}))
            found[affordance][name] = (int(match.found.sum()), len(match.found), int(match.false.sum()))
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rooms", type=Path, help="a folder of <room>.ply and <room>.labels.json")
    parser.add_argument("--generated", type=int, default=8, help="rooms to generate without --rooms")
    parser.add_argument("--seed", type=int, default=29, help="their seed (no model saw it)")
    parser.add_argument("--held-out", action="store_true", help="only the models' own test rooms")
    parser.add_argument("--models", type=Path, help="a folder of <affordance>.model.json (default: shipped)")
    parser.add_argument(
        "--loose", action="store_true", help="match places with DESIGN.md's loose tolerances (0.3 m, 0.5 rad)"
    )
    parser.add_argument("--real", action="store_true", help="the real validation rooms (real_rooms.py's)")
    parser.add_argument("--floor", action="store_true", help="the floor off by 1-3 cm or 0.5-1 deg instead")
    args = parser.parse_args()
    from affordcore.labels import LOOSE_TOLERANCES
    from affordcore.learn.model import load_model, models_in, shipped_models
    from affordcore.settings import Settings

    settings = Settings()
    if args.real:
        from real_rooms import REBUILT, VALIDATION

        from affordcore.learn.examples import labelled_rooms

        folder = VALIDATION[-1].parent
        rooms = [(cloud, labels) for _, cloud, labels in labelled_rooms([*VALIDATION, REBUILT])]
    else:
        folder = args.rooms or generated_rooms(args.generated, args.seed)
        rooms = [(cloud, None) for cloud in sorted(folder.glob("*.ply"))]
    files = models_in(args.models) if args.models else shipped_models()
    models = [load_model(path) for path in files.values()]
    if args.held_out:
        held_out = set(models[0].parameters["data"]["held_out_test_rooms"])
        rooms = [(path, labels) for path, labels in rooms if path.stem in held_out]
    if not rooms:
        among = " among the models' test rooms" if args.held_out else ""
        sys.exit(f"no <room>.ply in {folder}{among}")
    named = lifted() if args.floor else moved(settings.grid.step, settings.grid.theta_step)
    tolerances = LOOSE_TOLERANCES if args.loose else None
    how = "with its floor off" if args.floor else "moved by under one grid step"
    print(
        f"places found of labelled (+ false skeletons) with the room {how} "
        f"({len(rooms)} rooms of {folder.name}; step {settings.grid.step:g} m, theta step "
        f"{settings.grid.theta_step:g} rad; {os.cpu_count()} cores"
        + ("; places matched with the loose tolerances, 0.3 m and 0.5 rad" if args.loose else "")
        + ")\n"
    )
    print("| room | affordance | " + " | ".join(named) + " | spread of places found |")
    print("|---|---|" + "---:|" * len(named) + "---:|")
    totals = {model.affordance: {name: np.zeros(3, int) for name in named} for model in models}
    for path, labels in rooms:
        for affordance, by_shift in room_places(path, models, settings, named, tolerances, labels).items():
            counts = np.array([by_shift[name] for name in named])
            for name in named:
                totals[affordance][name] += by_shift[name]
            if counts[0, 1] == 0 and not counts[:, 2].any():
                continue  # nothing labelled and nothing found: no row
            print(f"| {path.stem} | {affordance} | {_cells(counts)} |")
    print("\nTotals per shift:\n")
    print("| affordance | " + " | ".join(named) + " | spread of places found |")
    print("|---|" + "---:|" * len(named) + "---:|")
    for affordance, by_shift in totals.items():
        print(f"| {affordance} | {_cells(np.array([by_shift[name] for name in named]))} |")


def _cells(counts: np.ndarray) -> str:
    """A table row's cells for (found, labelled, false) per shift, then the spread of the places found."""
    cells = " | ".join(f"{f}/{n} +{x}" for f, n, x in counts)
    return f"{cells} | {counts[:, 0].max() - counts[:, 0].min()}"


if __name__ == "__main__":
    main()
