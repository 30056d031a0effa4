"""What `afford map` hands to people and robots: per affordance a JSON map and a plan-view PNG, and one Rerun
recording of the room with every map.

`map_and_write` is the command's last stage: each model's scores, map, JSON and PNG in a worker process of
their own (forked once the fields exist, so nothing is copied to them), while this process writes the
recording and logs each map as it comes back. On 2 cores that is what keeps three plans and a recording from
costing more than the mapping (benchmarks/bench_map.py, docs/maps.md).
"""

from __future__ import annotations

import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

from ..learn.model import AffordanceModel

_JOB: tuple | None = None  # (scene, models, settings, out, plan): what forked workers read, never pickled


def write_map_outputs(
    scene, maps: dict, models: list[AffordanceModel], out: Path, rrd: Path | None
) -> list[Path]:
    """DIR/<affordance>.json and .png for every map of a `PreparedScene`, and the recording; returns the
    paths."""
    from .plots import plan_heights

    out.mkdir(parents=True, exist_ok=True)
    ids = {model.affordance: model.id for model in models}
    plan = plan_heights(scene.cloud.points)
    written = []
    for affordance, amap in maps.items():
        written += _json_and_png(scene, amap, ids[affordance], out, plan)
    if rrd is not None:
        recording = _open_with_cloud(rrd, list(maps), scene.cloud)
        _close_with_maps(recording, maps.values())
        written.append(rrd)
    return written


def map_and_write(
    scene,
    models: list[AffordanceModel],
    settings,
    out: Path,
    rrd: Path | None,
    workers: int | None = None,
    on_map: Callable[[str, object], None] | None = None,
    timings: dict[str, float] | None = None,
) -> tuple[dict, list[Path]]:
    """Every model's map of a `PreparedScene` (`pipeline.map_affordances`, one model at a time) and the
    outputs of `write_map_outputs`; returns ({affordance: map} in the models' order, the paths written).

    With ``workers`` > 1 (default: one per model when the machine has two cores or more, on Linux) each
    model is scored, mapped and written (JSON, PNG) in a forked worker process, and this process writes the
    recording meanwhile; ``on_map(affordance, map)`` hears of each map as it comes back. ``timings`` gets
    each stage's seconds: per affordance its scoring and map, and its JSON and PNG (in its worker), and the
    recording."""
    global _JOB
    from .plots import plan_heights

    out.mkdir(parents=True, exist_ok=True)
    timings = {} if timings is None else timings
    workers = default_workers(len(models)) if workers is None else max(1, min(workers, len(models)))
    _JOB = (scene, models, settings, out, plan_heights(scene.cloud.points))
    results: dict[int, tuple] = {}

    def collected(index: int, result: tuple) -> None:
        results[index] = result
        amap, _, seconds = result
        for stage, value in seconds.items():
            timings[f"{stage} {amap.affordance}"] = value
        if on_map:
            on_map(amap.affordance, amap)

    try:
        if workers == 1:
            for index in range(len(models)):
                collected(index, _map_one(index))
            recording = _open_with_cloud(rrd, [m.affordance for m in models], scene.cloud) if rrd else None
        else:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor, as_completed

            from .plots import pyplot

            pyplot()  # imported once here rather than once per worker: 0.4 s of CPU each on 2 cores
            with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork")) as pool:
                futures = {pool.submit(_map_one, index): index for index in range(len(models))}
                start = time.perf_counter()
                recording = (
                    _open_with_cloud(rrd, [m.affordance for m in models], scene.cloud) if rrd else None
                )
                timings["recording: the cloud"] = time.perf_counter() - start
                for future in as_completed(futures):
                    collected(futures[future], future.result())
    finally:
        _JOB = None
    ordered = [results[index] for index in range(len(models))]
    maps = {amap.affordance: amap for amap, _, _ in ordered}
    written = [path for _, paths, _ in ordered for path in paths]
    if recording is not None:
        start = time.perf_counter()
        _close_with_maps(recording, maps.values())
        timings["recording: the maps"] = time.perf_counter() - start
        written.append(rrd)
    return maps, written


def default_workers(n_models: int) -> int:
    """Worker processes for `map_and_write`: one per model where fork exists (Linux) and there are two
    cores or more, else none (1: all in this process)."""
    if not sys.platform.startswith("linux") or (os.cpu_count() or 1) < 2:
        return 1
    return max(1, min(n_models, 8))


def _map_one(index: int) -> tuple:
    """In a worker (or in-process): model `index`'s map, its JSON and PNG; (map, paths, seconds)."""
    from .pipeline import map_affordances

    scene, models, settings, out, plan = _JOB
    model = models[index]
    start = time.perf_counter()
    amap = map_affordances(scene.fields, scene.layout, [model], settings)[model.affordance]
    mapped = time.perf_counter()
    paths = _json_and_png(scene, amap, model.id, out, plan)
    seconds = {"score + map": mapped - start, "JSON + PNG": time.perf_counter() - mapped}
    return amap, paths, seconds


def _json_and_png(scene, amap, model_id: str, out: Path, plan) -> list[Path]:
    from .plots import plot_map

    document = amap.to_json(model_id, scene.alignment.world_from_input)
    path = out / f"{amap.affordance}.json"
    path.write_text(json.dumps(document) + "\n")
    return [path, plot_map(scene.cloud.points, amap, out / f"{amap.affordance}.png", plan=plan)]


def _open_with_cloud(rrd: Path, affordances: list[str], cloud):
    """The recording, named after the cloud's file and the time, with the cloud in it."""
    from .recording import log_cloud, open_recording, recording_name

    recording = open_recording(rrd, affordances, name=recording_name(f"{Path(cloud.source).stem} map"))
    log_cloud(recording, cloud.points)
    return recording


def _close_with_maps(recording, maps) -> None:
    from .recording import close_recording, log_map

    for amap in maps:
        log_map(recording, amap)
    close_recording(recording)


def summary_line(amap) -> str:
    """One line per map for people: places, poses above the threshold, the best score."""
    best = f", best {amap.place_labels()[0]}" if len(amap.skeletons) else ""
    return (
        f"{amap.affordance:<18} {len(amap.skeletons):>3} places, "
        f"{len(amap.positives):>7,} poses above the threshold{best}"
    )
