"""Generated rooms against the real rooms of ../shared/data/rooms: density, noise, holes, heights, labels.

    .venv/bin/python benchmarks/compare_rooms.py --generated DIR --out docs/figures
    .venv/bin/python benchmarks/compare_rooms.py --out docs/figures      # generates 6 rooms itself

DIR is the output of `afford synth` (depth scanner). Without --generated, `afford synth --rooms 6 --seed 0`
runs into a temporary folder. For contrast the same rooms (seed and kinds from DIR/summary.json) are made
again with `--scanner uniform`, unless --uniform gives such a folder. Prints a table and writes figures (PNG)
and compare_rooms.json to --out. What is measured and why: docs/synthetic-rooms.md.

Every measure is taken the same way on every cloud. Heights are above a floor plane fitted to the cloud
(least squares, refitted to the points within 3 cm of it), so the real kitchen's tilt (1.7 degrees) does not
smear its table and counter heights. Voxels are 10 cm with centres at multiples of 0.1 m
(affordcore.geometry.fields).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "rooms"
sys.path.insert(0, str(ROOT))

from affordcore.geometry.fields import estimate_normals
from affordcore.geometry.scene import load_cloud
from affordcore.geometry.skeleton import all_skeletons
from affordcore.labels import affordance_colours, class_counts, load_labels
from affordcore.mapping.pipeline import pose_grids_for_footprint
from affordcore.settings import NormalSettings

VOXEL = 0.10
FLOOR_BAND = 0.05  # a point within 5 cm of the floor plane is a floor point
TABLE_BAND, COUNTER_BAND = (0.60, 0.80), (0.80, 1.00)
REFERENCE_HEIGHTS = {"seat 0.45": 0.45, "table 0.72": 0.72, "counter 0.90": 0.90}
SOURCES = ("real", "depth", "uniform")
STYLE = {
    "depth": ("tab:blue", "generated, depth scanner"),
    "uniform": ("tab:gray", "generated, uniform sampling"),
}
REAL_COLOURS = ["tab:red", "tab:orange", "tab:brown", "tab:pink"]


# ------------------------------------------------------------------------------------------- measures


def floor_plane(points: np.ndarray) -> np.ndarray:
    """(a, b, c) of the floor z = a x + b y + c: start at z = 0, fit the points within 3 cm, refit 4 times."""
    plane = np.zeros(3)
    for _ in range(5):
        near = points[np.abs(points[:, 2] - points[:, :2] @ plane[:2] - plane[2]) < 0.03]
        plane = np.linalg.lstsq(np.c_[near[:, :2], np.ones(len(near))], near[:, 2], rcond=None)[0]
    return plane


def voxel_stats(points: np.ndarray, height: np.ndarray) -> dict:
    """Per occupied voxel: point count, height of the centroid, and a local plane fit (RMS residual,
    normal)."""
    keys = np.floor(points / VOXEL + 0.5).astype(np.int64)
    span = keys.max(axis=0) - keys.min(axis=0) + 1
    flat = np.ravel_multi_index((keys - keys.min(axis=0)).T, span)
    _, first, inverse, counts = np.unique(flat, return_index=True, return_inverse=True, return_counts=True)
    local = points - keys * VOXEL  # within +-5 cm: no cancellation in the moments
    mean = np.stack([np.bincount(inverse, local[:, k]) for k in range(3)], 1) / counts[:, None]
    cov = np.empty((len(counts), 3, 3))
    for a in range(3):
        for b in range(a, 3):
            moment = np.bincount(inverse, local[:, a] * local[:, b]) / counts
            cov[:, a, b] = cov[:, b, a] = moment - mean[:, a] * mean[:, b]
    values, vectors = np.linalg.eigh(cov)
    return {
        "count": counts,
        "height": np.bincount(inverse, height) / counts,
        "rms": np.sqrt(values[:, 0].clip(0)),
        "nz": np.abs(vectors[:, 2, 0]),
        "spread": values[:, 1] / np.maximum(values[:, 2], 1e-12),
        "layer": keys[first, 2],
    }


def cells_of(xy: np.ndarray) -> set:
    return set(map(tuple, np.floor(xy / VOXEL + 0.5).astype(int)))


def hull_cells(cells: set, candidates: np.ndarray) -> np.ndarray:
    """The candidate cells (k, 2) inside the convex hull of `cells`."""
    from scipy.spatial import Delaunay

    return Delaunay(np.array(sorted(cells), float)).find_simplex(candidates.astype(float)) >= 0


def regenerate_room(folder: Path, name: str):
    """The `Room` behind a generated cloud, rebuilt from summary.json's seed and kinds (as afford synth does),
    or None when that is impossible or does not reproduce the recorded size and pieces."""
    from affordcore.synth.rooms import generate_room

    try:
        summary = json.loads((folder / "summary.json").read_text())
        record = next(r for r in summary["rooms"] if r["room"] == name)
        index = int(name.rsplit("-", 1)[1])
        seed = np.random.SeedSequence(summary["seed"]).spawn(index + 1)[index]
        room = generate_room(
            summary["kinds"][index % len(summary["kinds"])], np.random.default_rng(seed), name
        )
    except (OSError, KeyError, StopIteration, ValueError):
        return None
    same_size = np.allclose(np.ptp(room.polygon, axis=0), record["size_m"], atol=0.006)
    same_pieces = [piece.kind for piece in room.pieces] == record["pieces"]
    return room if same_size and same_pieces else None  # else the generator changed since DIR was written


def measure(ply: Path, room=None) -> tuple[dict, dict]:
    """(numbers for the JSON, arrays for the figures) of one cloud and its labels."""
    points = load_cloud(ply).points
    plane = floor_plane(points)
    height = points[:, 2] - points[:, :2] @ plane[:2] - plane[2]
    vox = voxel_stats(points, height)
    planar = (vox["count"] >= 20) & (vox["spread"] > 0.1)
    horizontal, vertical = planar & (vox["nz"] > 0.9), planar & (vox["nz"] < 0.1)
    noise = {
        "floor": vox["rms"][horizontal & (np.abs(vox["height"]) < FLOOR_BAND)],
        "tops 0.3-1.2 m": vox["rms"][horizontal & (vox["height"] > 0.3) & (vox["height"] < 1.2)],
        "vertical": vox["rms"][vertical],
    }

    # holes: which 10 cm floor cells hold floor points, inside which outline
    floor_cells, all_cells = cells_of(points[np.abs(height) < FLOOR_BAND, :2]), cells_of(points[:, :2])
    low, high = np.array(sorted(all_cells)).min(0), np.array(sorted(all_cells)).max(0)
    grid = np.stack(
        np.meshgrid(*(np.arange(a, b + 1) for a, b in zip(low, high)), indexing="ij"), -1
    ).reshape(-1, 2)
    seen = np.array([tuple(c) in floor_cells for c in grid])
    regions = {
        "hull of occupied cells": hull_cells(all_cells, grid),
        "hull of floor cells": hull_cells(floor_cells, grid),
    }
    if room is not None:
        from affordcore.synth.rooms import inside_polygon

        regions["room outline"] = inside_polygon(room.polygon, grid * VOXEL)
        under = np.zeros(len(grid), bool)
        for box in room.furniture_boxes():  # open floor: under no part of any piece
            corners = box.corners_xy()
            near = np.all(
                (grid * VOXEL >= corners.min(0) - 0.1) & (grid * VOXEL <= corners.max(0) + 0.1), axis=1
            )
            under[near] |= _inside_box(box, grid[near] * VOXEL)
        regions["open floor (no furniture above)"] = regions["room outline"] & ~under
    coverage = {k: round(float(seen[r].mean()), 3) for k, r in regions.items()}

    # horizontal surfaces from the normals the fields use (cloud thinned to 2.5 cm, 10 cm radius)
    thinned, normals = estimate_normals(points, NormalSettings())
    up = np.abs(normals[:, 2]) > 0.95
    up_height, up_xy = thinned[up, 2] - thinned[up, :2] @ plane[:2] - plane[2], thinned[up, :2]
    under_tops, top_cells = {}, {}
    for band_name, (lo, hi) in (("tables 0.6-0.8 m", TABLE_BAND), ("counters 0.8-1.0 m", COUNTER_BAND)):
        # a plan cell is under a top when >= 4 up-facing points (of at most 16 at 2.5 cm) lie in the band
        # above it
        in_band = up_xy[(up_height >= lo) & (up_height < hi)]
        keys, n = np.unique(np.floor(in_band / VOXEL + 0.5).astype(int), axis=0, return_counts=True)
        top_cells[band_name] = tops = set(map(tuple, keys[n >= 4]))
        seen_share = round(float(np.mean([c in floor_cells for c in tops])), 3) if tops else None
        under_tops[band_name] = {"cells": len(tops), "with floor points": seen_share}

    labels_path = ply.with_name(ply.name[: -len(".ply")] + ".labels.json")
    labels = load_labels(labels_path)
    footprint = (*points[:, :2].min(axis=0), *points[:, :2].max(axis=0))
    heights = {skeleton.affordance: skeleton.torso_height for skeleton in all_skeletons()}
    counts = class_counts(labels, pose_grids_for_footprint(footprint), heights)
    q1, q2, q3 = np.percentile(vox["count"], [25, 50, 75])
    numbers = {
        "points": len(points),
        "extent_m": [round(float(v), 2) for v in np.ptp(points, axis=0)],
        "occupied_plan_area_m2": round(len(all_cells) * VOXEL**2, 1),
        "floor_tilt_deg": round(float(np.degrees(np.arctan(np.hypot(*plane[:2])))), 2),
        "occupied_voxels": len(vox["count"]),
        "points_per_voxel": {"q1": q1, "median": q2, "q3": q3},
        "occupied_voxels_by_height": {
            band: round(float(np.mean((vox["height"] >= lo) & (vox["height"] < hi))), 3)
            for band, lo, hi in (
                ("floor (|h| < 5 cm)", -FLOOR_BAND, FLOOR_BAND),
                ("0.05-1 m", FLOOR_BAND, 1.0),
                ("1-2 m", 1.0, 2.0),
                ("above 2 m", 2.0, 9.0),
            )
        },
        "noise_rms_mm": {
            k: {"voxels": len(v), "median": _mm(v, 50), "p90": _mm(v, 90)} for k, v in noise.items()
        },
        "floor_coverage": coverage,
        "floor_under_horizontal_tops": under_tops,
        "horizontal_surface_peaks_m": height_peaks(up_height),
        "labels": {name: len(labels.of(name)) for name in labels.affordances},
        "class_counts": {name: c._asdict() for name, c in counts.items()},
    }
    arrays = {
        "points": points,
        "height": height,
        "labels": labels,
        "vox": vox,
        "noise": noise,
        "up_height": up_height,
        "grid": grid,
        "seen": seen,
        "region": regions.get("room outline", regions["hull of occupied cells"]),
        "tables": np.array([tuple(c) in top_cells["tables 0.6-0.8 m"] for c in grid]),
    }
    return numbers, arrays


def _mm(values: np.ndarray, percentile: float) -> float | None:
    return round(1000 * float(np.percentile(values, percentile)), 2) if len(values) else None


def _inside_box(box, xy: np.ndarray) -> np.ndarray:
    c, s = np.cos(box.yaw), np.sin(box.yaw)
    local = (xy - np.array(box.centre[:2])) @ np.array([[c, -s], [s, c]])
    return np.all(np.abs(local) <= np.array(box.size[:2]) / 2, axis=1)


def height_peaks(heights: np.ndarray) -> list[list[float]]:
    """[height, share] of the clear peaks of up-facing points between 0.15 and 1.6 m (share: of those points,
    within 3 cm of the peak), largest share first."""
    from scipy.signal import find_peaks

    heights = heights[(heights > 0.15) & (heights < 1.6)]
    hist, edges = np.histogram(heights, bins=np.arange(0.15, 1.61, 0.01))
    smooth = np.convolve(hist, np.ones(3) / 3, mode="same") / max(1, len(heights))
    found, _ = find_peaks(smooth, prominence=0.01, distance=8)
    peaks = [
        [round(float(edges[i] + 0.005), 2), round(float(hist[max(0, i - 3) : i + 4].sum()) / len(heights), 3)]
        for i in found
    ]
    return sorted(peaks, key=lambda p: -p[1])[:5]


# ------------------------------------------------------------------------------------------- figures


def save(figure, path: Path) -> None:
    figure.savefig(path, dpi=90)
    import matplotlib.pyplot as plt

    plt.close(figure)
    print(f"  wrote {path} ({path.stat().st_size // 1024} KB)")


def top_view(axis, arrays: dict, title: str, colours: dict):
    """The cloud from above (the highest point of each 3 cm cell, grey in 0.2 m steps), each label in its
    affordance's colour with arrows along facing; returns the image (for a colour bar)."""
    import matplotlib
    from matplotlib.patches import Polygon

    points, labels, cell = arrays["points"], arrays["labels"], 0.03
    low = points[:, :2].min(axis=0)
    ij = np.floor((points[:, :2] - low) / cell).astype(int)
    image = np.full(ij.max(axis=0) + 1, np.nan)
    order = np.argsort(points[:, 2])
    image[ij[order, 0], ij[order, 1]] = points[order, 2]  # the last (highest) point of a cell wins
    x1, y1 = low + cell * np.array(image.shape)
    dots = axis.imshow(
        image.T,
        origin="lower",
        extent=(low[0], x1, low[1], y1),
        interpolation="nearest",
        cmap=matplotlib.colormaps["Greys"].resampled(12),
        vmin=-0.4,
        vmax=2.0,
    )
    for region in labels.unlabelled_regions:
        axis.add_patch(Polygon(region.polygon, fill=False, hatch="///", ec="dimgray", lw=0.8))
    for label in labels.labels:
        colour = colours[label.affordance]
        ends = np.array([label.at] if label.at is not None else [label.start, label.end])
        axis.plot(*ends.T, "o-" if len(ends) == 1 else "-", lw=4, ms=7, color=colour, mec="black", zorder=5)
        for base in (ends.mean(axis=0), *ends) if len(ends) > 1 else ends:
            axis.annotate(
                "",
                base + 0.35 * np.array([np.cos(label.facing), np.sin(label.facing)]),
                base,
                arrowprops={"arrowstyle": "-|>", "color": colour, "lw": 1.8},
                zorder=6,
            )
    axis.set_aspect("equal")
    axis.set_title(title, fontsize=10)
    axis.grid(alpha=0.25)
    return dots


