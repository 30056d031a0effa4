"""The cascade's second stage on the 10 m benchmark room: the features of the poses it rescores, and the walk
of its trees over them at several chunk sizes (rows walked at once), every shipped model.

The walk of 450 trees is the largest single cost of `afford map` by cProfile (docs/maps.md, "Speed"), so
its chunk size is measured here, side by side in one process: the same rows, every chunk size in turn within
each repeat, CPU seconds (medians), and the scores compared to the bit.

    .venv/bin/python benchmarks/bench_trees.py               # about a minute on 2 cores
    .venv/bin/python benchmarks/bench_trees.py --chunks 256,512,1024 --repeats 9
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from bench_map import room_cloud  # noqa: E402


def rescored_rows(scene, model, settings) -> tuple[np.ndarray, float]:
    """The feature rows the model's second stage rescores in this scene (as `model_scores` picks them), and
    the CPU seconds their features took."""
    import dataclasses

    from affordcore.geometry.features import features_at
    from affordcore.mapping.inference import best_poses
    from affordcore.mapping.pipeline import score_model

    first = dataclasses.replace(model, rescorer=None)
    grid, scores = score_model(first, scene.fields, scene.layout, settings)
    best = best_poses(scores.ravel(), model.rescorer["fraction"], model.rescorer.get("max_poses"))
    start = time.process_time()
    rows = features_at(scene.fields, model.as_skeleton(), grid, scene.layout, best)
    return rows, time.process_time() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--chunks", default="256,512,1024,2048", help="rows walked at once, comma-separated")
    args = parser.parse_args()
    from affordcore.geometry.gravity import align_to_gravity
    from affordcore.learn.model import load_model, shipped_models
    from affordcore.mapping.pipeline import prepare_scene
    from affordcore.settings import Settings

    settings = Settings()
    cloud = room_cloud()
    alignment = align_to_gravity(cloud.points, "auto", settings.gravity)
    scene = prepare_scene(cloud.transformed(alignment.world_from_input), settings, "none")
    chunks = [None] + [int(c) for c in args.chunks.split(",")]
    names = ["default"] + [str(c) for c in chunks[1:]]
    print(
        f"the second stage on the 10 m benchmark room, {os.cpu_count()} cores, {args.repeats} repeats, CPU "
        "seconds (medians); 'default' is `TreeEnsemble.log_odds`' own chunk"
    )
    walks = " | ".join(f"walk, {n} rows s" for n in names)
    print(f"| model | rows x trees | features s | {walks} | same scores |")
    print("|---|---|---:|" + "---:|" * len(names) + "---|")
    for model in (load_model(path) for path in shipped_models().values()):
        trees = model.trees
        if trees is None:
            continue
        rows, features = rescored_rows(scene, model, settings)
        reference = trees.log_odds(rows)
        seconds = {name: [] for name in names}
        same = True
        for _ in range(args.repeats):
            for name, chunk in zip(names, chunks, strict=True):
                start = time.process_time()
                scores = trees.log_odds(rows, chunk=chunk)
                seconds[name].append(time.process_time() - start)
                same &= bool(np.array_equal(scores, reference))
        walks = " | ".join(f"{statistics.median(seconds[n]):.3f}" for n in names)
        print(
            f"| {model.affordance} | {len(rows):,} x {len(trees.roots)} | {features:.2f} | {walks} | "
            f"{'yes' if same else 'NO'} |"
        )


if __name__ == "__main__":
    main()
