"""What the sensors saw: each voxel of the fields' lattice is unknown (never seen), free (seen through) or
occupied (holds points).

A cloud says where surfaces are, not where space is empty: a voxel without points may be air the sensor
looked through, or the space behind a sofa that nothing ever saw. Scored as it stands, the second looks
as open as the first, and a skeleton can stand in it. With the positions the sensor stood at (the
assembler's frames, a generated scan's stations, a depth frame's camera) the two part: space between a
sensor and the first surface along a line of sight was seen, and is free; the rest is unknown.

How: one range image per sensor position (the range of the nearest occupied voxel in each direction, over
bins of `VisibilitySettings.angular_step` in azimuth and elevation). Each occupied voxel covers the bins
its outline spans, a square across the line of sight (more bins the nearer it is); a single empty bin
between outlines takes its nearest neighbour's range. A voxel is free when it lies at least
one voxel nearer than that image's surface in its direction. Each position is
taken to have looked all round: a camera's field of view is not known here, so space in a line of sight
counts as seen. That errs towards free only where a surface was seen from elsewhere and the space in
front of it lies in the open view of another position, which a moving sensor mostly did look through.
A direction with no surface at all (an open door, a missing return) frees nothing.

The space the sensor's carrier stood in is free too (`_carrier_space`): a robot or a person was there, from
the floor up to the sensor, within `VisibilitySettings.carrier_radius` of it, though a camera looking ahead
never sees the space at its own feet (as a planner's costmap clears the robot's footprint). Without it the
spot a robot stands on reads as never seen, and a robot could not be sent back to turn where it stood.
"""

from __future__ import annotations

import functools

import numpy as np

from ..settings import VisibilitySettings
from .fields import SceneFields, VoxelLattice, at_columns, disc

UNKNOWN, FREE, OCCUPIED = 0, 1, 2

_SPLAT_HALF_WIDTH = 0.6  # voxels: a square this wide either side covers most of a voxel's outline
_MAX_SPAN = 64  # bins across at most: a voxel nearer than that to the sensor is not drawn in full
_SINE_TABLE = 1 << 14  # entries of the elevation table: a bin 89-90 degrees up still spans one


def voxel_states(
    occupancy: np.ndarray,
    lattice: VoxelLattice,
    origins: np.ndarray,
    settings: VisibilitySettings | None = None,
) -> np.ndarray:
    """(nx, ny, nz) uint8 UNKNOWN / FREE / OCCUPIED of `occupancy` (the fields' lattice), seen from the
    sensor positions `origins` (M, 3, world frame; at most `settings.max_origins` of them are used, spread
    out by `spread_origins`)."""
    settings = settings or VisibilitySettings()
    occupied = np.asarray(occupancy) > 0
    state = np.where(occupied, OCCUPIED, UNKNOWN).astype(np.uint8)
    origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    if not len(origins) or not occupied.any():
        return state
    surface = lattice.centres(np.argwhere(occupied))
    # voxel centres along each axis, in float32: the per-position arithmetic over every voxel is what costs
    axes = [
        (lattice.origin[k] + np.arange(n, dtype=np.float64) * lattice.resolution).astype(np.float32)
        for k, n in enumerate(lattice.shape)
    ]
    free = np.zeros(occupied.shape, bool)
    for origin in spread_origins(origins, settings.max_origins):  # a few dozen at most
        image = _range_image(surface - origin, lattice.resolution, settings.angular_step)
        offsets = [axis - np.float32(o) for axis, o in zip(axes, origin)]
        _in_front(offsets, image, settings.angular_step, lattice.resolution, free)
    if settings.carrier_radius > 0:
        free[_carrier_space(occupied, lattice, origins, settings.carrier_radius)] = True
    state[free & ~occupied] = FREE
    return state


