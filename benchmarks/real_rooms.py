"""The shipped models on the real rooms with hand-made labels (../shared/data/rooms): the report of issue 5.

For each room and each affordance it labels: pose-level precision / recall / F1 at the model's threshold
(DESIGN.md, "Metrics"), the F1 an oracle threshold would reach on that room (how well the scores rank poses,
apart from where the threshold sits), and place-level recall with the count of false skeletons. Figures of
the maps with the labels go to docs/figures/real-rooms/. Needs ../shared beside the project.

    .venv/bin/python benchmarks/real_rooms.py            # about a minute on 2 cores
    .venv/bin/python benchmarks/real_rooms.py --rooms DIR --figures none   # any folder of labelled clouds

With `--rooms`, any folder of `<room>.ply` beside `<room>.labels.json` (`afford synth`'s output) is scored the
same way (with the sensor positions of a `<room>.origins.npy` beside it, as `afford map` reads them), with
each affordance's totals at the end; `--models DIR` scores other model files than the shipped ones.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from affordcore.geometry.scene import load_cloud
from affordcore.labels import ground_truth, load_labels, match_places
from affordcore.learn.baselines import tune_threshold
from affordcore.learn.model import load_model, models_in, shipped_models
from affordcore.learn.train import metrics
from affordcore.mapping.pipeline import map_affordances, prepare_scene
from affordcore.mapping.plots import plot_map
from affordcore.settings import Settings

ROOMS = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "rooms"
FIGURES = Path(__file__).resolve().parents[1] / "docs" / "figures" / "real-rooms"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--gravity",
        default="none",
        help="none: the rooms are z-up already; auto: find the floor as for any cloud",
    )
    parser.add_argument("--rooms", type=Path, default=ROOMS, help="a folder of <room>.ply and its labels")
    parser.add_argument("--models", type=Path, help="a folder of <affordance>.model.json (default: shipped)")
    parser.add_argument("--figures", default=str(FIGURES), help="where the plan views go; none: no figures")
    args = parser.parse_args()
    if not args.rooms.is_dir():
        where = "../shared/data/rooms beside the project" if args.rooms == ROOMS else "labelled rooms"
        sys.exit(f"{args.rooms} not found: this report needs {where}")
    figures = None if args.figures == "none" else Path(args.figures)
    settings = Settings()
    files = models_in(args.models) if args.models else shipped_models()
    models = {name: load_model(path) for name, path in files.items()}
    if figures is not None:
        figures.mkdir(parents=True, exist_ok=True)
    totals = {name: np.zeros(3, np.int64) for name in models}  # places found, labelled, false skeletons
    print(
        "| room | affordance | labels | positive poses | P / R / F1 at the threshold "
        "| oracle-threshold F1 | places found | false skeletons | probabilities of the places |"
    )
    print("|---|---|---:|---:|---|---:|---:|---:|---|")
    for cloud_path in sorted(args.rooms.glob("*.ply")):
        labels = load_labels(cloud_path.with_name(cloud_path.stem + ".labels.json"))
        scene = prepare_scene(load_cloud(cloud_path), settings, args.gravity)
        # every affordance in every room: a skeleton where the room labels none of its affordance is false
        chosen = list(models.values())
        maps = map_affordances(scene.fields, scene.layout, chosen, settings)
        short = cloud_path.stem.split("_")[0]
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
            if figures is not None:
                plot_map(scene.cloud.points, amap, figures / f"{short}-{model.affordance}.png", labels=labels)
    rooms = len(list(args.rooms.glob("*.ply")))
    for name, (found, labelled, false) in totals.items():
        print(f"| all {rooms} rooms | {name} | {labelled} | | | | {found} / {labelled} | {false} | |")


if __name__ == "__main__":
    main()
