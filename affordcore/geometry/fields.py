"""Voxel fields of a room: occupancy, Euclidean distance transform and surface normals.

The lattice puts voxel centres at whole multiples of the resolution (voxel (i, j, k) is centred at
``origin + (i, j, k) * resolution``), so the floor at z = 0 lies in the middle of one voxel layer rather than
on a boundary where noise would split it between two.

Normals. Estimated normals have no sign: a surface seen from both sides gives n and -n, and a plain mean
cancels. Per voxel we therefore average the *axis* n n^T (the scatter tensor) and take its principal
eigenvector, which is sign-free. The voxel's normal then gets a fixed orientation: surfaces within 60 degrees
of horizontal face up (people sit and lean on the top of things); steeper ones (`NormalSettings.steep_facing`)
face the room's centre in plan, the cloud's mean point (`centre`, the default: walls face in), or the side
with more scanned floor around them (`floor`: walls face the room, whose floor the sensor saw; a sofa's back
faces the seat and the floor in front of it). The floor rule is local, so a room that grows flips no normal
far from the growth (affordcore.mapping.updates); the mean point moves with every scan and flips faces metres
away.
Voxels without points have a zero normal, so a cell average over them measures how much surface there is as
well as which way it faces.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from functools import partial

import numpy as np

from ..settings import NormalSettings, VoxelSettings
from .cells import cell_sums
from .columns import FineColumns, fine_columns

_UP_FACING_NZ = 0.5  # |n_z| above this (within 60 deg of vertical) means "faces up"
# a steep surface faces the side whose disc of this radius (m), this far out (m), holds more scanned floor
_FLOOR_DISC, _FLOOR_LOOK = 0.4, 0.6
_CROWD_BOX = 2.0  # m: where no floor decides, the side whose square of this edge holds more columns does
_EXACT_REACH = 0.5  # m: soft fields measure distances to the points themselves up to this far from a surface


@dataclass(frozen=True)
class VoxelLattice:
    origin: np.ndarray  # centre of voxel (0, 0, 0), metres
    resolution: float
    shape: tuple[int, int, int]

    def continuous_index(self, points: np.ndarray) -> np.ndarray:
        """Position in voxel units, voxel centres at whole numbers."""
        return (np.asarray(points, dtype=np.float64) - self.origin) / self.resolution

    def voxel_of(self, points: np.ndarray) -> np.ndarray:
        """Index of the voxel containing each point (may lie outside the lattice)."""
        return np.floor(self.continuous_index(points) + 0.5).astype(np.int64)

    def centres(self, index: np.ndarray) -> np.ndarray:
        return self.origin + np.asarray(index, dtype=np.float64) * self.resolution

    @property
    def upper(self) -> np.ndarray:
        return self.origin + (np.array(self.shape) - 1) * self.resolution


@dataclass
class SceneFields:
    lattice: VoxelLattice
    occupancy: np.ndarray  # (nx, ny, nz) float32, 1 where a voxel holds points
    distance: np.ndarray  # (nx, ny, nz) float32, metres from the voxel centre to the nearest occupied centre
    normals: np.ndarray  # (nx, ny, nz, 3) float32, unit where a surface is, else 0
    footprint: tuple[float, float, float, float]  # the cloud's x_min, y_min, x_max, y_max
    steep_facing: str = "centre"  # which way steep normals face (`NormalSettings.steep_facing`)
    # (nx, ny, nz) uint8 `visibility` states (unknown, free, occupied) when the sensor positions are known;
    # None when the cloud came without them (a file): then unknown space cannot be told from free
    visibility: np.ndarray | None = None
    # (nx, ny, nz) float32 in [0, 1], soft fields only (`VoxelSettings.fields`): how near the nearest point
    # comes to each voxel centre, what the collision feature reads; `occupancy` stays the binary state that
    # decides where the floor was seen and what was scanned
    soft_occupancy: np.ndarray | None = None
    normal_estimator: str = "cube"  # how the normals were estimated (`NormalSettings.estimator`)
    # the lowest and highest surface over each 5 cm column (`columns`): what a second stage may read finer
    # than the voxels; None in fields made before they were kept, or sent without them
    columns: FineColumns | None = None

    @property
    def nbytes(self) -> int:
        extras = (a.nbytes for a in (self.visibility, self.soft_occupancy, self.columns) if a is not None)
        return self.occupancy.nbytes + self.distance.nbytes + self.normals.nbytes + sum(extras)

    @property
    def collision(self) -> np.ndarray:
        """The occupancy the collision feature reads: the soft one when the fields are soft."""
        return self.occupancy if self.soft_occupancy is None else self.soft_occupancy


def disc(reach: int) -> np.ndarray:
    """(2 reach + 1, 2 reach + 1) bool: the cells within `reach` cells of the centre, a round footprint
    for dilations and means over a plan."""
    di, dj = np.mgrid[-reach : reach + 1, -reach : reach + 1]
    return di**2 + dj**2 <= reach**2


def lattice_around(points: np.ndarray, settings: VoxelSettings) -> VoxelLattice:
    """A lattice covering the cloud, the floor and the space up to ``min_height``, with a margin all round."""
    res = settings.resolution
    if len(points) == 0 or not np.isfinite(points).all():
        raise ValueError("the fields need a non-empty cloud of finite points")
    low = points.min(axis=0)
    high = points.max(axis=0)
    low[2] = min(low[2], 0.0)
    high[2] = max(high[2], settings.min_height)
    first = np.floor((low - settings.margin) / res)
    last = np.ceil((high + settings.margin) / res)
    counts = last - first + 1
    # counted in floats: a hostile cloud's extent must not overflow the check that refuses it
    if float(np.prod(counts)) > settings.max_voxels:
        size = " x ".join(f"{v:.4g}" for v in high - low)
        raise ValueError(
            f"the cloud spans {size} m: {float(np.prod(counts)):.3g} voxels at {res} m, above "
            f"AFFORD_VOXEL__MAX_VOXELS ({settings.max_voxels:,})"
        )
    return VoxelLattice(first * res, res, tuple(int(n) for n in counts))


def compute_fields(
    points: np.ndarray,
    voxel: VoxelSettings | None = None,
    normal_settings: NormalSettings | None = None,
    normals: np.ndarray | None = None,
    estimator=None,
) -> SceneFields:
    """Occupancy, distance transform and normal field of a gravity-aligned cloud.

    ``normals`` (one per point) are used when given, otherwise the cloud is thinned and normals estimated by
    ``estimator(points, normal_settings) -> (thinned points, normals)``: `estimate_normals`, or a
    `updates.NormalCache` that re-estimates only where the cloud changed.
    """
    from scipy import ndimage

    voxel = voxel or VoxelSettings()
    normal_settings = normal_settings or NormalSettings()
    points = np.asarray(points, dtype=np.float64)
    lattice = lattice_around(points, voxel)
    columns = fine_columns(points)
    flat = _flat_index(lattice, lattice.voxel_of(points))
    n_voxels = int(np.prod(lattice.shape))
    occupied = np.bincount(flat, minlength=n_voxels) > 0
    occupancy = occupied.reshape(lattice.shape).astype(np.float32)
    distance = ndimage.distance_transform_edt(~occupied.reshape(lattice.shape), sampling=lattice.resolution)
    if normals is None:
        points, normals = (estimator or estimate_normals)(points, normal_settings)
    if normal_settings.steep_facing == "floor":
        steep = partial(towards_floor, floor=floor_density(occupancy, lattice), resolution=lattice.resolution)
    else:
        steep = partial(towards_centre, lattice=lattice, centre=points.mean(axis=0))
    footprint = tuple(float(v) for v in (*points[:, :2].min(axis=0), *points[:, :2].max(axis=0)))
    if voxel.fields == "soft":
        corners = list(_corner_weights(lattice, points))  # what both the occupancy and the normals spread
        soft = soft_occupancy(lattice, corners)
        field = _normal_field(lattice, points, normals, steep, corners) * soft[..., None]
        distance = distance_to_points(lattice, points, distance)
        return SceneFields(
            lattice, occupancy, distance, field, footprint, normal_settings.steep_facing,
            soft_occupancy=soft, normal_estimator=normal_settings.estimator, columns=columns,
        )  # fmt: skip
    field = _normal_field(lattice, points, normals, steep)
    return SceneFields(
        lattice, occupancy, distance.astype(np.float32), field, footprint, normal_settings.steep_facing,
        normal_estimator=normal_settings.estimator, columns=columns,
    )  # fmt: skip


# Soft fields (`VoxelSettings.fields = "soft"`). Binary fields quantise the room to the lattice: a table's
# edge 4 cm into a voxel and 6 cm into it are different rooms to them, and the lattice is anchored in the
# world, so where a robot's frame puts the room changes the features (docs/accuracy.md, "Where the room sits
# on the grid"). Soft fields let each point weigh on the voxels around it by how near their centres it lies,
# so they change continuously as the room moves against the lattice.


def _corner_weights(lattice: VoxelLattice, points: np.ndarray) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """For each of the 8 voxel centres around every point: (flat voxel index, trilinear weight) per point."""
    index = lattice.continuous_index(points)
    base = np.floor(index).astype(np.int64)
    fraction = index - base
    for corner in np.ndindex(2, 2, 2):
        offset = np.array(corner)
        weight = np.prod(np.where(offset, fraction, 1 - fraction), axis=1)
        yield _flat_index(lattice, base + offset), weight


def soft_occupancy(lattice: VoxelLattice, corners: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """(nx, ny, nz) float32 from the points' `_corner_weights`: per voxel, the largest trilinear weight any
    point gives its centre, the product over the axes of 1 - |offset| in voxels. 1 for a point at the
    centre, 0.5 for a surface on a face between two voxels, falling to 0 a voxel away; the most of any
    point, so it does not grow with the cloud's density as a sum would."""
    occupancy = np.zeros(int(np.prod(lattice.shape)), dtype=np.float64)
    for flat, weight in corners:
        np.maximum.at(occupancy, flat, weight)
    return occupancy.reshape(lattice.shape).astype(np.float32)


