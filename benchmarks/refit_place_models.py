"""Refit the shipped models' place models (their margins and cuts) on their own validation rooms and the real
validation rooms, with the present code, leaving the pose models untouched: training's calibration without
its pose threshold (`train.calibrate(..., pose=False)`), for a change in how candidates are found, matched or
cut that does not touch the poses' scores.

Reads the rooms each model file names as its validation rooms from `benchmarks/accuracy.py`'s data set, and
the real rooms from the folders `afford models rebuild --real` takes, and rewrites the model files in place
(`--out` writes them elsewhere); prints each place model's margin, cut and places before and after.

    .venv/bin/python benchmarks/refit_place_models.py --data bench-data/accuracy500 --out DIR   # 3 minutes
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from accuracy import REAL_ROOMS, ROOT  # noqa: E402  the real validation rooms the accuracy runs read


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=ROOT / "bench-data" / "accuracy")
    parser.add_argument(
        "--out", type=Path, help="write the model files here (default: over the shipped ones)"
    )
    parser.add_argument("--cache", type=Path, help="the room cache (default: learn.cache_dir)")
    args = parser.parse_args()

    from affordcore.geometry.features import FeatureLayout
    from affordcore.learn.cache import RoomCache
    from affordcore.learn.examples import Task, data_set_rooms, labelled_rooms, load_rooms
    from affordcore.learn.model import load_model, shipped_models
    from affordcore.learn.train import calibrate
    from affordcore.settings import Settings

    settings = Settings()
    layout = FeatureLayout.from_settings(settings)
    cache = RoomCache(args.cache) if args.cache else RoomCache.from_settings(settings)
    files = {f.name: f for f in data_set_rooms(args.data)}
    real = load_rooms(labelled_rooms([f for f in REAL_ROOMS if f.is_dir()]), settings, cache=cache)
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
    print(f"real rooms: {', '.join(room.name for room in real) or 'none'}\n")
    print("| affordance | margin, cut before | places before | margin, cut after | places after |")
    print("|---|---:|---|---:|---|")
    for name, path in shipped_models().items():
        model = load_model(path, layout)
        names = model.validation["rooms"]
        missing = [n for n in names if n not in files]
        if missing:
            raise SystemExit(f"{args.data}: no rooms {', '.join(missing[:3])}...: make the data set first")
        before = (model.places.eligible_margin, model.places.cut, _said(model.validation))
        rooms = load_rooms([files[n] for n in names], settings, cache=cache)
        calibrate(model, rooms, Task(name, settings, layout), pose=False, real=real)
        model.save((args.out or path.parent) / path.name)
        print(
            f"| {name} | {before[0]:g}, {before[1]:.2f} | {before[2]} | {model.places.eligible_margin:g}, "
            f"{model.places.cut:.2f} | {_said(model.validation)} |"
        )


def _said(validation: dict) -> str:
    keys = ("probability_place_recall", "probability_false_per_room")
    own = ", ".join(f"{k.removeprefix('probability_')} {validation[k]:.2f}" for k in keys if k in validation)
    real = validation.get("real") or {}
    if real:
        own += "; real: " + ", ".join(f"{k.removeprefix('probability_')} {real[k]:.2f}" for k in keys)
    return own


if __name__ == "__main__":
    main()
