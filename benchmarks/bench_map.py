"""Cloud in, affordance maps out: where the time goes, for all three affordances of a 10 m x 10 m room.

The room of bench_features.py (walls, door, sofas, tables, desks, counters, shelves; 100 x 100 x 3 x 63 =
1.89 million poses per affordance), mapped with the shipped models. Stages, each the median of the repeats:
gravity alignment, voxel fields, scoring every pose (the linear model applied to the fields, no features
materialised) with its skeleton / confidence maps, per affordance, and writing the JSON, PNG and Rerun
outputs. Side by side, one affordance scored the other way (materialise every feature vector, then w . f),
checked equal, and what each cascade's second stage adds to its first stage.

    .venv/bin/python benchmarks/bench_map.py             # about 2 minutes on 2 cores
    .venv/bin/python benchmarks/bench_map.py --repeats 1
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from bench_features import POINTS_PER_M2, SEED, room_boxes  # noqa: E402

from affordcore.example import box_surface_points  # noqa: E402
from affordcore.features import iter_features  # noqa: E402
from affordcore.gravity import align_to_gravity  # noqa: E402
from affordcore.inference import score_poses  # noqa: E402
from affordcore.learn.model import (
    load_model,  # noqa: E402
    shipped_models,  # noqa: E402
)
from affordcore.outputs import write_map_outputs  # noqa: E402
from affordcore.pipeline import map_affordances, prepare_scene  # noqa: E402
from affordcore.scene import Cloud  # noqa: E402
from affordcore.settings import Settings  # noqa: E402


def room_cloud(side: float = 10.0) -> Cloud:
    rng = np.random.default_rng(SEED)
    points = np.concatenate(
        [box_surface_points(low, high, POINTS_PER_M2, rng) for low, high in room_boxes(side, rng)]
    )
    return Cloud(points + rng.normal(scale=0.003, size=points.shape), source="10 m benchmark room")


def one_run(cloud: Cloud, settings: Settings, models) -> dict[str, float]:
    seconds = {}
    start = time.perf_counter()
    alignment = align_to_gravity(cloud.points, "auto", settings.gravity)
    seconds["gravity alignment (auto: floor search over 3 axes)"] = time.perf_counter() - start
    start = time.perf_counter()
    scene = prepare_scene(cloud.transformed(alignment.world_from_input), settings, "none")
    seconds["voxel fields (occupancy, distance, normals)"] = time.perf_counter() - start
    clock = [time.perf_counter()]

    def lap(affordance: str, _map) -> None:  # map_affordances reports each affordance as it is done
        seconds[f"score + map {affordance} (1.89 M poses)"] = time.perf_counter() - clock[0]
        clock[0] = time.perf_counter()

    maps = map_affordances(scene.fields, scene.layout, models, settings, on_map=lap)
    with tempfile.TemporaryDirectory() as out:
        start = time.perf_counter()
        write_map_outputs(scene, maps, models, Path(out), Path(out) / "map.rrd")
        seconds["JSON + PNG + Rerun outputs"] = time.perf_counter() - start
    seconds["cloud in to maps computed (no outputs)"] = sum(
        v for k, v in seconds.items() if not k.startswith("JSON")
    )
    return seconds, scene


def materialised(scene, model, settings) -> tuple[float, float, float]:
    """Seconds to score one affordance by features @ w and by applying w to the fields (side by side), and
    the largest difference between the two."""
    skeleton = model.as_skeleton()
    grid = scene.pose_grid(skeleton, settings)
    start = time.perf_counter()
    scores = np.empty(grid.size, dtype=np.float32)
    weights = model.weights.astype(np.float32)
    for chunk in iter_features(
        scene.fields, skeleton, grid, scene.layout, settings.features.chunk_mb, reuse_buffer=True
    ):
        scores[chunk.start : chunk.stop] = chunk.values @ weights + model.bias
    slow = time.perf_counter() - start
    start = time.perf_counter()
    fast = score_poses(scene.fields, skeleton, grid, scene.layout, model.weights, model.bias).ravel()
    seconds = time.perf_counter() - start
    return slow, seconds, float(np.max(np.abs(fast - scores)) / max(1e-9, float(np.max(np.abs(scores)))))


def second_stage(scene, models, settings, repeats: int) -> list[tuple[str, int, float]]:
    """(affordance, poses rescored, seconds) of each cascade's second stage: the model's scoring less its
    first stage's alone, timed alternately, median over `repeats`."""
    import dataclasses

    from affordcore.maps import RULED_OUT
    from affordcore.pipeline import score_model

    rows = []
    for model in (m for m in models if m.rescorer):
        first = dataclasses.replace(model, rescorer=None)
        extra = []
        for _ in range(repeats):
            start = time.perf_counter()
            score_model(first, scene.fields, scene.layout, settings)
            middle = time.perf_counter()
            _, scores = score_model(model, scene.fields, scene.layout, settings)
            extra.append((time.perf_counter() - middle) - (middle - start))
        rows.append((model.affordance, int(np.count_nonzero(scores > RULED_OUT)), statistics.median(extra)))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    settings = Settings()
    models = [load_model(path) for path in shipped_models().values()]
    cloud = room_cloud()
    import open3d  # noqa: F401  (import cost is not the pipeline's)
    import rerun  # noqa: F401

    runs, cpu = [], []
    for _ in range(args.repeats):
        cpu_start, wall_start = time.process_time(), time.perf_counter()
        seconds, scene = one_run(cloud, settings, models)
        cpu.append((time.process_time() - cpu_start) / (time.perf_counter() - wall_start))
        runs.append(seconds)
    print(
        f"{len(cloud):,} points, {os.cpu_count()} cores, {args.repeats} repeats, "
        f"cpu/wall {min(cpu):.2f}-{max(cpu):.2f} "
        f"(2.0 would be both cores busy; far below 1 means a contended machine)"
    )
    print("| stage | seconds (median) |\n|---|---:|")
    for stage in runs[0]:
        print(f"| {stage} | {statistics.median(r[stage] for r in runs):.2f} |")
    slow, fast, difference = materialised(scene, models[0], settings)
    print(
        f"\n{models[0].affordance}: features materialised then w . f: {slow:.2f} s; "
        f"applied to the fields: {fast:.2f} s "
        f"({slow / fast:.1f}x); largest difference {difference:.1e} of the largest score"
    )
    stages = second_stage(scene, models, settings, args.repeats)
    for affordance, rescored, seconds in stages:
        print(f"{affordance}: the second stage rescores {rescored:,} poses in {seconds:.2f} s")
    if stages:
        print(
            f"second stage, all {len(stages)} affordances: {sum(s for _, _, s in stages):.2f} s (target: 1 s)"
        )
    print(
        f"peak memory {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:,.0f} MB (the whole process)"
    )


if __name__ == "__main__":
    main()