def figures(results: dict, out: Path, chosen: list[tuple[str, str]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    real = list(results["real"])
    colour_of = {name: REAL_COLOURS[i % len(REAL_COLOURS)] for i, name in enumerate(real)}
    short = {name: name.split("_")[0] + " " + name.split("_")[1] for name in real}

    def series(sources=("depth", "uniform")):
        """(label, colour, [arrays of every room]) per line: each real room, then each pooled generator."""
        yield from ((f"real: {short[n]}", colour_of[n], [results["real"][n]]) for n in real)
        for source in sources:
            if results[source]:
                rooms = list(results[source].values())
                yield f"{STYLE[source][1]} ({len(rooms)} rooms)", STYLE[source][0], rooms

    # 1. top views: each real room beside a generated one
    names = sorted(
        {a for source in ("real", "depth") for r in results[source].values() for a in r["labels"].affordances}
    )
    colours = affordance_colours(names)
    figure, axes = plt.subplots(
        len(chosen), 2, figsize=(12, 5.2 * len(chosen)), layout="constrained", squeeze=False
    )
    for row, (real_name, generated_name) in enumerate(chosen):
        top_view(axes[row, 0], results["real"][real_name], f"real: {real_name}", colours)
        dots = top_view(
            axes[row, 1],
            results["depth"][generated_name],
            f"generated (depth scanner): {generated_name}",
            colours,
        )
    figure.colorbar(dots, ax=axes, shrink=0.5, label="point height z (m)")
    handles = [Line2D([], [], color=colours[n], lw=4, label=n) for n in names]
    handles.append(Patch(fill=False, hatch="///", ec="dimgray", label="unlabelled region"))
    figure.legend(handles=handles, loc="outside lower center", ncol=len(handles), frameon=False)
    figure.suptitle("Top views (arrows: the facing of the labelled person), metres")
    save(figure, out / "rooms_top_views.png")

    # 2. density: points per occupied voxel, and where the occupied voxels are in height
    figure, (left, right) = plt.subplots(1, 2, figsize=(12, 4.6), layout="constrained")
    bins = np.logspace(0, np.log10(3000), 40)
    for label, colour, rooms in series():
        counts = np.concatenate([r["vox"]["count"] for r in rooms])
        left.hist(
            counts,
            bins=bins,
            weights=np.full(len(counts), 1 / len(counts)),
            histtype="step",
            lw=2,
            color=colour,
            label=f"{label}: median {np.median(counts):.0f}",
        )
        layers = np.concatenate([r["vox"]["layer"] for r in rooms])
        share = np.bincount(layers.clip(-1, 30) + 1, minlength=32) / len(layers)
        right.plot(share, VOXEL * (np.arange(32) - 1), "-o", ms=3, color=colour, label=label)
    left.set(
        xscale="log",
        xlabel="points in an occupied 10 cm voxel",
        ylabel="share of occupied voxels",
        title="Point density per occupied voxel",
    )
    left.legend(fontsize=8, loc="center right")
    right.set(
        xlabel="share of occupied voxels in the layer",
        ylabel="voxel layer centre z (m)",
        title="Where the occupied voxels are (10 cm layers)",
        ylim=(-0.15, 3.0),
    )
    right.legend(fontsize=8)
    save(figure, out / "rooms_density.png")

    # 3. heights of up-facing surfaces
    figure, axis = plt.subplots(figsize=(10, 4.6), layout="constrained")
    for label, colour, rooms in series():
        heights = np.concatenate([r["up_height"] for r in rooms])
        heights = heights[(heights > 0.15) & (heights < 1.6)]
        axis.hist(
            heights,
            bins=np.arange(0.15, 1.61, 0.01),
            density=True,
            histtype="step",
            lw=1.8,
            color=colour,
            label=label,
        )
    for name, z in REFERENCE_HEIGHTS.items():
        axis.axvline(z, color="black", ls=":", lw=1)
        axis.text(z + 0.01, axis.get_ylim()[1] * 0.95, name, fontsize=8, va="top")
    axis.set(
        xlabel="height above the fitted floor plane (m)",
        ylabel="density of up-facing points (1/m)",
        title="Heights of horizontal surfaces (normals within 18 degrees of vertical, 0.15-1.6 m)",
    )
    axis.legend(fontsize=8)
    save(figure, out / "rooms_surface_heights.png")

    # 4. noise: RMS residual of a plane fit in each planar voxel with >= 20 points
    classes = list(next(iter(results["real"].values()))["noise"])
    figure, axis = plt.subplots(figsize=(11, 4.6), layout="constrained")
    entries = list(series(("depth",)))  # uniform samples carry no noise (0 mm, see compare_rooms.json)
    width = 0.8 / len(entries)
    for k, (label, colour, rooms) in enumerate(entries):
        data = [1000 * np.concatenate([r["noise"][c] for r in rooms]) for c in classes]
        positions = np.arange(len(classes)) + (k - (len(entries) - 1) / 2) * width
        parts = axis.boxplot(
            data, positions=positions, widths=width * 0.85, whis=(10, 90), showfliers=False, patch_artist=True
        )
        for box in parts["boxes"]:
            box.set(facecolor=colour, alpha=0.6)
        for median in parts["medians"]:
            median.set(color="black")
        axis.plot([], [], "s", color=colour, alpha=0.6, ms=10, label=label)
    axis.set(
        yscale="log",
        ylabel="RMS distance from the voxel's plane (mm)",
        xticks=range(len(classes)),
        xticklabels=[f"{c}\n(normal {'vertical' if c != 'vertical' else 'horizontal'})" for c in classes],
        title="Surface noise: per planar 10 cm voxel with >= 20 points (box: quartiles, whiskers: 10-90 %)",
    )
    axis.set_yticks([1, 2, 3, 5, 10, 20], ["1", "2", "3", "5", "10", "20"])
    axis.grid(axis="y", alpha=0.3, which="both")
    axis.legend(fontsize=8, loc="lower left")
    save(figure, out / "rooms_noise.png")

    # 5. holes: floor cells with and without floor points, and table tops above them
    figure, axes = plt.subplots(
        len(chosen), 2, figsize=(12, 5.2 * len(chosen)), layout="constrained", squeeze=False
    )
    from matplotlib.colors import ListedColormap

    # codes 1 to 4; 0: outside the region
    legend = [
        ("floor points", "#c9c9c9"),
        ("no floor points", "#d62728"),
        ("table top 0.6-0.8 m, floor seen", "#1f77b4"),
        ("table top 0.6-0.8 m, no floor points", "#ff7f0e"),
    ]
    cmap = ListedColormap(["white"] + [c for _, c in legend])
    for row, pair in enumerate(chosen):
        for column, (source, name) in enumerate(zip(("real", "depth"), pair)):
            a = results[source][name]
            grid = a["grid"]
            code = np.where(a["region"], np.where(a["seen"], 1, 2), 0)
            code = np.where(a["tables"], np.where(a["seen"], 3, 4), code)
            image = np.zeros(np.ptp(grid, axis=0) + 1, int)
            image[tuple((grid - grid.min(0)).T)] = code
            x0, y0 = (grid.min(0) - 0.5) * VOXEL
            x1, y1 = (grid.max(0) + 0.5) * VOXEL
            axes[row, column].imshow(
                image.T,
                origin="lower",
                extent=(x0, x1, y0, y1),
                cmap=cmap,
                vmin=0,
                vmax=4,
                interpolation="nearest",
            )
            coverage = a["numbers"]["floor_coverage"]
            outline = "room outline" if "room outline" in coverage else "hull of occupied cells"
            tables = a["numbers"]["floor_under_horizontal_tops"]["tables 0.6-0.8 m"]["with floor points"]
            axes[row, column].set_title(
                f"{'real' if source == 'real' else 'generated'}: {name}\nfloor points in "
                f"{coverage[outline]:.0%} of the {outline}, under "
                f"{'no' if tables is None else f'{tables:.0%} of the'} table-top cells",
                fontsize=10,
            )
    figure.legend(
        handles=[Patch(color=c, label=t) for t, c in legend],
        loc="outside lower center",
        ncol=4,
        frameon=False,
    )
    figure.suptitle(
        "What the depth camera never saw: 10 cm floor cells with and without floor points "
        "(within 5 cm of the floor)"
    )
    save(figure, out / "rooms_floor_holes.png")


# ------------------------------------------------------------------------------------------- main


def synth(out: Path, rooms: int, seed: int, scanner: str, kinds: list[str] | None = None) -> None:
    command = [
        str(Path(sys.executable).with_name("afford")),
        "synth",
        "--rooms",
        str(rooms),
        "--seed",
        str(seed),
        "--out",
        str(out),
        "--scanner",
        scanner,
        *(["--kinds", ",".join(kinds)] if kinds else []),
    ]
    print("$ afford", " ".join(command[1:]), flush=True)
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)


def pooled(rooms: list[dict]) -> dict:
    """One source's rooms together: voxel densities and noise pooled over voxels, coverage averaged over
    rooms, floor under table tops pooled over table-top cells."""
    counts = np.concatenate([r["vox"]["count"] for r in rooms])
    noise = {c: np.concatenate([r["noise"][c] for r in rooms]) for c in rooms[0]["noise"]}
    numbers = [r["numbers"] for r in rooms]
    under = [n["floor_under_horizontal_tops"] for n in numbers]
    return {
        "rooms": len(rooms),
        "points_per_voxel": {
            "q1": float(np.percentile(counts, 25)),
            "median": float(np.median(counts)),
            "q3": float(np.percentile(counts, 75)),
            "share with 1-3 points": round(float(np.mean(counts <= 3)), 3),
        },
        "noise_rms_mm": {c: {"median": _mm(v, 50), "p90": _mm(v, 90)} for c, v in noise.items()},
        "floor_coverage_mean": {
            k: round(float(np.mean([n["floor_coverage"][k] for n in numbers])), 3)
            for k in numbers[0]["floor_coverage"]
        },
        "floor_under_horizontal_tops": {
            band: round(
                sum(u[band]["cells"] * (u[band]["with floor points"] or 0) for u in under)
                / max(1, sum(u[band]["cells"] for u in under)),
                3,
            )
            for band in under[0]
        },
        "occupied_voxels_in_floor_layer": round(
            float(np.mean([n["occupied_voxels_by_height"]["floor (|h| < 5 cm)"] for n in numbers])), 3
        ),
    }


def table(results: dict) -> str:
    head = [
        "room",
        "source",
        "size x*y*z (m)",
        "points",
        "pts/voxel q1-med-q3",
        "noise floor/tops/vert (mm)",
        "floor cover hull/outline",
        "floor under tables",
        "surface peaks (m)",
        "labels",
    ]
    rows = []
    for source in SOURCES:
        for name, r in results[source].items():
            n, nz = r["numbers"], r["numbers"]["noise_rms_mm"]
            ppv = n["points_per_voxel"]
            rows.append(
                [
                    name[:28],
                    source,
                    "x".join(f"{v:.1f}" for v in n["extent_m"]),
                    f"{n['points']:,}",
                    f"{ppv['q1']:.0f}-{ppv['median']:.0f}-{ppv['q3']:.0f}",
                    "/".join("-" if v["median"] is None else f"{v['median']:.1f}" for v in nz.values()),
                    "/".join(
                        f"{n['floor_coverage'][k]:.2f}"
                        for k in ("hull of occupied cells", "room outline")
                        if k in n["floor_coverage"]
                    ),
                    str(n["floor_under_horizontal_tops"]["tables 0.6-0.8 m"]["with floor points"]),
                    " ".join(f"{h:.2f}" for h, _ in sorted(n["horizontal_surface_peaks_m"][:3])),
                    ", ".join(f"{k[:10]} {v}" for k, v in n["labels"].items() if v),
                ]
            )
    widths = [max(len(str(x)) for x in column) for column in zip(head, *rows)]
    return "\n".join("  ".join(str(x).ljust(w) for x, w in zip(row, widths)) for row in [head, *rows])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--generated", type=Path, help="afford synth output (depth scanner); default: 6 rooms, seed 0"
    )
    parser.add_argument(
        "--uniform", type=Path, help="the same rooms made with --scanner uniform; default: made here"
    )
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "figures")
    args = parser.parse_args()
    if not REAL.is_dir() or not sorted(REAL.glob("*.ply")):
        sys.exit(
            f"compare_rooms: the real rooms are not at {REAL} (../shared/data/rooms beside the project); "
            "nothing to compare with"
        )
    scratch = tempfile.TemporaryDirectory(prefix="compare_rooms_")
    generated = args.generated or Path(scratch.name) / "depth"
    if args.generated is None:
        synth(generated, 6, 0, "depth")
    uniform = args.uniform
    if uniform is None:
        if not (generated / "summary.json").is_file():
            sys.exit(
                f"compare_rooms: {generated}/summary.json is missing (not an afford synth output?); "
                "give --uniform DIR"
            )
        summary = json.loads((generated / "summary.json").read_text())
        uniform = Path(scratch.name) / "uniform"
        synth(uniform, len(summary["rooms"]), summary["seed"], "uniform", summary["kinds"])
    args.out.mkdir(parents=True, exist_ok=True)

    results = {source: {} for source in SOURCES}
    for source, folder in (("real", REAL), ("depth", generated), ("uniform", uniform)):
        for ply in sorted(folder.glob("*.ply")):
            print(f"measuring {source}: {ply.name}", flush=True)
            numbers, arrays = measure(ply, None if source == "real" else regenerate_room(folder, ply.stem))
            results[source][ply.stem] = {**arrays, "numbers": numbers}

    # a generated room of the most similar kind beside each real one
    kinds = {
        "7scenes": "workshop",
        "nyu": "living",
    }
    chosen = [
        (
            real,
            next(
                (g for g in results["depth"] if g.startswith(kinds.get(real.split("_")[0], ""))),
                next(iter(results["depth"])),
            ),
        )
        for real in results["real"]
    ]
    figures(results, args.out, chosen)
    document = {
        source: {name: r["numbers"] for name, r in rooms.items()} for source, rooms in results.items()
    }
    document["pooled"] = {source: pooled(list(rooms.values())) for source, rooms in results.items() if rooms}
    version = subprocess.run(
        ["git", "-C", str(ROOT), "describe", "--always", "--dirty"],
        check=False,
        capture_output=True,
        text=True,
    ).stdout.strip()  # read-only: which generator made the rooms
    document["generated"] = {
        "depth": str(args.generated or "temporary: afford synth --rooms 6 --seed 0"),
        "uniform": str(args.uniform or "temporary: the same rooms with --scanner uniform"),
        "project_version": version or "unknown",
        "command": " ".join(sys.argv),
    }
    (args.out / "compare_rooms.json").write_text(json.dumps(document, indent=1, default=float) + "\n")
    print(table(results))
    print(json.dumps(document["pooled"], indent=1))
    print(f"numbers: {args.out / 'compare_rooms.json'}")


if __name__ == "__main__":
    main()
