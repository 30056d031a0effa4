"""Figures a person reads faster than numbers (matplotlib, no screen needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .fields import SceneFields


def pyplot():
    """matplotlib's pyplot on the Agg backend: every figure here goes to a file, no screen needed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_fields(fields: SceneFields, path: str | Path, slice_height: float = 0.45) -> Path:
    """Plan views of a room's fields: the height of the highest occupied voxel, and the distance field at
    ``slice_height`` (seat height by default), with the floor footprint the pose grid covers."""
    plt = pyplot()

    lattice = fields.lattice
    z = lattice.origin[2] + np.arange(lattice.shape[2]) * lattice.resolution
    occupied = fields.occupancy > 0.5
    top = np.where(occupied.any(axis=2), z[np.argmax(np.where(occupied, z, -np.inf), axis=2)], np.nan)
    k = int(np.clip(round((slice_height - lattice.origin[2]) / lattice.resolution), 0, lattice.shape[2] - 1))
    half = lattice.resolution / 2
    extent = (lattice.origin[0] - half, lattice.upper[0] + half, lattice.origin[1] - half, lattice.upper[1] + half)
    x0, y0, x1, y1 = fields.footprint

    figure, axes = plt.subplots(1, 2, figsize=(12, 5.5), constrained_layout=True)
    panels = [
        (top, "viridis", "height of the highest occupied voxel (m)"),
        (fields.distance[:, :, k], "magma", f"distance to the nearest surface at z = {z[k]:.2f} m (m)"),
    ]
    for axis, (image, cmap, title) in zip(axes, panels):
        shown = axis.imshow(image.T, origin="lower", extent=extent, cmap=cmap, interpolation="nearest")
        axis.add_patch(plt.Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ec="cyan", lw=1.2, ls="--"))
        axis.set_title(title, fontsize=10)
        axis.set_xlabel("x (m)")
        axis.set_ylabel("y (m)")
        axis.set_aspect("equal")
        figure.colorbar(shown, ax=axis, shrink=0.8)
    figure.suptitle(f"voxel fields, {lattice.resolution * 100:.0f} cm voxels; dashed: floor footprint of the pose grid")
    path = Path(path)
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path


def plot_map(points: np.ndarray, amap, path: str | Path, cell: float = 0.05, labels=None) -> Path:
    """Plan view of one affordance map: the cloud from above (the highest point per 5 cm cell, darker =
    higher), the confidence map as filled contours above the model's threshold, and each skeleton of the
    skeleton map as a dot with an arrow along its facing, labelled with its score. Given a `LabelSet`, the
    affordance's ground-truth labels are drawn too (orange, with their facing)."""
    plt = pyplot()

    grid = amap.grid
    low, high = points[:, :2].min(axis=0), points[:, :2].max(axis=0)
    shape = np.ceil((high - low) / cell).astype(int) + 1
    index = np.floor((points[:, :2] - low) / cell).astype(int)
    top = np.full(shape, np.nan)
    order = np.argsort(points[:, 2])  # written lowest first, so each cell ends with its highest point
    top[index[order, 0], index[order, 1]] = points[order, 2]
    figure, ax = plt.subplots(figsize=(9, 9 * max(0.4, shape[1] / shape[0])), constrained_layout=True)
    ax.imshow(top.T, origin="lower", extent=(low[0], low[0] + shape[0] * cell, low[1], low[1] + shape[1] * cell),
              cmap="Greys", vmin=-0.5, vmax=2.5, interpolation="nearest")
    confidence = amap.confidence.T  # rows y, columns x
    top = float(np.max(confidence))
    if top > amap.threshold:
        levels = np.linspace(amap.threshold, top, 8)
        filled = ax.contourf(grid.x, grid.y, confidence, levels=levels, cmap="viridis", alpha=0.55)
        figure.colorbar(filled, ax=ax, shrink=0.7, label="decision value (above the model's threshold)")
    for x, y, _, theta, score in amap.skeletons:
        ax.plot(x, y, "o", color="crimson", ms=6)
        ax.annotate("", (x + 0.35 * np.cos(theta), y + 0.35 * np.sin(theta)), (x, y),
                    arrowprops={"arrowstyle": "->", "color": "crimson", "lw": 1.6})
        ax.text(x, y - 0.18, f"{score:.2f}", color="crimson", fontsize=7, ha="center", va="top")
    for label in (labels.of(amap.affordance) if labels is not None else []):
        ends = np.array([label.at] if label.at is not None else [label.start, label.end])
        ax.plot(ends[:, 0], ends[:, 1], "-o", color="darkorange", lw=3, ms=4, alpha=0.8)
        middle = ends.mean(axis=0)
        ax.annotate("", middle + 0.3 * np.array([np.cos(label.facing), np.sin(label.facing)]), middle,
                    arrowprops={"arrowstyle": "->", "color": "darkorange", "lw": 1.6})
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{amap.affordance}: {len(amap.skeletons)} places, {len(amap.positives):,} poses above the threshold")
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return Path(path)
