"""The cascade's second stage on the 10 m benchmark room: the features of the poses it rescores, and the walk
of its trees over them (`TreeEnsemble.log_odds`, compiled by numba), every shipped model.

The walk of 450 trees is one of the largest costs of a map (docs/maps.md, "Speed"), so it is measured here on
its own, side by side in one process: the same rows, every walk in turn within each repeat, CPU seconds
(medians; numba's compilation done before), and the largest difference from this commit's scores. The walks:
this commit's over the complete layout, and over the node tables (the kernel for trees too deep for that
layout); with ``--old PATH`` (a git worktree of an earlier commit) that commit's walk too: its
`affordcore/learn/trees.py` is loaded as a module of its own and reads the same model documents (for commits
before numba, whose file imports nothing of the project).

    .venv/bin/python benchmarks/bench_trees.py               # about a minute on 2 cores
    .venv/bin/python benchmarks/bench_trees.py --old /tmp/old-afford --repeats 9
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


def old_ensemble_class(worktree: str):
    """`TreeEnsemble` as the commit checked out at `worktree` defines it."""
    import importlib.util

    path = Path(worktree) / "affordcore" / "learn" / "trees.py"
    spec = importlib.util.spec_from_file_location("old_trees", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the class is made
    spec.loader.exec_module(module)
    return module.TreeEnsemble


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--old", help="a worktree of the commit whose walk runs beside this one's")
    args = parser.parse_args()
    from affordcore.geometry.gravity import align_to_gravity
    from affordcore.learn.model import load_model, shipped_models
    from affordcore.learn.trees import TreeEnsemble, compile_walk
    from affordcore.mapping.pipeline import prepare_scene
    from affordcore.settings import Settings

    settings = Settings()
    cloud = room_cloud()
    alignment = align_to_gravity(cloud.points, "auto", settings.gravity)
    scene = prepare_scene(cloud.transformed(alignment.world_from_input), settings, "none")
    old = old_ensemble_class(args.old) if args.old else None
    names = ["complete layout", "node tables"] + (["old commit"] if old else [])
    print(
        f"the second stage on the 10 m benchmark room, {os.cpu_count()} cores, {args.repeats} repeats, CPU "
        "seconds (medians)" + (f"; 'old commit' is the walk at {args.old}" if old else "")
    )
    walks = " | ".join(f"walk, {n} s" for n in names)
    print(f"| model | rows x trees | features s | {walks} | largest difference |")
    print("|---|---|---:|" + "---:|" * len(names) + "---:|")
    compile_walk()
    for model in (load_model(path) for path in shipped_models().values()):
        trees = model.trees
        if trees is None:
            continue
        rows, features = rescored_rows(scene, model, settings)
        tables = TreeEnsemble.from_dict(model.rescorer["trees"])
        tables.__dict__["_complete"] = None  # the cached layout: none, so the node tables are walked
        walks = [trees.log_odds, tables.log_odds]
        if old is not None:
            walks.append(old.from_dict(model.rescorer["trees"]).log_odds)
        reference = trees.log_odds(rows)
        seconds = {name: [] for name in names}
        difference = 0.0
        for _ in range(args.repeats):
            for name, walk in zip(names, walks, strict=True):
                start = time.process_time()
                scores = walk(rows)
                seconds[name].append(time.process_time() - start)
                difference = max(difference, float(np.abs(scores - reference).max()))
        walks = " | ".join(f"{statistics.median(seconds[n]):.3f}" for n in names)
        print(
            f"| {model.affordance} | {len(rows):,} x {len(trees.roots)} | {features:.2f} | {walks} | "
            f"{difference:.1e} |"
        )


if __name__ == "__main__":
    main()