def distance_to_points(lattice: VoxelLattice, points: np.ndarray, voxel_distance: np.ndarray) -> np.ndarray:
    """(nx, ny, nz) float32: the distance from each voxel centre within `_EXACT_REACH` of a surface to the
    nearest point (m), the binary fields' distance to the nearest occupied voxel's centre (`voxel_distance`)
    beyond: the joints that touch or near a surface are the ones whose distance decides a pose, and the
    search's cost grows steeply with its reach (docs/geometry.md measures it)."""
    from scipy.spatial import cKDTree

    distance = voxel_distance.astype(np.float32)
    near = np.flatnonzero(voxel_distance.ravel() <= _EXACT_REACH)
    # the nearest point lies within a voxel's diagonal of the nearest occupied centre (half of it for a
    # point of that voxel; the rest covers thinned points, means that may cross a face)
    bound = _EXACT_REACH + np.sqrt(3) * lattice.resolution
    centres = lattice.centres(np.stack(np.unravel_index(near, lattice.shape), axis=1))
    exact, _ = cKDTree(points).query(centres, distance_upper_bound=bound, workers=-1)
    distance.ravel()[near] = np.minimum(exact, bound)
    return distance


def estimate_normals(points: np.ndarray, settings: NormalSettings) -> tuple[np.ndarray, np.ndarray]:
    """Thin the cloud to ``settings.downsample`` and estimate unit normals (unsigned) at the kept points."""
    if settings.downsample > 0:
        points = voxel_down_sample(points, settings.downsample)
    return points, normals_at(points, settings)


