"""Which places the scans show: the shipped models' place recall on the generated test rooms,
split by how much of each labelled place's body the sensors saw.

A place's body is where a person using it would be: the 15 joints of its affordance's skeleton at the label
(a segment's middle). Each lies in a voxel the room's sensor positions saw (free or occupied) or never saw
(unknown, docs/geometry.md); a place is *seen* when at most a quarter of its joints are in unknown voxels
and *hidden* when more than half are: a chair behind a table seen from across the room, a seat under a top.
Places found of labelled, per scan style and affordance, for each kind; then, of the places missed, those the
pose scores saw (a pose above the model's threshold within DESIGN.md's place tolerance of the label: the
place step lost them) and those they did not. Last, the places at desks and tables by the state their chair
was generated in (the label's note, docs/synthetic-rooms.md "Table scenes"): a place is labelled whatever its
chair's state, with no chair at all too.

Reads the data set of `benchmarks/accuracy.py` and its test rooms (`learn.defaults`' split), each with its
``<room>.origins.npy``; the real rooms carry no sensor positions and are not in it.

    .venv/bin/python benchmarks/studies/are_missed_places_hidden_from_the_scans.py   # 5 min, 2 cores
"""

from __future__ import annotations

import argparse
import os
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from which_place_evidence_survives_a_scan_change import (  # noqa: E402  (the shipped models' split)
    STYLES,
    add_split_arguments,
    shipped_split,
)

SEEN, HIDDEN = 0.25, 0.5  # unknown shares at most (seen) and above (hidden)
KINDS = ("seen", "partly seen", "hidden")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_split_arguments(parser)
    args = parser.parse_args()
    places = collect(args)
    print(f"{os.cpu_count()} cores; {len(places)} labelled places in the test rooms")
    print_recall(places)


def collect(args) -> list[dict]:
    """Every labelled place of the test rooms: its style, affordance, whether the shipped maps found it, and
    the unknown share of its joints."""
    from affordcore.geometry.scene import load_cloud
    from affordcore.labels import load_labels, match_places
    from affordcore.learn.model import load_model, shipped_models
    from affordcore.mapping.pipeline import map_affordances, prepare_scene
    from affordcore.settings import Settings

    settings = Settings()
    models = [load_model(path) for path in shipped_models().values()]
    files, part, style = shipped_split(args)
    places = []
    for name in (n for n, where in part.items() if where == "test"):
        labels = load_labels(files[name].labels)
        scene = prepare_scene(load_cloud(files[name].cloud), settings, "none")
        if scene.fields.visibility is None:
            print(f"{name}: no sensor positions, left out", file=sys.stderr)
            continue
        maps = map_affordances(scene.fields, scene.layout, models, settings)
        for model in models:
            amap = maps[model.affordance]
            found = match_places(labels, model.affordance, amap.skeletons[:, [0, 1, 3]]).found
            for label, hit in zip(labels.of(model.affordance), found):
                places.append(
                    {
                        "style": style[name],
                        "affordance": model.affordance,
                        "found": bool(hit),
                        "unknown": unknown_share(scene.fields, model.as_skeleton(), label),
                        "scored": best_score_at(amap, label) > model.threshold,
                        "chair": chair_state(label.note),
                    }
                )
        print(f"{name} ({style[name]}) done", file=sys.stderr, flush=True)
    return places


def unknown_share(fields, skeleton, label) -> float:
    """The share of the joints of `skeleton` at `label` (a segment's middle) in voxels no sensor saw."""
    from affordcore.geometry.skeleton import place_joints
    from affordcore.geometry.visibility import UNKNOWN

    xy = np.asarray(label.at if label.at is not None else np.add(label.start, label.end) / 2, float)
    torso = label.z if label.z is not None else skeleton.torso_height
    joints = place_joints(skeleton.joints, np.array([[xy[0], xy[1], torso, label.facing]]))[0]
    voxels = fields.lattice.voxel_of(joints)
    inside = np.all((voxels >= 0) & (voxels < np.array(fields.lattice.shape)), axis=1)
    unknown = np.ones(len(joints), bool)  # beyond the lattice nothing was seen
    unknown[inside] = fields.visibility[tuple(voxels[inside].T)] == UNKNOWN
    return float(unknown.mean())


