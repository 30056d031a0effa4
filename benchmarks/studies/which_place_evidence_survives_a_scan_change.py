"""Which place evidence survives a change of scan: place models fitted on the validation rooms of some scan
styles and tested on the test rooms of the others, for variants of the evidence.

The real rooms are a test set, so the shift between generated and real scans cannot be tuned on. The scan
styles give a shift of the same kind inside generated data: fused depth frames, meshes and laser scans see a
room whole, raw frames and walks see it from one side. A place model whose evidence survives fitting on the
one and testing on the other is the one to trust on a scan nobody generated. Variants:

* all: every `places.EVIDENCE` column (the shipped place models);
* no-score: without the peak's own score, the column a score shift moves most;
* relative: only what is counted from the room itself (margin over the median, below the best, rank, support
  near the peak, scanned share).

Reads the data set and the shipped models of `benchmarks/accuracy.py` (the last 96 rooms: 48 validation, 48
test, as `learn.defaults` splits them); prints places found at probability 0.5, false skeletons per room and
the log-loss per candidate.

Then the place cut (`learn.thresholds.place_cut`): the shipped place models refitted on every validation room
(the same fit as training's), each cut chosen under a budget of false places per validation room, judged on
the test rooms per scan style and on the real rooms (../shared/data/rooms, a test set: never fitted on).

    .venv/bin/python benchmarks/studies/which_place_evidence_survives_a_scan_change.py   # 6 min, 2 cores
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np

from affordcore.synth.styles import STYLES as SCAN_STYLES

ROOT = Path(__file__).resolve().parents[2]
REAL_ROOMS = ROOT.parent / "shared" / "data" / "rooms"
DENSE, SPARSE = {"fused", "mesh", "laser"}, {"frames", "walk", "sweep"}
SPLITS = {
    "dense -> sparse": (DENSE, SPARSE),
    "sparse -> dense": (SPARSE, DENSE),
    "all -> all": (DENSE | SPARSE,) * 2,
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_split_arguments(parser)
    args = parser.parse_args()
    from affordcore.mapping.places import EVIDENCE

    candidates = collect(args)
    variants = {
        "all": list(range(len(EVIDENCE))),
        "no-score": [i for i, name in enumerate(EVIDENCE) if name != "score"],
        "relative": [
            EVIDENCE.index(n) for n in ("over_median", "below_best", "rank", "near_peak", "scanned")
        ],
    }
    print(
        f"{os.cpu_count()} cores; places found at p >= 0.5, false skeletons per room, log-loss per candidate"
    )
    print("| affordance | fitted on -> tested on | " + " | ".join(variants) + " |")
    print("|---|---|" + "---|" * len(variants))
    for affordance in sorted({c["affordance"] for c in candidates}):
        for split, (fit_styles, test_styles) in SPLITS.items():
            cells = [
                evaluate(candidates, affordance, fit_styles, test_styles, columns)
                for columns in variants.values()
            ]
            print(f"| {affordance} | {split} | " + " | ".join(cells) + " |")
    print_cuts(candidates)


BUDGETS = (0.2, 0.4, 0.6, 1.0)  # false places per validation room
STYLES = tuple(SCAN_STYLES)  # the generator's, in the order `afford synth` deals them


def print_cuts(candidates: list[dict]) -> None:
    """Places found / labels and false skeletons per room, on the test rooms (all, each style) and the real
    rooms, at a fixed 0.5 and at the cut each budget chooses on the validation rooms."""
    from affordcore.learn.thresholds import _fit_on, place_cut

    print("\nplace cuts: places found, false skeletons per room (cut chosen on the validation rooms)")
    groups = {"test": ("test", None), **{s: ("test", s) for s in STYLES}, "real": ("real", None)}
    print("| affordance | budget | cut | " + " | ".join(groups) + " |")
    print("|---|---|---|" + "---|" * len(groups))
    for affordance in sorted({c["affordance"] for c in candidates}):
        mine = [c for c in candidates if c["affordance"] == affordance]
        validation = [c["candidates"] for c in mine if c["part"] == "validation"]
        model = _fit_on(validation)
        for budget in (None, *BUDGETS):
            cut = 0.5 if budget is None else place_cut(validation, budget, 0.45)
            cells = []
            for part, style in groups.values():
                rooms = [c["candidates"] for c in mine if c["part"] == part and style in (None, c["style"])]
                found, _, false = np.sum(
                    [c.places(model.probability(c.evidence), cut, 0.45) for c in rooms], axis=0
                )
                labels = sum(c.matches.shape[0] for c in rooms)
                cells.append(f"{found}/{labels}, {false / max(1, len(rooms)):.2f}")
            label = "fixed" if budget is None else f"{budget}"
            print(f"| {affordance} | {label} | {cut:.2f} | " + " | ".join(cells) + " |")


def add_split_arguments(parser: argparse.ArgumentParser) -> None:
    """The data set of `benchmarks/accuracy.py` and the shipped models' split of its first rooms (by default
    the split `afford models rebuild` trains on, `learn.defaults`)."""
    from affordcore.learn.defaults import ROOMS, TEST, VALIDATION

    parser.add_argument("--data", type=Path, default=ROOT / "bench-data" / "accuracy")
    parser.add_argument("--rooms", type=int, default=ROOMS, help="the data set's first rooms")
    parser.add_argument("--validation", type=int, default=VALIDATION)
    parser.add_argument("--test", type=int, default=TEST)


def shipped_split(args) -> tuple[dict, dict[str, str], dict[str, str]]:
    """(the room files by name, "validation" or "test" by name, validation rooms first, the scan style by
    name) of the shipped models' split of the data set (`add_split_arguments`)."""
    from affordcore.learn.defaults import split_by_index
    from affordcore.learn.examples import data_set_rooms

    style = {r["room"]: r["style"] for r in json.loads((args.data / "summary.json").read_text())["rooms"]}
    ordered = sorted(data_set_rooms(args.data), key=lambda files: int(files.name.rsplit("-", 1)[1]))
    files = {f.name: f for f in ordered[: args.rooms]}
    _, validation, test = split_by_index(list(files), args.validation, args.test)
    part = {**{n: "validation" for n in validation}, **{n: "test" for n in test}}
    return files, part, style