def normals_at(points: np.ndarray, settings: NormalSettings) -> np.ndarray:
    """Unit normals (unsigned) of a cloud at its points, by `settings.estimator`: the principal axes of each
    point's nearest `max_neighbours` within `radius` as open3d's `estimate_normals` computes them
    (`normals.pca_normals`), or of the points of the cube around its nearest lattice vertex
    (`normals.cube_normals`)."""
    from .normals import cube_normals, pca_normals

    if settings.estimator == "cube":
        return cube_normals(points, settings.radius)
    return pca_normals(points, settings.radius, settings.max_neighbours)


def voxel_down_sample(points: np.ndarray, voxel: float) -> np.ndarray:
    """The mean of the points in each cell of a world-anchored lattice of `voxel` cells (cell (i, j, k) spans
    [i - 1/2, i + 1/2) x voxel along each axis: centred on multiples of `voxel`, like the voxel lattice, so
    the floor at z = 0 lies mid-cell and not on a face, where a levelling a hair off would split it), sorted
    by cell. Like open3d's `PointCloud.voxel_down_sample`, 8x
    faster, except that open3d anchors its cells at the cloud's minimum: there, a point added beyond the
    minimum moves every cell and every thinned point of the room, here only its own cell changes (map
    updates rely on that, affordcore.mapping.updates)."""
    return thin_cells(points, voxel)[0]


