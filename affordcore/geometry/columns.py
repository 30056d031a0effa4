"""Fine columns: the lowest and the highest surface over each 5 cm column of a room, and what a pose reads of
them in its own frame, for the second stage.

Why: the fields are 10 cm voxels, so a seat 0.42 m high and one 0.48 m high, or a table edge 4 cm and 9 cm
in front of the knees, read alike to them. The second stage sees only a room's best few thousand poses, so
it can afford a finer look: the column maps are one pass over the points, a pose's read is a few hundred
lookups. Two heights a column (the lowest surface above the floor's clutter, the highest under head
height) tell a seat from a table top over it, as for a chair pushed in under a table, which one height
would hide.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

RESOLUTION = 0.05  # m, the columns' cell
BAND = (0.15, 1.5)  # m above the floor: what a body meets; below it floor clutter, above it shelves
EMPTY_LOW = 2.0  # a column with no surface in the band: its lowest surface as if above everything
# where a pose reads the columns, in its frame (forward u along theta, v to its left): 5 cm along the
# body's axis, which is where seats, backs and table edges differ, 10 cm across it
FORWARD = np.round(np.arange(-0.30, 0.70 + 1e-9, RESOLUTION), 3)
ACROSS = np.round(np.arange(-0.30, 0.30 + 1e-9, 2 * RESOLUTION), 3)
N_FEATURES = 2 * len(FORWARD) * len(ACROSS)


@dataclass(frozen=True)
class FineColumns:
    origin: np.ndarray  # (2,) x, y of cell (0, 0)'s lower corner
    resolution: float
    low: np.ndarray  # (nx, ny) float32: the lowest surface in the band above each cell, EMPTY_LOW if none
    high: np.ndarray  # (nx, ny) float32: the highest surface in the band, 0 if none

    @property
    def nbytes(self) -> int:
        return self.low.nbytes + self.high.nbytes


def fine_columns(points: np.ndarray, margin: float = 1.0) -> FineColumns:
    """The column maps of a gravity-aligned cloud (floor at z = 0), over its footprint and `margin` round it
    (a pose at the footprint's edge reads up to 0.7 m out)."""
    points = np.asarray(points, dtype=np.float64)
    origin = np.floor((points[:, :2].min(axis=0) - margin) / RESOLUTION) * RESOLUTION
    shape = tuple(int(n) for n in np.ceil((points[:, :2].max(axis=0) + margin - origin) / RESOLUTION) + 1)
    inside = points[(points[:, 2] >= BAND[0]) & (points[:, 2] <= BAND[1])]
    cell = np.floor((inside[:, :2] - origin) / RESOLUTION).astype(np.int64)
    flat = cell[:, 0] * shape[1] + cell[:, 1]
    low = np.full(shape[0] * shape[1], EMPTY_LOW, dtype=np.float32)
    high = np.zeros(shape[0] * shape[1], dtype=np.float32)
    np.minimum.at(low, flat, inside[:, 2].astype(np.float32))
    np.maximum.at(high, flat, inside[:, 2].astype(np.float32))
    return FineColumns(origin, RESOLUTION, low.reshape(shape), high.reshape(shape))


def column_reads(
    columns: FineColumns, x: np.ndarray, y: np.ndarray, theta: np.ndarray, feet: np.ndarray
) -> np.ndarray:
    """(n, N_FEATURES) float32: each pose's lowest then highest surfaces at the FORWARD x ACROSS points of its
    frame, as heights above its feet (`feet`: the height its skeleton's feet stand at, 0 on the floor);
    points off the maps read as empty columns."""
    u, v = (a.ravel() / columns.resolution for a in np.meshgrid(FORWARD, ACROSS, indexing="ij"))
    c, s = np.cos(theta)[:, None], np.sin(theta)[:, None]
    # in cells, float32: a 5 cm cell stays exact to far under a millimetre over hundreds of metres
    fi = ((x - columns.origin[0]) / columns.resolution)[:, None].astype(np.float32) + (u * c - v * s)
    fj = ((y - columns.origin[1]) / columns.resolution)[:, None].astype(np.float32) + (u * s + v * c)
    nx, ny = columns.low.shape
    on = (fi >= 0) & (fi < nx) & (fj >= 0) & (fj < ny)
    # a point off the maps reads one more cell after the last, an empty one
    flat = np.where(on, fi.astype(np.int64) * ny + fj.astype(np.int64), nx * ny)
    heights = np.empty((2, nx * ny + 1), dtype=np.float32)
    heights[0, :-1], heights[1, :-1], heights[:, -1] = (
        columns.low.ravel(),
        columns.high.ravel(),
        (EMPTY_LOW, 0),
    )
    lift = feet[:, None].astype(np.float32)
    out = np.empty((len(x), N_FEATURES), dtype=np.float32)
    half = N_FEATURES // 2
    low, high = heights[0][flat], heights[1][flat]
    # an empty column stays empty whatever the pose's height
    np.copyto(out[:, :half], np.where(low >= EMPTY_LOW, EMPTY_LOW, low - lift))
    np.copyto(out[:, half:], np.where(high <= 0.0, 0.0, high - lift))
    return out