def best_score_at(amap, label) -> float:
    """The best score of the poses a skeleton at `label` would match (DESIGN.md's place tolerance)."""
    from affordcore.labels import THETA_TOLERANCE, XY_TOLERANCE, angle_gap

    grid = amap.grid
    near = label.distance(np.stack(np.meshgrid(grid.x, grid.y, indexing="ij"), axis=-1)) <= XY_TOLERANCE
    turned = angle_gap(grid.theta, label.facing) <= THETA_TOLERANCE
    scores = amap.scores[:, turned][:, :, near]
    return float(scores.max()) if scores.size else -np.inf


# the phrases `furniture._chair_note` writes into a table place's label note, the most specific first (they
# name the states of `furniture.CHAIR_STATES`; a pushed-in chair may be in as far as it goes)
CHAIR_NOTES = ("as far as it goes", "pushed in", "pulled out", "turned", "no chair")
SHARED_TABLES = ("meeting table", "dining table")  # tables of several places, as against a desk or a bar


def chair_state(note: str) -> str | None:
    """The chair's state a table place's label note names, with where for a missing chair: "no chair at a
    shared table" apart from "no chair at a desk or bar" (a desk's knee space shows where its place is, an
    empty stretch of a meeting table's edge does not); None for a place at no table."""
    state = next((s for s in CHAIR_NOTES if s in note), None)
    if state == "no chair":
        return state + (" at a shared table" if note.startswith(SHARED_TABLES) else " at a desk or bar")
    return state


def kind(unknown: float) -> str:
    return KINDS[0] if unknown <= SEEN else KINDS[2] if unknown > HIDDEN else KINDS[1]


def print_recall(places: list[dict]) -> None:
    """Places found of labelled per affordance, scan style and kind."""
    print(
        f"\nPlaces found of labelled: seen (<= {SEEN:.0%} of the joints unknown) / partly seen / hidden "
        f"(> {HIDDEN:.0%} unknown)\n"
    )
    print("| affordance | " + " | ".join(STYLES) + " | all |")
    print("|---|" + "---|" * (len(STYLES) + 1))
    for affordance in sorted({p["affordance"] for p in places}):
        cells = []
        for style in (*STYLES, None):
            chosen = [p for p in places if p["affordance"] == affordance and style in (None, p["style"])]
            counts = defaultdict(lambda: [0, 0])
            for p in chosen:
                counts[kind(p["unknown"])][0] += p["found"]
                counts[kind(p["unknown"])][1] += 1
            cells.append(" / ".join(f"{counts[k][0]}/{counts[k][1]}" for k in KINDS))
        print(f"| {affordance} | " + " | ".join(cells) + " |")
    print(
        "\nPlaces missed: with a pose above the threshold at the label (lost by the place step) / without\n"
    )
    print("| affordance | " + " | ".join(KINDS) + " | all |")
    print("|---|" + "---|" * (len(KINDS) + 1))
    for affordance in sorted({p["affordance"] for p in places}):
        missed = [p for p in places if p["affordance"] == affordance and not p["found"]]
        cells = []
        for chosen in [[p for p in missed if kind(p["unknown"]) == k] for k in KINDS] + [missed]:
            scored = sum(p["scored"] for p in chosen)
            cells.append(f"{scored} / {len(chosen) - scored}")
        print(f"| {affordance} | " + " | ".join(cells) + " |")
    print_chairs(places)


def print_chairs(places: list[dict]) -> None:
    """Places at desks and tables found of labelled by their chair's state; of those missed, how many the
    pose scores saw (a positive pose at the label)."""
    chaired = [p for p in places if p["chair"] is not None]
    if not chaired:
        return
    print("\nPlaces at desks and tables by their chair's state: found / labelled (missed, a pose positive)\n")
    print("| affordance | chair | " + " | ".join(STYLES) + " | all |")
    print("|---|---|" + "---|" * (len(STYLES) + 1))
    for affordance in sorted({p["affordance"] for p in chaired}):
        for state in sorted({p["chair"] for p in chaired if p["affordance"] == affordance}):
            cells = []
            for style in (*STYLES, None):
                chosen = [
                    p
                    for p in chaired
                    if p["affordance"] == affordance and p["chair"] == state and style in (None, p["style"])
                ]
                found = sum(p["found"] for p in chosen)
                lost = sum(p["scored"] and not p["found"] for p in chosen)
                cells.append(f"{found}/{len(chosen)} ({lost})" if chosen else "-")
            print(f"| {affordance} | {state} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