def thin_cells(points: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """(`voxel_down_sample`'s means, each one's cell as one int64 key: `cell_keys` of its (i, j, k)), sorted
    by key."""
    unique, sums, counts = cell_sums(points, voxel)
    return sums / counts[:, None], unique


def _flat_index(lattice: VoxelLattice, index: np.ndarray) -> np.ndarray:
    if (index < 0).any() or (index >= np.array(lattice.shape)).any():
        raise ValueError("points outside the voxel lattice")
    return np.ravel_multi_index(index.T, lattice.shape)


def _normal_field(
    lattice: VoxelLattice, points: np.ndarray, normals: np.ndarray, steep, corners: list | None = None
) -> np.ndarray:
    """Per voxel: the principal axis of sum(n n^T) over its points, oriented as the module docstring says
    (`steep(axis, columns)`: the signs that orient steep axes, `towards_centre` or `towards_floor`). Given the
    points' `corners` (`_corner_weights`, soft fields) each point adds its n n^T to the 8 voxels around it by
    trilinear weight."""
    if corners is not None:
        voxels, scatter = _spread_scatter(lattice, corners, normals)
    else:
        flat = _flat_index(lattice, lattice.voxel_of(points))
        voxels, inverse = np.unique(flat, return_inverse=True)
        scatter = np.empty((len(voxels), 3, 3))
        for a in range(3):
            for b in range(a, 3):
                scatter[:, a, b] = scatter[:, b, a] = np.bincount(
                    inverse, normals[:, a] * normals[:, b], len(voxels)
                )
    _, vectors = np.linalg.eigh(scatter)
    axis = vectors[:, :, -1]  # eigenvector of the largest eigenvalue
    index = np.stack(np.unravel_index(voxels, lattice.shape), axis=1)
    axis *= orientation_signs(axis, steep(axis, index[:, :2]))[:, None]
    field = np.zeros((*lattice.shape, 3), dtype=np.float32)
    field.reshape(-1, 3)[voxels] = axis
    return field


def _spread_scatter(
    lattice: VoxelLattice, corners: list, normals: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(flat indices of the voxels the points weigh on, each one's sum of n n^T over the points around it
    by trilinear weight (voxels, 3, 3)). Sums run over those voxels only, numbered densely: a few times
    the occupied voxels, where the lattice holds ten times more."""
    touched = np.zeros(int(np.prod(lattice.shape)), dtype=bool)
    for flat, weight in corners:
        touched[flat[weight > 0]] = True
    voxels = np.flatnonzero(touched)
    number = np.cumsum(touched) - 1  # a touched voxel's place in `voxels`
    pairs = [(a, b) for a in range(3) for b in range(a, 3)]
    products = [normals[:, a] * normals[:, b] for a, b in pairs]
    scatter = np.zeros((len(voxels), 3, 3))
    for flat, weight in corners:
        index = number[flat]
        for (a, b), product in zip(pairs, products, strict=True):
            scatter[:, a, b] += np.bincount(index, weight * product, len(voxels))
    return voxels, scatter + np.triu(scatter, 1).transpose(0, 2, 1)


def floor_seen(occupancy: np.ndarray, lattice: VoxelLattice) -> np.ndarray:
    """(nx, ny) bool: a floor voxel (z within one voxel of 0) holds points."""
    k0 = int(round(-lattice.origin[2] / lattice.resolution))
    return occupancy[:, :, max(0, k0 - 1) : k0 + 2].max(axis=2) > 0


def floor_density(occupancy: np.ndarray, lattice: VoxelLattice) -> np.ndarray:
    """(nx, ny) float32: the fraction of scanned floor in the disc of `_FLOOR_DISC` around each column, plus a
    thousandth of the fraction of columns holding anything in the `_CROWD_BOX` around it: where the floor is
    hidden on both sides of a surface, the side with more in it (the room's, not the unseen space behind a
    wall) breaks the tie (a difference of one floor voxel outweighs it)."""
    from scipy import ndimage

    reach = max(1, int(round(_FLOOR_DISC / lattice.resolution)))
    footprint = disc(reach).astype(np.float32)
    floor = ndimage.correlate(
        floor_seen(occupancy, lattice).astype(np.float32),
        footprint / footprint.sum(),
        mode="constant",
        cval=0.0,
    )
    columns = (occupancy.max(axis=2) > 0).astype(np.float32)
    box = 2 * int(round(_CROWD_BOX / 2 / lattice.resolution)) + 1
    crowd = ndimage.uniform_filter(columns, size=box, mode="constant", cval=0.0)
    return floor + np.float32(1e-3) * crowd


def orientation_signs(axis: np.ndarray, steep: np.ndarray) -> np.ndarray:
    """+1 or -1 per unsigned normal: face up when within 60 deg of vertical, else take the `steep` sign."""
    up_facing = np.abs(axis[:, 2]) > _UP_FACING_NZ
    sign = np.where(up_facing, np.sign(axis[:, 2]), np.sign(steep))
    return np.where(sign == 0, 1.0, sign)


def towards_centre(
    axis: np.ndarray, columns: np.ndarray, lattice: VoxelLattice, centre: np.ndarray
) -> np.ndarray:
    """The sign that turns each axis at voxel columns (n, 2) to face `centre` in plan."""
    plan = lattice.origin[:2] + columns * lattice.resolution
    return np.sign(np.einsum("ij,ij->i", axis[:, :2], centre[:2] - plan))


def towards_floor(axis: np.ndarray, columns: np.ndarray, floor: np.ndarray, resolution: float) -> np.ndarray:
    """The sign that turns each axis at voxel columns (n, 2) to the side with more scanned floor `_FLOOR_LOOK`
    out (`floor`: `floor_density`); on a tie (nothing scanned on either side) the horizontal part's larger
    component is made positive, a fixed local choice."""
    from scipy.ndimage import map_coordinates

    plan = axis[:, :2] / np.maximum(np.linalg.norm(axis[:, :2], axis=1, keepdims=True), 1e-12)
    look = plan * (_FLOOR_LOOK / resolution)

    def floor_at(offset: np.ndarray) -> np.ndarray:  # bilinear: no rounding rule to break symmetry
        return map_coordinates(floor, (columns + offset).T, order=1, mode="nearest")

    ahead, behind = floor_at(look), floor_at(-look)
    larger = np.take_along_axis(plan, np.abs(plan).argmax(axis=1)[:, None], axis=1)[:, 0]
    return np.where(np.abs(ahead - behind) > 1e-6, np.sign(ahead - behind), np.sign(larger))


def observed_floor(fields: SceneFields, x: np.ndarray, y: np.ndarray, margin: float) -> np.ndarray:
    """(len(x), len(y)) bool: whether a floor voxel (z within one voxel of 0) holds points within `margin`
    of each (x, y). Unscanned floor looks like free space to the other fields; a person's place is next to
    floor the sensor saw (seats and desks hide the floor right under them, hence the margin)."""
    from scipy import ndimage

    lattice = fields.lattice
    seen = floor_seen(fields.occupancy, lattice)
    reach = int(round(margin / lattice.resolution))
    if reach > 0:
        seen = ndimage.binary_dilation(seen, disc(reach))
    return at_columns(seen, lattice, x, y)


def scanned_cells(fields: SceneFields, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(len(x), len(y)) bool: whether the sensor saw anything in each (x, y)'s voxel column: scanned floor,
    or a surface above it (a seat or a table top hides the floor under it, yet the place was seen). A column
    with neither was never looked at: unknown, not empty."""
    return at_columns(fields.occupancy.any(axis=2), fields.lattice, x, y)


def mapped_cells(
    fields: SceneFields, x: np.ndarray, y: np.ndarray, margin: float, scanned: np.ndarray | None = None
) -> np.ndarray:
    """(len(x), len(y)) bool: the cells a place may stand on. Near scanned floor (`observed_floor`), and with
    `scanned` (`scanned_cells` of the same cells) also where a scanned surface hides the floor: a table place
    whose chair is pushed in, or a seat, has its floor in the shadow of what the sensor did see. A column
    where nothing at all was seen stays unmapped: no phantom place in a region the scan never reached."""
    mapped = observed_floor(fields, x, y, margin)
    return mapped if scanned is None else mapped | scanned


def at_columns(plan: np.ndarray, lattice: VoxelLattice, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(len(x), len(y)): `plan` (one value per voxel column) at the column under each (x, y), the lattice's
    edge columns for positions beyond it."""
    ix = np.clip(np.rint((x - lattice.origin[0]) / lattice.resolution).astype(int), 0, lattice.shape[0] - 1)
    iy = np.clip(np.rint((y - lattice.origin[1]) / lattice.resolution).astype(int), 0, lattice.shape[1] - 1)
    return plan[np.ix_(ix, iy)]