def _carrier_space(
    occupied: np.ndarray, lattice: VoxelLattice, origins: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Indices (i, j, k) of the voxels the sensors' carrier filled: in the columns within `radius` of each
    sensor position (every one of them, not only the spread-out ones), from the sensor's voxel down to just
    above the first occupied voxel under it (the floor, or a top the sensor was held over), or, where the
    scan holds nothing under it (a camera never sees its own feet), to the room's lowest surface."""
    (nx, ny, nz), cell = lattice.shape, lattice.voxel_of(origins)
    reach = int(np.floor(radius / lattice.resolution + 0.5))
    di, dj = np.nonzero(disc(reach))
    i, j = cell[:, :1] + (di - reach), cell[:, 1:2] + (dj - reach)  # (origins, disc cells)
    top = np.broadcast_to(np.minimum(cell[:, 2:], nz - 1), i.shape)
    inside = (i >= 0) & (i < nx) & (j >= 0) & (j < ny) & (top >= 0)
    highest = np.full(nx * ny, -1)
    np.maximum.at(highest, i[inside] * ny + j[inside], top[inside])  # under several: to the highest
    columns = np.flatnonzero(highest >= 0)
    ci, cj, top = columns // ny, columns % ny, highest[columns]
    k = np.arange(nz)
    below = occupied[ci, cj] & (k < top[:, None])  # (columns, nz)
    lowest_surface = int(np.argmax(occupied.any(axis=(0, 1))))
    bottom = np.where(below, k, -1).max(axis=1)
    bottom[bottom < 0] = lowest_surface
    rows, layers = np.nonzero((k > bottom[:, None]) & (k <= top[:, None]))
    return ci[rows], cj[rows], layers


def spread_origins(origins: np.ndarray, count: int) -> np.ndarray:
    """At most `count` of the positions, spread out (farthest-point order from the first): a walk's
    thousand frames see the room from a few dozen distinct places."""
    if len(origins) <= count:
        return origins
    chosen = [0]
    nearest = np.linalg.norm(origins - origins[0], axis=1)
    for _ in range(count - 1):  # `count` rounds, each vectorised over every position
        chosen.append(int(nearest.argmax()))
        nearest = np.minimum(nearest, np.linalg.norm(origins - origins[chosen[-1]], axis=1))
    return origins[chosen]


def _bins(step: float) -> tuple[int, int]:
    """Rows (elevation) and columns (azimuth) of a range image of `step` degrees."""
    return int(round(180 / step)), int(round(360 / step))


def _plan(x: np.ndarray, y: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Distance in plan and azimuth bin of offsets (x, y) from a sensor position."""
    n_az = _bins(step)[1]
    column = ((np.arctan2(y, x) + np.pi) * (1.0 / np.radians(step))).astype(np.int32)
    return np.sqrt(x * x + y * y), column % n_az


def _range_image(offsets: np.ndarray, resolution: float, step: float) -> np.ndarray:
    """(n_el, n_az): the range of the nearest surface voxel in each direction; 0 where none was seen
    (nothing is free that way). A single empty bin among surface bins (a gap between two outlines) takes its
    nearest neighbour's range."""
    from scipy import ndimage

    from .range_images import draw_outlines

    n_el, n_az = _bins(step)
    image = np.full(n_el * n_az, np.inf)
    draw_outlines(*_outlines(offsets, resolution, step), n_az, image)
    image = image.reshape(n_el, n_az)
    gaps = np.isinf(image)
    near = ndimage.minimum_filter(image, size=3, mode=("nearest", "wrap"))
    image[gaps] = near[gaps]
    image[np.isinf(image)] = 0.0
    return image


def _outlines(offsets: np.ndarray, resolution: float, step: float) -> tuple[np.ndarray, ...]:
    """The rectangle of range-image bins each surface voxel's outline covers as the sensor sees it (first
    row, rows, first column, columns; columns wrap round), and the voxel's range: the bins within
    `_SPLAT_HALF_WIDTH` voxels of its centre across the line of sight, in elevation (that width at its
    range) and in azimuth (at its distance in plan, so a voxel under the sensor spans many azimuth bins)."""
    n_el = _bins(step)[0]
    per_bin = 1.0 / np.radians(step)
    x, y, z = offsets.T
    across = np.hypot(x, y)
    distance = np.hypot(across, z)
    row = (np.arctan2(z, across) + np.pi / 2) * per_bin  # fractional bins
    column = (np.arctan2(y, x) + np.pi) * per_bin
    half = _SPLAT_HALF_WIDTH * resolution * per_bin
    half_row = np.minimum(half / np.maximum(distance, resolution), _MAX_SPAN / 2)
    half_column = np.minimum(half / np.maximum(across, resolution), _MAX_SPAN / 2)
    first_row = np.clip(np.floor(row - half_row), 0, n_el - 1).astype(np.int64)
    rows = np.clip(np.floor(row + half_row), 0, n_el - 1).astype(np.int64) - first_row + 1
    first_column = np.floor(column - half_column).astype(np.int64)
    columns = np.floor(column + half_column).astype(np.int64) - first_column + 1
    return first_row, rows, first_column, columns, distance


@functools.lru_cache(maxsize=4)
def _elevation_rows(step: float) -> np.ndarray:
    """Elevation bin by the sine of the elevation, tabulated over [-1, 1] in `_SINE_TABLE` steps: one
    lookup per voxel instead of an arctan2, at most one bin off at a bin's edge."""
    sine = np.linspace(-1.0, 1.0, _SINE_TABLE)
    rows = ((np.arcsin(sine) + np.pi / 2) * (1.0 / np.radians(step))).astype(np.int32)
    return np.minimum(rows, _bins(step)[0] - 1).astype(np.int16)


def _in_front(
    offsets: list[np.ndarray], image: np.ndarray, step: float, resolution: float, free: np.ndarray
) -> None:
    """Marks in `free` (nx, ny, nz) each voxel centre of the lattice whose centres lie at the offsets (x, y,
    z, one array per axis) from the sensor that is a voxel or more in front of the surface the range image
    holds in its direction. A voxel column shares its plan distance and azimuth: those are worked out once
    per column."""
    from .range_images import mark_in_front

    x, y, z = offsets
    across, column = _plan(x[:, None], y[None, :], step)
    to_table = np.float32((_SINE_TABLE - 1) / 2)
    mark_in_front(across, column, z, image, _elevation_rows(step), to_table, np.float32(resolution), free)


def seen_share(state: np.ndarray, lattice: VoxelLattice, low: float, high: float) -> np.ndarray:
    """(nx, ny) float: the share of each voxel column's voxels between heights `low` and `high` (m above
    the floor) that the sensors saw (free or occupied)."""
    heights = lattice.origin[2] + np.arange(lattice.shape[2]) * lattice.resolution
    band = (heights >= low - 1e-9) & (heights <= high + 1e-9)
    if not band.any():
        raise ValueError(f"no voxel layer between {low} and {high} m")
    return (state[:, :, band] != UNKNOWN).mean(axis=2)


def body_seen(fields: SceneFields, x: np.ndarray, y: np.ndarray, settings: VisibilitySettings) -> np.ndarray:
    """(len(x), len(y)) float: how much of the body space of a place at each (x, y) the sensors saw: the
    `seen_share` of the voxel columns within `settings.seen_radius`, between `seen_low` and `seen_high`.
    Raises ValueError when the fields carry no visibility (a cloud without sensor positions)."""
    from scipy import ndimage

    if fields.visibility is None:
        raise ValueError("these fields carry no visibility: the cloud came without sensor positions")
    lattice = fields.lattice
    share = seen_share(fields.visibility, lattice, settings.seen_low, settings.seen_high)
    reach = int(round(settings.seen_radius / lattice.resolution))
    footprint = disc(reach).astype(float)
    # beyond the lattice nothing was seen: the disc's mean counts it as unseen
    share = ndimage.convolve(share, footprint / footprint.sum(), mode="constant", cval=0.0)
    return at_columns(share, lattice, x, y)


def compile_range_images() -> None:
    """Compile the range images' kernels now (or read them from numba's cache) on a lattice of one occupied
    voxel, with the argument types `voxel_states` passes, so that a service's first fields do not wait."""
    occupancy = np.zeros((3, 3, 3), np.uint8)
    occupancy[1, 1, 1] = 1
    voxel_states(occupancy, VoxelLattice(np.zeros(3), 0.1, (3, 3, 3)), np.array([[0.0, 0.0, 0.1]]))
