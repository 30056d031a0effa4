"""Voxel fields of a room: occupancy, Euclidean distance transform and surface normals.

The lattice puts voxel centres at whole multiples of the resolution (voxel (i, j, k) is centred at
``origin + (i, j, k) * resolution``), so the floor at z = 0 lies in the middle of one voxel layer rather than
on a boundary where noise would split it between two.

Normals. Estimated normals have no sign: a surface seen from both sides gives n and -n, and a plain mean
cancels. Per voxel we therefore average the *axis* n n^T (the scatter tensor) and take its principal
eigenvector, which is sign-free. The voxel's normal then gets a fixed orientation: surfaces within 60 degrees
of horizontal face up (people sit and lean on the top of things); steeper ones face the room's centre in
plan (walls face in). Voxels without points have a zero normal, so a cell average over them measures how
much surface there is as well as which way it faces.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .settings import NormalSettings, VoxelSettings

_UP_FACING_NZ = 0.5  # |n_z| above this (within 60 deg of vertical) means "faces up"


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

    @property
    def nbytes(self) -> int:
        return self.occupancy.nbytes + self.distance.nbytes + self.normals.nbytes


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
) -> SceneFields:
    """Occupancy, distance transform and normal field of a gravity-aligned cloud.

    ``normals`` (one per point) are used when given, otherwise estimated with open3d.
    """
    from scipy import ndimage

    voxel = voxel or VoxelSettings()
    normal_settings = normal_settings or NormalSettings()
    points = np.asarray(points, dtype=np.float64)
    lattice = lattice_around(points, voxel)
    flat = _flat_index(lattice, lattice.voxel_of(points))
    n_voxels = int(np.prod(lattice.shape))
    occupied = np.bincount(flat, minlength=n_voxels) > 0
    occupancy = occupied.reshape(lattice.shape).astype(np.float32)
    distance = ndimage.distance_transform_edt(~occupied.reshape(lattice.shape), sampling=lattice.resolution)
    if normals is None:
        points, normals = estimate_normals(points, normal_settings)
    field = _normal_field(lattice, points, normals, points.mean(axis=0))
    footprint = tuple(float(v) for v in (*points[:, :2].min(axis=0), *points[:, :2].max(axis=0)))
    return SceneFields(lattice, occupancy, distance.astype(np.float32), field, footprint)


def estimate_normals(points: np.ndarray, settings: NormalSettings) -> tuple[np.ndarray, np.ndarray]:
    """Thin the cloud to ``settings.downsample`` and estimate unit normals (unsigned) at the kept points."""
    import open3d as o3d

    if settings.downsample > 0:
        points = voxel_down_sample(points, settings.downsample)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pcd.estimate_normals(
        o3d.geometry.KDTreeSearchParamHybrid(radius=settings.radius, max_nn=settings.max_neighbours)
    )
    return np.asarray(pcd.points), np.asarray(pcd.normals)


def voxel_down_sample(points: np.ndarray, voxel: float) -> np.ndarray:
    """open3d's `PointCloud.voxel_down_sample`, the same points to the bit (voxels from the cloud's minimum
    less half a voxel, each voxel's points summed in order and divided by their count), 8x faster, in a
    fixed order (sorted by voxel) where open3d's follows a hash map."""
    low = points.min(axis=0) - voxel * 0.5
    keys = np.floor((points - low) / voxel).astype(np.int64)
    span = keys.max(axis=0) + 1
    flat = (keys[:, 0] * span[1] + keys[:, 1]) * span[2] + keys[:, 2]
    _, inverse, counts = np.unique(flat, return_inverse=True, return_counts=True)
    return np.stack([np.bincount(inverse, points[:, k]) for k in range(3)], axis=1) / counts[:, None]


def _flat_index(lattice: VoxelLattice, index: np.ndarray) -> np.ndarray:
    if (index < 0).any() or (index >= np.array(lattice.shape)).any():
        raise ValueError("points outside the voxel lattice")
    return np.ravel_multi_index(index.T, lattice.shape)


def _normal_field(
    lattice: VoxelLattice, points: np.ndarray, normals: np.ndarray, centre: np.ndarray
) -> np.ndarray:
    """Per voxel: the principal axis of sum(n n^T) over its points, oriented as the module docstring says."""
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
    centres = lattice.centres(np.stack(np.unravel_index(voxels, lattice.shape), axis=1))
    axis *= orientation_signs(axis, centres, centre)[:, None]
    field = np.zeros((*lattice.shape, 3), dtype=np.float32)
    field.reshape(-1, 3)[voxels] = axis
    return field


def orientation_signs(axis: np.ndarray, positions: np.ndarray, room_centre: np.ndarray) -> np.ndarray:
    """+1 or -1 per unsigned normal: face up when within 60 deg of vertical, else face the room's centre."""
    up_facing = np.abs(axis[:, 2]) > _UP_FACING_NZ
    towards_centre = np.einsum("ij,ij->i", axis[:, :2], room_centre[:2] - positions[:, :2])
    sign = np.where(up_facing, np.sign(axis[:, 2]), np.sign(towards_centre))
    return np.where(sign == 0, 1.0, sign)


def observed_floor(fields: SceneFields, x: np.ndarray, y: np.ndarray, margin: float) -> np.ndarray:
    """(len(x), len(y)) bool: whether a floor voxel (z within one voxel of 0) holds points within `margin`
    of each (x, y). Unscanned floor looks like free space to the other fields; a person's place is next to
    floor the sensor saw (seats and desks hide the floor right under them, hence the margin)."""
    from scipy import ndimage

    lattice = fields.lattice
    k0 = int(round(-lattice.origin[2] / lattice.resolution))
    seen = fields.occupancy[:, :, max(0, k0 - 1) : k0 + 2].max(axis=2) > 0
    reach = int(round(margin / lattice.resolution))
    if reach > 0:
        dy, dx = np.mgrid[-reach : reach + 1, -reach : reach + 1]
        seen = ndimage.binary_dilation(seen, dx**2 + dy**2 <= reach**2)
    ix = np.clip(np.rint((x - lattice.origin[0]) / lattice.resolution).astype(int), 0, lattice.shape[0] - 1)
    iy = np.clip(np.rint((y - lattice.origin[1]) / lattice.resolution).astype(int), 0, lattice.shape[1] - 1)
    return seen[np.ix_(ix, iy)]
