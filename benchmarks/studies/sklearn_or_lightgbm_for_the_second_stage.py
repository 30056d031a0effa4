"""Benchmark: the cascade's second stage fitted by scikit-learn's HistGradientBoostingClassifier (what
`affordcore.learn.cascade.fit_trees` uses) against LightGBM's LGBMClassifier at equal settings.

For each affordance, the first stage (`linear-tuned`) is fitted on the training rooms' examples as training
does (`room_examples`, then `stack` at `learn.max_negatives`); `second_stage_examples` then gives the rows the
trees see, for the training rooms and separately for held-out test rooms (fraction `learn.rescore_fraction`,
at most `learn.rescore_max_poses` a room, as `fit_cascade` calls it). Both libraries get `TreeSettings`'
defaults (150 iterations, lr 0.1, 31 leaves, depth 8, 40 rows a leaf, l2 1.0) and the same sample weights
(positives up-weighted to a 25 % share, as in `fit_trees`), on one thread. Reported: fit seconds (median of
--repeats fits, the estimator's `fit` only), prediction seconds for the test rows (median), and test average
precision (`average_precision_score` weighted by the examples' weights).

Rooms come from the generated data set in bench-data/accuracy (never the real rooms). Run from the repository
root (about 10 minutes on one core):

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/studies/sklearn_or_lightgbm_for_the_second_stage.py
    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/studies/sklearn_or_lightgbm_for_the_second_stage.py \
        --train 0-39 --test 110-125 --affordance standing-working --affordance sitting-relaxing

Needs lightgbm (not a project dependency): .venv/bin/pip install lightgbm==4.7.0
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

import numpy as np
from lightgbm import LGBMClassifier
from sklearn.metrics import average_precision_score

from affordcore.geometry.features import FeatureLayout
from affordcore.learn.cascade import (
    TreeSettings,
    second_stage_examples,
    tree_classifier,
    tree_sample_weights,
)
from affordcore.learn.examples import Task, data_set_rooms, load_rooms, room_examples, stack
from affordcore.learn.learners import get_learner
from affordcore.settings import Settings


def room_range(text: str) -> range:
    first, _, last = text.partition("-")
    return range(int(first), int(last or first) + 1)


def models(trees: TreeSettings, seed: int) -> dict:
    return {
        "sklearn HGB": lambda: tree_classifier(trees, seed),  # what the cascade fits
        "LightGBM": lambda: LGBMClassifier(
            n_estimators=trees.max_iter,
            learning_rate=trees.learning_rate,
            num_leaves=trees.max_leaf_nodes,
            max_depth=trees.max_depth,
            min_child_samples=trees.min_samples_leaf,
            reg_lambda=trees.l2_regularization,
            random_state=seed,
            num_threads=1,
            verbose=-1,
        ),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(ROOT / "bench-data" / "accuracy"))
    parser.add_argument("--train", default="0-39", help="training rooms, by the number ending their name")
    parser.add_argument("--test", default="110-125", help="held-out rooms, by the number ending their name")
    parser.add_argument("--affordance", action="append", help="default: standing-working, sitting-relaxing")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    affordances = args.affordance or ["standing-working", "sitting-relaxing"]

    settings = Settings(learn={"workers": 1})
    trees = TreeSettings()
    files = sorted(data_set_rooms(args.data), key=lambda f: int(re.search(r"(\d+)$", f.name).group(1)))
    number = {f.name: int(re.search(r"(\d+)$", f.name).group(1)) for f in files}
    train_files = [f for f in files if number[f.name] in room_range(args.train)]
    test_files = [f for f in files if number[f.name] in room_range(args.test)]
    start = time.perf_counter()
    train_rooms, test_rooms = load_rooms(train_files, settings), load_rooms(test_files, settings)
    seconds = time.perf_counter() - start
    print(f"{len(train_rooms)} training rooms, {len(test_rooms)} test rooms, loaded in {seconds:.0f} s")

    rows = []
    for affordance in affordances:
        rng = np.random.default_rng([args.seed, 1])
        task = Task(affordance, settings, FeatureLayout.from_settings(settings))
        examples = {room.name: room_examples(room, task) for room in train_rooms}
        learn = settings.learn
        train = stack(
            examples,
            list(examples),
            learn.max_negatives,
            np.random.default_rng(args.seed),
            learn.max_positives,
        )
        first = get_learner("linear-tuned").fit(train, train, {}, rng)
        fraction, max_poses = settings.learn.rescore_fraction, settings.learn.rescore_max_poses
        fit_set = second_stage_examples(
            train_rooms, task, first.weights, first.bias, fraction, rng, max_poses=max_poses
        )
        test_set = second_stage_examples(
            test_rooms, task, first.weights, first.bias, fraction, rng, max_poses=max_poses
        )
        weight = tree_sample_weights(fit_set.y, fit_set.weights, trees)
        target = (fit_set.y > 0).astype(int)
        print(
            f"{affordance}: second stage {len(fit_set.y):,} training rows ({fit_set.positives:,} positive), "
            f"{len(test_set.y):,} test rows ({test_set.positives:,} positive), {fit_set.X.shape[1]} features"
        )
        for library, make in models(trees, args.seed).items():
            fits, predictions = [], []
            for _ in range(args.repeats):
                model, start = make(), time.perf_counter()
                model.fit(fit_set.X, target, sample_weight=weight)
                middle = time.perf_counter()
                proba = model.predict_proba(test_set.X)[:, 1]
                fits.append(middle - start)
                predictions.append(time.perf_counter() - middle)
            ap = average_precision_score(test_set.y > 0, proba, sample_weight=test_set.weights)
            rows.append((affordance, library, statistics.median(fits), statistics.median(predictions), ap))
            print(f"  {library}: fits {', '.join(f'{s:.2f}' for s in fits)} s, test AP {ap:.4f}", flush=True)

    print(f"\ncores: {os.cpu_count()} (usable: {len(os.sched_getaffinity(0))}); one thread per fit")
    print(f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}\n")
    print(f"| affordance | library | fit s (median of {args.repeats}) | predict s (test rows) | test AP |")
    print("|---|---|---:|---:|---:|")
    for affordance, library, fit, predict, ap in rows:
        print(f"| {affordance} | {library} | {fit:.2f} | {predict:.3f} | {ap:.4f} |")


if __name__ == "__main__":
    main()
