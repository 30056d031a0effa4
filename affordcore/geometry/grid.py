"""The pose grid: every (x, y, z, theta) a skeleton is tried at (DESIGN.md, "Pose grid").

x and y are the centres of ``step`` cells tiling the room's floor footprint, so a 10 m x 10 m room has
100 x 100 positions and each position is one pixel of the confidence map. theta = k * theta_step for
k = 0 .. n_theta - 1. z is the skeleton's torso height and ``z_levels_each_side`` voxels above and below it,
and, for a skeleton whose file says so (``torso_reach_above``), further levels above up to that reach (a
seated person on a bar stool); skeletons without it get DESIGN.md's grid.

Poses are numbered in C order over the axes (z, theta, x, y): one (z, theta) pair is a contiguous slab of
nx * ny poses, which is how features are computed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..settings import GridSettings


@dataclass(frozen=True)
class PoseGrid:
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    theta: np.ndarray

    def __post_init__(self) -> None:
        for name in ("x", "y", "z", "theta"):
            object.__setattr__(self, name, np.atleast_1d(np.asarray(getattr(self, name), dtype=np.float64)))
        steps = np.concatenate([np.diff(self.x), np.diff(self.y)])
        if len(steps) and (steps.min() <= 0 or np.ptp(steps) > 1e-9):
            raise ValueError("pose grid x and y must be increasing with one common step")

    @classmethod
    def over_footprint(
        cls,
        footprint: tuple[float, float, float, float],
        torso_height: float,
        voxel_resolution: float,
        settings: GridSettings | None = None,
        reach_above: float = 0.0,
    ) -> PoseGrid:
        """The grid over a floor footprint; `reach_above` (m) adds torso levels above the usual ones."""
        settings = settings or GridSettings()
        x_min, y_min, x_max, y_max = footprint
        if not (x_max >= x_min and y_max >= y_min):
            raise ValueError(f"empty floor footprint {footprint}")
        levels = torso_levels(settings.z_levels_each_side, reach_above, voxel_resolution)
        return cls(
            x=_cell_centres(x_min, x_max, settings.step),
            y=_cell_centres(y_min, y_max, settings.step),
            z=torso_height + levels * voxel_resolution,
            theta=np.arange(settings.n_theta) * settings.theta_step,
        )

    @property
    def shape(self) -> tuple[int, int, int, int]:
        return (len(self.z), len(self.theta), len(self.x), len(self.y))

    @property
    def size(self) -> int:
        return int(np.prod(self.shape))

    @property
    def step(self) -> float:
        """The x and y spacing (nan for a single position)."""
        for axis in (self.x, self.y):
            if len(axis) > 1:
                return float(axis[1] - axis[0])
        return float("nan")

    def poses(self, index: np.ndarray) -> np.ndarray:
        """(n, 4) array of (x, y, z, theta) for flat pose indices."""
        iz, it, ix, iy = np.unravel_index(np.asarray(index), self.shape)
        return np.stack([self.x[ix], self.y[iy], self.z[iz], self.theta[it]], axis=-1)

    def as_dict(self) -> dict:
        return {
            "x0": float(self.x[0]),
            "y0": float(self.y[0]),
            "step": self.step,
            "nx": len(self.x),
            "ny": len(self.y),
            "z": [round(float(v), 6) for v in self.z],
            "theta_step": float(self.theta[1] - self.theta[0]) if len(self.theta) > 1 else 0.0,
            "n_theta": len(self.theta),
            "order": "z, theta, x, y (C order)",
        }


def torso_levels(each_side: int, reach_above: float, voxel_resolution: float) -> np.ndarray:
    """Voxel steps from the skeleton's torso height: -each_side .. each_side, extended upwards to the
    highest whole step within `reach_above` (the tolerance keeps 0.3 / 0.1 from flooring to 2)."""
    highest = max(each_side, int(np.floor(reach_above / voxel_resolution + 1e-6)))
    return np.arange(-each_side, highest + 1)


def _cell_centres(low: float, high: float, step: float) -> np.ndarray:
    first = np.floor(low / step)
    last = max(np.ceil(high / step), first + 1)
    return (np.arange(first, last) + 0.5) * step
