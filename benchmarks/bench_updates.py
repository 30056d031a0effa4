"""Map updates in proportion to the change: what the fields and maps of a room cost when it changes a little,
updated as the services update them, against computing them from scratch, side by side, for each feature
layout: the paper's (the default: untruncated distance, steep normals facing the cloud's mean point; the
shipped models) and the local one (distance truncated at 1 m, steep normals facing the scanned floor; models
given by --local-models, trained with that layout).

Two rooms of bench_map.py's generator (6 m, kitchen-size, and the 10 m benchmark room), each changed in the
ways a robot's map changes: a box of 0.1 / 0.3 / 0.6 m put down on free floor near the room's centre, and
the last metre of the room along x seen for the first time (the map grew). For each: the voxel fields of the
room before and after, from scratch and with the normals of the room before (`updates.NormalCache`, as the
features service keeps them), then the three shipped models' maps of the changed room by a mapper that mapped
the room before (an update, `pipeline.RoomMapper`, as the inference service keeps it) and by a fresh one,
alternating the order every repeat. Their maps must be equal (places, scores, cut): the
column says so. Medians over the repeats, the core count and the load.

    AFFORD_FEATURES__DISTANCE_CAP=1.0 AFFORD_NORMALS__STEEP_FACING=floor \
        .venv/bin/afford models rebuild --out bench-data/models-local                # once, about 15 minutes
    .venv/bin/python benchmarks/bench_updates.py --local-models bench-data/models-local   # about 10 minutes
    .venv/bin/python benchmarks/bench_updates.py --repeats 1 --sides 6                     # the paper's only
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from bench_map import room_cloud  # noqa: E402

from affordcore.example import box_surface_points  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--sides", default="6,10", help="room sizes (m)")
    parser.add_argument("--local-models", type=Path, help="models trained with the local layout (a folder)")
    parser.add_argument("--local-cap", type=float, default=1.0, help="the local layout's distance cap (m)")
    args = parser.parse_args()

    from affordcore.geometry.fields import compute_fields
    from affordcore.learn.model import shipped_models

    layouts = {"paper": layout_and_models(None, "centre", list(shipped_models().values()))}
    if args.local_models:
        paths = sorted(args.local_models.glob("*.model.json"))
        layouts["local"] = layout_and_models(args.local_cap, "floor", paths)
    print(
        f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}; layouts {', '.join(layouts)}; "
        f"medians of {args.repeats}",
        flush=True,
    )
    rows = []
    for name, (settings, layout, models) in layouts.items():
        for side in (float(s) for s in args.sides.split(",")):
            room = room_cloud(side).points
            base_fields = compute_fields(room, settings.voxel, settings.normals)
            for change, (before, after) in changes(room, base_fields, side).items():
                fields = compare_fields(settings, before, after, args.repeats)
                old = compute_fields(before, settings.voxel, settings.normals)
                new = compute_fields(after, settings.voxel, settings.normals)
                row = compare(models, layout, settings, old, new, args.repeats)
                rows.append({"layout": name, "room": f"{side:g} m", "change": change, **fields, **row})
                print(f"  {rows[-1]}", flush=True)
    print_table(rows)
    print(
        f"peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20:.2f} GB; load average "
        f"{os.getloadavg()[0]:.1f} at the end"
    )


def layout_and_models(cap: float | None, facing: str, paths: list[Path]):
    """(settings, feature layout, its models) of one layout; the models must have been trained with it."""
    from affordcore.geometry.features import FeatureLayout
    from affordcore.learn.model import load_model
    from affordcore.settings import Settings

    base = Settings()
    settings = base.model_copy(
        update={
            "features": base.features.model_copy(update={"distance_cap": cap}),
            "normals": base.normals.model_copy(update={"steep_facing": facing}),
        }
    )
    layout = FeatureLayout.from_settings(settings)
    return settings, layout, [load_model(path, layout) for path in paths]


def changes(room: np.ndarray, fields, side: float) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """{what changed: (points before, points after)}."""
    rng = np.random.default_rng(0)
    x, y = open_floor(fields)
    out = {}
    for edge in (0.1, 0.3, 0.6):
        low = np.array([x - edge / 2, y - edge / 2, 0.0])
        box = box_surface_points(low, low + [edge, edge, max(edge, 0.45)], 900, rng)
        out[f"{edge:g} m box"] = (room, np.concatenate([room, box]))
    out["1 m of room newly seen"] = (room[room[:, 0] < room[:, 0].max() - 1.0], room)
    return out


def open_floor(fields) -> tuple[float, float]:
    """The (x, y) nearest the room's centre with nothing within 0.4 m between 0.2 and 1.5 m up (else the most
    open one): a free spot, where the change's reach is not cut short by walls."""
    lattice = fields.lattice
    k0, k1 = (int(round((h - lattice.origin[2]) / lattice.resolution)) for h in (0.2, 1.5))
    clearance = fields.distance[:, :, k0:k1].min(axis=2)
    x, y = (lattice.origin[a] + np.arange(lattice.shape[a]) * lattice.resolution for a in (0, 1))
    x_min, y_min, x_max, y_max = fields.footprint
    inside = np.outer((x > x_min + 0.5) & (x < x_max - 0.5), (y > y_min + 0.5) & (y < y_max - 0.5))
    clearance = np.where(inside, clearance, 0.0)
    centre = np.hypot(*np.meshgrid(x - (x_min + x_max) / 2, y - (y_min + y_max) / 2, indexing="ij"))
    free = clearance >= min(0.4, clearance.max())
    i, j = np.unravel_index(np.argmin(np.where(free, centre, np.inf)), clearance.shape)
    return tuple(lattice.origin[:2] + np.array([i, j]) * lattice.resolution)


