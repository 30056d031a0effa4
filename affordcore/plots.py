"""Figures a person reads faster than numbers (matplotlib, no screen needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .fields import SceneFields


def plot_fields(fields: SceneFields, path: str | Path, slice_height: float = 0.45) -> Path:
    """Plan views of a room's fields: the height of the highest occupied voxel, and the distance field at
    ``slice_height`` (seat height by default), with the floor footprint the pose grid covers."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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
