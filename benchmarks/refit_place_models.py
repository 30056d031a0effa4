"""Refit the shipped models' place models (and their cuts) on their own validation rooms, with the present
code's candidates, leaving the pose models untouched: what training's last step does (`learn.train`), for a
change in how candidates are found or matched that does not touch the poses' scores.

Reads the rooms each model file names as its validation rooms from `benchmarks/accuracy.py`'s data set and
rewrites the model files in place (`--out` writes them elsewhere); prints each place model's cut and its
places on those rooms before and after.

    .venv/bin/python benchmarks/refit_place_models.py        # about 5 minutes on 2 cores
"""

from __future__ import annotations

import argparse
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=ROOT / "bench-data" / "accuracy")
    parser.add_argument(
        "--out", type=Path, help="write the model files here (default: over the shipped ones)"
    )
    args = parser.parse_args()

    from affordcore.geometry.features import FeatureLayout
    from affordcore.learn.examples import data_set_rooms, load_rooms
    from affordcore.learn.model import load_model, shipped_models
    from affordcore.learn.thresholds import fit_places, room_scores
    from affordcore.learn.train import place_model_report
    from affordcore.settings import Settings

    settings = Settings()
    layout = FeatureLayout.from_settings(settings)
    files = {f.name: f for f in data_set_rooms(args.data)}
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
    print("| affordance | cut before | places before | cut after | places after |")
    print("|---|---:|---|---:|---|")
    for name, path in shipped_models().items():
        model = load_model(path, layout)
        names = model.validation["rooms"]
        missing = [n for n in names if n not in files]
        if missing:
            raise SystemExit(f"{args.data}: no rooms {', '.join(missing[:3])}...: make the data set first")
        scored = [
            room_scores(model, room, layout, settings)
            for room in load_rooms([files[n] for n in names], settings)
        ]
        before = place_model_report(scored, model, settings)
        cut_before = model.places.cut
        place_model = fit_places(
            scored, model.threshold, settings.learn.place_false_budget, settings.map.nms_radius
        )
        model.place_model = place_model.to_dict()
        after = place_model_report(scored, model, settings)
        model.validation.update(after)
        model.save((args.out or path.parent) / path.name)
        print(f"| {name} | {cut_before:.2f} | {_said(before)} | {model.places.cut:.2f} | {_said(after)} |")


def _said(report: dict) -> str:
    return ", ".join(
        f"{k} {v:.2f}" if isinstance(v, float) else f"{k} {v}" for k, v in sorted(report.items())
    )


if __name__ == "__main__":
    main()