def compare_fields(settings, before: np.ndarray, after: np.ndarray, repeats: int) -> dict:
    """The fields of the changed room from scratch and with the normals of the room before (NormalCache),
    alternating; the largest difference between the two."""
    from affordcore.geometry.fields import compute_fields
    from affordcore.mapping.updates import NormalCache

    scratch_s, cached_s = [], []
    for repeat in range(repeats):
        cache = NormalCache()
        compute_fields(before, settings.voxel, settings.normals, estimator=cache)
        for which in ("cached", "scratch") if repeat % 2 == 0 else ("scratch", "cached"):
            start = time.perf_counter()
            fields = compute_fields(
                after, settings.voxel, settings.normals, estimator=cache if which == "cached" else None
            )
            (cached_s if which == "cached" else scratch_s).append(time.perf_counter() - start)
            if which == "cached":
                cached, estimated, thinned = fields, cache.estimated, len(cache.points)
            else:
                scratch = fields
    return {
        "fields_s": statistics.median(scratch_s),
        "fields_update_s": statistics.median(cached_s),
        "normals_estimated": estimated / thinned,
        "fields_diff": float(np.abs(cached.normals - scratch.normals).max()),
    }


def compare(models, layout, settings, old, new, repeats: int) -> dict:
    from affordcore.mapping.pipeline import RoomMapper

    update_s, full_s = [], []
    for repeat in range(repeats):
        primed = RoomMapper(models, layout, settings)
        primed.maps(old)
        for which in ("update", "full") if repeat % 2 == 0 else ("full", "update"):
            mapper = primed if which == "update" else RoomMapper(models, layout, settings)
            start = time.perf_counter()
            maps = mapper.maps(new)
            (update_s if which == "update" else full_s).append(time.perf_counter() - start)
            if which == "update":
                updated, reports = maps, primed.reports
            else:
                scratch = maps
    same = all(
        np.array_equal(updated[a].skeletons, scratch[a].skeletons)
        and np.array_equal(updated[a].scores, scratch[a].scores)
        and updated[a].place_threshold == scratch[a].place_threshold
        for a in scratch
    )
    rescored = sum(r.rescored_poses for r in reports.values()) / sum(r.total_poses for r in reports.values())
    return {
        "poses": sum(r.total_poses for r in reports.values()),
        "rescored": rescored,
        "update_s": statistics.median(update_s),
        "full_s": statistics.median(full_s),
        "same": same,
    }


def print_table(rows: list[dict]) -> None:
    print()
    print(
        "| layout | room | change | normals estimated | fields from scratch s | fields updated s | poses "
        "rescored | maps from scratch s | maps updated s | scratch / updated (fields + maps) | same maps |"
    )
    print("|---|---|---|---:|---:|---:|---:|---:|---:|---:|---|")
    for r in rows:
        scratch, updated = r["fields_s"] + r["full_s"], r["fields_update_s"] + r["update_s"]
        print(
            f"| {r['layout']} | {r['room']} | {r['change']} | {100 * r['normals_estimated']:.0f} % "
            f"| {r['fields_s']:.2f} | {r['fields_update_s']:.2f} "
            f"| {100 * r['rescored']:.0f} % of {r['poses']:,} "
            f"| {r['full_s']:.2f} | {r['update_s']:.2f} | {scratch / updated:.1f}x "
            f"| {'yes' if r['same'] else 'NO'} |"
        )
    worst = max(r["fields_diff"] for r in rows)
    print(f"\nlargest difference between updated and fresh normal fields: {worst:.1e}")


if __name__ == "__main__":
    main()
