"""The shipped models on the real validation rooms (../shared/data/rooms and ../shared/data/validation): per
room and per affordance, and in all.

For each room and each affordance: pose-level precision / recall / F1 at the model's threshold (DESIGN.md,
"Metrics"), the F1 an oracle threshold would reach on that room (how well the scores rank poses, apart from
where the threshold sits), place-level recall with the count of false skeletons, and each place's probability.
Then per affordance over every room, the false skeletons per room, and a reliability table of the place
probabilities (predicted against how often such a place matched a label). Figures of the maps with the
labels go to docs/figures/real-rooms/. Needs ../shared beside the project; the ScanNet meeting room's cloud,
which its terms keep out of ../shared, is read from --rebuilt (made by ../shared/data/rebuild/scannet0470.py)
and reported as not rebuilt when absent.

    .venv/bin/python benchmarks/real_rooms.py                         # about a minute on 2 cores
    .venv/bin/python benchmarks/real_rooms.py --gravity 0,0,-1        # levelled by a floor search under -z
    .venv/bin/python benchmarks/real_rooms.py --rooms DIR --figures none   # any folders of labelled clouds

With `--rooms`, any folder of `<room>.ply` beside `<room>.labels.json` (`afford synth`'s output) is scored the
same way (with the sensor positions of a `<room>.origins.npy` beside it, as `afford map` reads them);
`--models DIR` scores other model files than the shipped ones.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from affordcore.geometry.scene import load_cloud
from affordcore.labels import (
    THETA_TOLERANCE,
    XY_TOLERANCE,
    angle_gap,
    ground_truth,
    load_labels,
    match_places,
    place_matches,
)
from affordcore.learn.baselines import tune_threshold
from affordcore.learn.examples import labelled_rooms, missing_clouds
from affordcore.learn.model import load_model, models_in, shipped_models
from affordcore.learn.train import metrics
from affordcore.mapping.maps import RULED_OUT
from affordcore.mapping.pipeline import RoomMapper, parse_gravity, prepare_scene
from affordcore.mapping.places import above_threshold, place_candidates
from affordcore.mapping.plots import plot_map
from affordcore.settings import Settings

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
VALIDATION = [SHARED / "rooms", SHARED / "validation"]
REBUILT = Path(__file__).resolve().parents[1] / "bench-data" / "validation"
FIGURES = Path(__file__).resolve().parents[1] / "docs" / "figures" / "real-rooms"
BINS = np.array([0.0, 0.2, 0.4, 0.6, 0.8, 1.0])  # of the reliability table


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--gravity",
        default="none",
        help="none: the rooms are z-up already; auto: find the floor as for any cloud; X,Y,Z: gravity given",
    )
    parser.add_argument("--rooms", type=Path, action="append", help="a folder of <room>.ply and its labels")
    parser.add_argument("--rebuilt", type=Path, default=REBUILT, help="where rebuilt clouds are (ScanNet's)")
    parser.add_argument("--models", type=Path, help="a folder of <affordance>.model.json (default: shipped)")
    parser.add_argument("--figures", default=str(FIGURES), help="where the plan views go; none: no figures")
    args = parser.parse_args()
    folders = args.rooms or VALIDATION
    missing = [folder for folder in folders if not folder.is_dir()]
    if missing:
        sys.exit(f"{', '.join(map(str, missing))} not found: this report needs labelled rooms (../shared)")
    figures = None if args.figures == "none" else Path(args.figures)
    settings = Settings()
    files = models_in(args.models) if args.models else shipped_models()
    models = {name: load_model(path) for name, path in files.items()}
    if figures is not None:
        figures.mkdir(parents=True, exist_ok=True)
    gravity = parse_gravity(args.gravity)
    totals = {name: np.zeros(3, np.int64) for name in models}  # places found, labelled, false skeletons
    false_per_room, calibration = {}, []  # (probability, matched a label) of every place
    why: list[str] = []  # a row per place missed and per false skeleton: where, and which step lost it
    print(f"gravity {args.gravity}\n")
    print(
        "| room | affordance | labels | positive poses | P / R / F1 at the threshold "
        "| oracle-threshold F1 | places found | false skeletons | probabilities of the places |"
    )
    print("|---|---|---:|---:|---|---:|---:|---:|---|")
    for name in missing_clouds([*folders, args.rebuilt]):
        print(f"| {'_'.join(name.split('_')[:2])} | (not rebuilt: ../shared/data/rebuild) | | | | | | | |")
    for name, cloud_path, labels_path in labelled_rooms([*folders, args.rebuilt]):
        short = "_".join(name.split("_")[:2])
        labels = load_labels(labels_path)
        scene = prepare_scene(load_cloud(cloud_path), settings, gravity)
        labels = labels.moved(scene.alignment.world_from_input)
        # every affordance in every room: a skeleton where the room labels none of its affordance is false
        chosen = list(models.values())
        mapper = RoomMapper(chosen, scene.layout, settings)
        maps = mapper.maps(scene.fields)
        false_per_room[short] = 0
        for model in chosen:
            amap = maps[model.affordance]
            truth = ground_truth(
                labels, model.affordance, amap.grid, torso_height=model.as_skeleton().torso_height
            )
            scored = truth.scored_mask().ravel()
            y = np.where(truth.pose_mask().ravel()[scored], 1, -1)
            scores = amap.scores.ravel()[scored]  # as the map scored them (scanned floor only)
            at = metrics(scores, y, model.threshold)
            oracle = tune_threshold(scores, y)[1] if (y > 0).any() else 0.0
            places = match_places(labels, model.affordance, amap.skeletons[:, [0, 1, 3]])
            print(
                f"| {short} | {model.affordance} | {len(labels.of(model.affordance))} | "
                f"{at['positives']:,} | "
                f"{at['precision']:.2f} / {at['recall']:.2f} / {at['f1']:.2f} | {oracle:.2f} | "
                f"{int(places.found.sum())} / {len(places.found)} | {int(places.false.sum())} | "
                f"{', '.join(amap.place_labels()) or '-'} |"
            )
            totals[model.affordance] += [places.found.sum(), len(places.found), places.false.sum()]
            false_per_room[short] += int(places.false.sum())
            why += explain(short, labels, model, amap, places, mapper.scanned[model.affordance], settings)
            kept = ~places.ignored  # a place in an unlabelled region is neither found nor false
            calibration += list(zip(amap.probabilities[kept], ~places.false[kept]))
            if figures is not None and cloud_path.parent != args.rebuilt:  # a rebuilt room's data stays out
                plot_map(scene.cloud.points, amap, figures / f"{short}-{model.affordance}.png", labels=labels)
    rooms = len(false_per_room)
    for name, (found, labelled, false) in totals.items():
        print(f"| all {rooms} rooms | {name} | {labelled} | | | | {found} / {labelled} | {false} | |")
    print(
        "\nfalse skeletons per room (every affordance): "
        + ", ".join(f"{r} {n}" for r, n in false_per_room.items())
    )
    _reliability(calibration)
    print("\n| room | affordance | place | where (x, y, facing) | lost at |\n|---|---|---|---|---|")
    print("\n".join(why))


def explain(short: str, labels, model, amap, places, scanned, settings: Settings) -> list[str]:
    """Which step lost each labelled place the map missed, and what each false skeleton is: the pose scores
    (no pose on the label beats the threshold), the candidates (no candidate peak on the label: a stronger
    neighbour's took its cell), or the place model (a candidate on it, below the cut); a false skeleton is a
    candidate the place model put above the cut."""
    rows = []
    grid, threshold = amap.grid, model.threshold
    margin = model.places.eligible_margin if model.places else 0.0  # how far under it a place may peak
    chosen = labels.of(model.affordance)
    spacing = model.places.candidate_spacing if model.places else 0.25
    candidates = place_candidates(amap.scores, grid, threshold, spacing, scanned)
    probabilities = model.places.probability(candidates.evidence) if model.places else candidates.rows[:, 4]
    cut = place_cut(model, settings)
    eligible = (model.places.eligible if model.places else above_threshold)(candidates.rows, threshold)
    on_label, _ = place_matches(labels, model.affordance, candidates.rows[:, [0, 1, 3]])  # as the map matches
    for label, found, near in zip(chosen, places.found, on_label):
        if found:
            continue
        best = _best_pose(amap.scores, grid, label)
        if best == float("-inf"):
            lost = "fields: no pose on it is scored (its cells were never seen, nor a surface over them)"
        elif best <= threshold - margin:
            under = f"the threshold {threshold:.2f}" + (f" less the margin {margin:.2f}" if margin else "")
            lost = f"pose scores: the best pose on it scores {best:.2f}, under {under}"
        elif not (near & eligible).any():
            peaks = candidates.rows[eligible]
            off = label.distance(peaks[:, :2])
            turned = np.degrees(angle_gap(peaks[off.argmin(), 3], label.facing)) if len(peaks) else 0.0
            nearest = (
                f"; the nearest candidate peak stands {off.min():.2f} m off, facing {turned:.0f} deg off"
                if len(peaks)
                else ""
            )
            lost = f"candidates: a pose on it scores {best:.2f}, but no candidate peak is on it{nearest}"
        else:
            top = probabilities[near & eligible].max()
            lost = f"place model: its candidate's probability {top:.2f} is under the cut {cut:.2f}"
        rows.append(
            f"| {short} | {model.affordance} | missed: {_short(label.note)} | {_where(label)} | {lost} |"
        )
    for skeleton, false, probability in zip(amap.skeletons, places.false, amap.probabilities):
        if false:
            x, y, theta = skeleton[0], skeleton[1], skeleton[3]
            rows.append(
                f"| {short} | {model.affordance} | false, p {probability:.2f} | ({x:.2f}, {y:.2f}, "
                f"{np.degrees(theta):.0f} deg) | place model: a candidate above the cut {cut:.2f} |"
            )
    return rows


def place_cut(model, settings: Settings) -> float:
    """The probability a place must reach (the place model's cut, or the setting over it)."""
    chosen = settings.map.place_probability
    return chosen if chosen is not None else (model.places.cut if model.places else float("nan"))


def _best_pose(scores: np.ndarray, grid, label) -> float:
    """The best score of a pose within DESIGN.md's tolerance of a label (any z level)."""
    xx, yy = np.meshgrid(grid.x, grid.y, indexing="ij")
    near_xy = label.distance(np.column_stack([xx.ravel(), yy.ravel()])).reshape(xx.shape) <= XY_TOLERANCE
    near_theta = angle_gap(grid.theta, label.facing) <= THETA_TOLERANCE
    on = scores[:, near_theta][:, :, near_xy]
    on = on[on > RULED_OUT]
    return float(on.max()) if on.size else float("-inf")


def _short(note: str | None) -> str:
    """A label's note, its first clause (without the labeller's confidence)."""
    import re

    text = re.sub(r"\[confidence:[^\]]*\]\s*", "", note or "labelled place")
    return text.split(":")[0].split(";")[0].split("(")[0].strip()[:60]


def _where(label) -> str:
    """A label's middle in plan, and its facing."""
    ends = [label.at] if label.at is not None else [label.start, label.end]
    x, y = np.mean(np.array(ends, dtype=float), axis=0)
    return f"({x:.2f}, {y:.2f}, {np.degrees(label.facing):.0f} deg)"


def _reliability(calibration: list[tuple[float, bool]]) -> None:
    """Predicted probability against how often a place of that probability matched a label."""
    pairs = np.array([(p, m) for p, m in calibration if np.isfinite(p)], dtype=np.float64).reshape(-1, 2)
    print("\n| place probability | places | matched a label | observed frequency |\n|---|---:|---:|---:|")
    for low, high in zip(BINS[:-1], BINS[1:]):
        inside = (pairs[:, 0] >= low) & ((pairs[:, 0] < high) | (high == BINS[-1]))
        count, matched = int(inside.sum()), int(pairs[inside, 1].sum())
        observed = f"{matched / count:.2f}" if count else "-"
        print(f"| {low:.1f}-{high:.1f} | {count} | {matched} | {observed} |")


if __name__ == "__main__":
    main()