def collect(args) -> list[dict]:
    """Every candidate place of the validation and test rooms under the shipped models, with its evidence."""
    from affordcore.geometry.features import FeatureLayout
    from affordcore.learn.examples import data_set_rooms, load_rooms
    from affordcore.learn.model import load_model, shipped_models
    from affordcore.learn.thresholds import room_scores
    from affordcore.settings import Settings

    settings = Settings()
    layout = FeatureLayout.from_settings(settings)
    files, part, style = shipped_split(args)
    rooms = load_rooms([files[n] for n in part], settings)
    if REAL_ROOMS.is_dir():  # a test set: scored and reported, never fitted or chosen on
        real = load_rooms(data_set_rooms(REAL_ROOMS), settings)
        part.update({r.name: "real" for r in real})
        style.update({r.name: "real" for r in real})
        rooms += real
    found = []
    for name, path in shipped_models().items():
        model = load_model(path, layout)
        for room in rooms:
            scored = room_scores(model, room, layout, settings)
            c = scored.model_candidates(model)
            found.append(
                {"affordance": name, "style": style[room.name], "part": part[room.name], "candidates": c}
            )
    return found


def evaluate(candidates: list[dict], affordance: str, fit_styles, test_styles, columns: list[int]) -> str:
    """Place model of the `columns` of the evidence, fitted on the validation rooms of `fit_styles`, on the
    test rooms of `test_styles`. The other columns are held at 0: constant, they weigh nothing, and the place
    model stays the shipped one's code (`places.fit_place_model`)."""
    from affordcore.mapping.places import fit_place_model

    def chosen(part, styles):
        return [
            c["candidates"]
            for c in candidates
            if c["affordance"] == affordance and c["part"] == part and c["style"] in styles
        ]

    def kept(evidence: np.ndarray) -> np.ndarray:
        only = np.zeros_like(evidence)
        only[:, columns] = evidence[:, columns]
        return only

    fit = chosen("validation", fit_styles)
    used = np.concatenate([c.used[~c.ignored] for c in fit])
    if used.all() or not used.any():
        return "-"
    model = fit_place_model(np.concatenate([kept(c.evidence[~c.ignored]) for c in fit]), used)
    tested = chosen("test", test_styles)
    found = labels = false = 0
    losses = []
    for c in tested:
        p = model.probability(kept(c.evidence))
        f, _, fa = c.places(p, 0.5, 0.45)
        found, labels, false = found + f, labels + c.matches.shape[0], false + fa
        counted = np.clip(p[~c.ignored], 1e-6, 1 - 1e-6)
        truth = c.used[~c.ignored]
        losses.append(-(truth * np.log(counted) + ~truth * np.log(1 - counted)))
    return f"{found}/{labels}, {false / max(1, len(tested)):.1f}, {np.concatenate(losses).mean():.3f}"


if __name__ == "__main__":
    main()
