"""Per-pose features (DESIGN.md, "Features of one pose"), computed slab by slab for millions of poses.

One feature vector, in this order:

* ``dist:<JOINT>`` (15): the distance transform at each placed joint (m), truncated at ``distance_cap`` when
  the layout sets one;
* ``coll:<JOINT>`` (15): the occupancy at each placed joint, a fraction in [0, 1];
* ``normal:<i>,<j>,<k>:<axis>`` (3 per cell): the mean surface normal of each cell of a cube of
  ``cube_size`` around the torso, cells indexed along the skeleton's own x (forward), y (left), z (up) and
  C-ordered, the normal expressed in the skeleton frame (it turns with theta).

Fields are read by trilinear interpolation between voxel centres. That makes every feature a continuous
function of the pose (no ties at voxel faces), the collision feature the occupied fraction of a voxel-sized
box around the joint, and a cell's normal, for a cell the size of a voxel, exactly the overlap-weighted mean
of the voxels it covers (for larger cells, the mean over a lattice of such samples at voxel spacing).

Speed. Every pose of a (z, theta) slab places its joints and cube cells at the same offsets from its own
(x, y), and pose positions step by whole voxels, so each feature column of a slab is one shifted, strided
slice of a field (bilinear: at most four). No per-pose work at all: with the paper's 10 cm cells the cost is
mostly writing the long normal-cube rows; with coarser cells, reading the samples. The z part of the
interpolation depends only on the torso height, so it is done once per z level. Measured in
benchmarks/bench_features.py (docs/benchmarks.md).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from ..settings import NORMAL_ESTIMATORS, STEEP_FACINGS, Settings
from .fields import SceneFields
from .grid import PoseGrid
from .skeleton import JOINTS, Skeleton, rotation_z

FEATURE_VERSION = 1
# how the normal field is oriented (`NormalSettings.steep_facing`, affordcore.geometry.fields): in the
# fingerprint
_NORMAL_RULES = {
    "centre": "scatter-tensor principal axis; up if |n_z| > 0.5 else towards the room centre in plan",
    "floor": "scatter-tensor principal axis; up if |n_z| > 0.5 else towards more scanned floor "
    "(0.4 m disc 0.6 m out), ties to more occupied columns (2 m square)",
}


@dataclass(frozen=True)
class FeatureLayout:
    """What one feature vector holds; its `fingerprint` ties models to the code that made their features."""

    cube_size: float = 1.0
    cell_size: float = 0.10
    voxel_resolution: float = 0.10
    # Distances beyond this read as this (m); None: the paper's untruncated distance. Truncated, a surface
    # changes the distance feature only within the cap of itself, so a change of the room changes the scores
    # only near it (affordcore.mapping.updates); beyond a skeleton's reach a distance says little about a
    # pose.
    distance_cap: float | None = None
    # which way steep normals face (`NormalSettings.steep_facing`): the fields must be computed with the same
    steep_facing: str = "centre"
    # fields of `VoxelSettings.fields` "soft" (True) or "binary"
    soft_fields: bool = False
    # how the normals are estimated (`NormalSettings.estimator`; its default)
    normal_estimator: str = "cube"

    def __post_init__(self) -> None:
        if self.distance_cap is not None and not self.distance_cap > 0:
            raise ValueError(f"distance_cap must be positive or None, not {self.distance_cap}")
        if self.steep_facing not in STEEP_FACINGS:
            raise ValueError(f"steep_facing is one of {list(STEEP_FACINGS)}, not {self.steep_facing!r}")
        if self.normal_estimator not in NORMAL_ESTIMATORS:
            raise ValueError(
                f"normal_estimator is one of {list(NORMAL_ESTIMATORS)}, not {self.normal_estimator!r}"
            )
        cells = self.cube_size / self.cell_size
        if abs(cells - round(cells)) > 1e-6 or round(cells) < 1:
            raise ValueError(f"cube_size {self.cube_size} is not a whole number of cells of {self.cell_size}")

    @classmethod
    def from_settings(cls, settings: Settings) -> FeatureLayout:
        features = settings.features
        return cls(
            features.cube_size,
            features.cell_size,
            settings.voxel.resolution,
            features.distance_cap,
            settings.normals.steep_facing,
            settings.voxel.fields == "soft",
            settings.normals.estimator,
        )

    @property
    def cells_per_axis(self) -> int:
        return round(self.cube_size / self.cell_size)

    @property
    def samples_per_cell(self) -> int:
        """Samples per cell along each axis, at about voxel spacing."""
        return max(1, round(self.cell_size / self.voxel_resolution))

    @property
    def samples_per_axis(self) -> int:
        return self.cells_per_axis * self.samples_per_cell

    @property
    def n_cells(self) -> int:
        return self.cells_per_axis**3

    @property
    def n_features(self) -> int:
        return 2 * len(JOINTS) + 3 * self.n_cells

    def sample_positions(self) -> np.ndarray:
        """Sample coordinates along one cube axis, relative to the torso (uniform, cell-aligned)."""
        n = self.samples_per_axis
        return -self.cube_size / 2 + (np.arange(n) + 0.5) * self.cube_size / n

    def cell_centres(self) -> np.ndarray:
        """(n_cells, 3) cell centres in the skeleton frame, in feature order."""
        n = self.cells_per_axis
        axis = -self.cube_size / 2 + (np.arange(n) + 0.5) * self.cell_size
        return np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)

    def names(self) -> list[str]:
        n = self.cells_per_axis
        cells = [
            f"normal:{i},{j},{k}:{a}" for i in range(n) for j in range(n) for k in range(n) for a in "xyz"
        ]
        return [f"dist:{j}" for j in JOINTS] + [f"coll:{j}" for j in JOINTS] + cells

    def describe(self) -> dict:
        described = {
            "version": FEATURE_VERSION,
            "joints": list(JOINTS),
            "blocks": ["dist", "coll", "normal"],
            "cube_size": self.cube_size,
            "cell_size": self.cell_size,
            "voxel_resolution": self.voxel_resolution,
            "n_features": self.n_features,
            "sampling": "trilinear",
            "normals": _NORMAL_RULES[self.steep_facing],
        }
        if self.distance_cap is not None:  # absent for the paper's distance: layout-1 fingerprints still hold
            described["distance_cap"] = self.distance_cap
        if self.soft_fields:  # likewise absent for binary fields
            described["fields"] = "soft: trilinear point weights, distance to the nearest point"
        if self.normal_estimator == "cube":  # and for the nearest neighbours' normals
            described["normal_estimator"] = "cube of the radius around the nearest lattice vertex"
        return described

    @property
    def fingerprint(self) -> str:
        return hashlib.sha256(json.dumps(self.describe(), sort_keys=True).encode()).hexdigest()[:16]


@dataclass
class FeatureChunk:
    """Features of the contiguous pose range [start, stop): rows of one (z, theta) slab."""

    start: int
    stop: int
    iz: int
    itheta: int
    rows: slice  # x indices of the slab
    values: np.ndarray  # (stop - start, n_features) float32


class ReachError(ValueError):
    """Placed joints or cube cells fall outside the voxel fields."""


def iter_features(
    fields: SceneFields,
    skeleton: Skeleton,
    grid: PoseGrid,
    layout: FeatureLayout,
    chunk_mb: float = 256.0,
    reuse_buffer: bool = False,
) -> Iterator[FeatureChunk]:
    """Features of every pose of the grid, in pose order, a bounded chunk at a time.

    With ``reuse_buffer`` every chunk's values live in one array that the next chunk overwrites: copy what
    you keep. It saves the page faults of a fresh chunk-sized array per chunk.
    """
    sampler = _SlabSampler(fields, grid, layout)
    nz, nt, nx, ny = grid.shape
    row_bytes = ny * layout.n_features * 4
    rows_per_chunk = max(1, min(nx, int(chunk_mb * 2**20 // row_bytes)))
    buffer = np.empty((rows_per_chunk, ny, layout.n_features), dtype=np.float32) if reuse_buffer else None
    for iz in range(nz):
        level = sampler.level(grid.z[iz], skeleton)
        for it in range(nt):
            slab = sampler.slab(level, skeleton, grid.theta[it])
            for x0 in range(0, nx, rows_per_chunk):
                rows = slice(x0, min(nx, x0 + rows_per_chunk))
                start = ((iz * nt + it) * nx + rows.start) * ny
                values = slab.features(rows, None if buffer is None else buffer[: rows.stop - rows.start])
                yield FeatureChunk(start, start + len(values), iz, it, rows, values)


def compute_features(
    fields: SceneFields, skeleton: Skeleton, grid: PoseGrid, layout: FeatureLayout, max_mb: float = 2048.0
) -> np.ndarray:
    """Every pose's features as one (n_poses, n_features) array; for grids that fit in ``max_mb``."""
    size_mb = grid.size * layout.n_features * 4 / 2**20
    if size_mb > max_mb:
        raise MemoryError(
            f"{grid.size} poses x {layout.n_features} features is {size_mb:.0f} MB (limit {max_mb:.0f} MB); "
            "use iter_features"
        )
    out = np.empty((grid.size, layout.n_features), dtype=np.float32)
    for chunk in iter_features(fields, skeleton, grid, layout, reuse_buffer=True):
        out[chunk.start : chunk.stop] = chunk.values
    return out


def features_at(
    fields: SceneFields,
    skeleton: Skeleton,
    grid: PoseGrid,
    layout: FeatureLayout,
    index: np.ndarray,
) -> np.ndarray:
    """Features of the given poses only (flat grid indices), (len(index), n_features) float32, rows in the
    order given: the same values as the grid's rows from `iter_features` (normals rotated and cells summed
    after the read rather than before, so equal up to float32 rounding).

    For the second stage and for sampled training sets, so the cost follows the number of poses asked for,
    not the grid. The bilinear corners and weights of each joint and normal sample depend only on the pose's
    theta, so they are tabled per theta; the fields, interpolated in z once per torso height that has a pose,
    are stacked by level, and a compiled kernel reads each pose's row from them (`pose_reads`)."""
    index = np.asarray(index, dtype=np.int64).ravel()
    if len(index) and (index.min() < 0 or index.max() >= grid.size):
        raise IndexError(f"pose indices must lie in [0, {grid.size}) for this grid")
    if not len(index):
        return np.empty((0, layout.n_features), dtype=np.float32)
    sampler = _SlabSampler(fields, grid, layout)
    iz, it, ix, iy = np.unravel_index(index, grid.shape)
    z_used, level_of = np.unique(iz, return_inverse=True)
    theta_used, theta_of = np.unique(it, return_inverse=True)
    reader = _PoseReader(sampler, skeleton, [grid.z[z] for z in z_used], grid.theta[theta_used])
    return reader.features(level_of, theta_of, ix, iy)


class _PoseReader:
    """Bilinear reads of z-interpolated fields at scattered poses: `features_at`'s engine."""

    def __init__(self, sampler: _SlabSampler, skeleton: Skeleton, torso_heights, thetas: np.ndarray):
        self.layout, self.stride = sampler.layout, sampler.stride
        levels = [sampler.level(z, skeleton) for z in torso_heights]
        # (levels * X * Y, values per position): one row per voxel column of one level
        self.fields = {
            name: np.stack([level[name] for level in levels]).reshape(
                len(levels) * sampler.shape[0] * sampler.shape[1], -1
            )
            for name in ("distance", "occupancy", "normals")
        }
        self.columns = sampler.shape[1]  # y extent: x steps a row index by this much
        self.per_level = sampler.shape[0] * sampler.shape[1]
        rotations = np.stack([rotation_z(theta) for theta in thetas])  # (T, 3, 3)
        self.rotations = rotations.astype(np.float32)
        axis = self.layout.sample_positions()
        sample_xy = np.stack(np.meshgrid(axis, axis, indexing="ij"), axis=-1).reshape(-1, 2)
        joint_xy = np.einsum("jk,tlk->tjl", skeleton.joints, rotations)[:, :, :2]  # (T, joints, 2)
        sample_xy = np.einsum("sk,tlk->tsl", sample_xy, rotations[:, :2, :2])  # (T, samples, 2)
        self.joint_corners = _corner_table(sampler, joint_xy)
        self.sample_corners = _corner_table(sampler, sample_xy)

    def features(self, level: np.ndarray, theta: np.ndarray, ix: np.ndarray, iy: np.ndarray) -> np.ndarray:
        from .pose_reads import read_rows

        base = level * self.per_level + (ix * self.stride) * self.columns + iy * self.stride  # (n,)
        out = np.empty((len(base), self.layout.n_features), dtype=np.float32)
        read_rows(
            base, theta, self.fields["distance"], self.fields["occupancy"], self.fields["normals"],
            *self.joint_corners, *self.sample_corners, self.layout.cells_per_axis,
            self.layout.samples_per_cell, out,
        )  # fmt: skip
        # n_skeleton = R^T n_world; for row vectors that is n_world @ R (numpy's matmul, as the grid's slabs),
        # a block of rows at a time so that its temporaries stay small however many poses are asked for
        normals = out[:, 2 * len(JOINTS) :]
        for start in range(0, len(base), ROTATED_ROWS):
            rows = slice(start, start + ROTATED_ROWS)
            block = normals[rows]
            block[:] = np.matmul(block.reshape(len(block), -1, 3), self.rotations[theta[rows]]).reshape(
                len(block), -1
            )
        return out


def _corner_table(sampler: _SlabSampler, offsets_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For offsets (T, k, 2) in metres: the four bilinear corners of each, as row offsets into a level's
    X * Y columns (T, k, 4), and their weights (T, k, 4) float32, in `_SlabSampler.corners`' order and
    arithmetic (a corner it drops has weight 0 here)."""
    base, fraction = sampler.floor_and_fraction(offsets_xy[..., 0], offsets_xy[..., 1])
    (bu, bv), (fu, fv) = base, fraction
    rows = np.stack([bu * sampler.shape[1] + bv + du * sampler.shape[1] + dv for du, dv in CORNERS], axis=-1)
    weights = np.stack([(fu if du else 1 - fu) * (fv if dv else 1 - fv) for du, dv in CORNERS], axis=-1)
    weights[weights <= 1e-12] = 0.0
    return rows, weights.astype(np.float32)


CORNERS = ((0, 0), (1, 0), (0, 1), (1, 1))  # bilinear corners, in the order their terms are summed
ROTATED_ROWS = 4096  # `features_at` turns the normals of this many rows at a time


class _SlabSampler:
    """Reads fields at offsets that are the same for every pose of a slab."""

    def __init__(self, fields: SceneFields, grid: PoseGrid, layout: FeatureLayout):
        lattice = fields.lattice
        self.fields, self.layout, self.res = fields, layout, lattice.resolution
        step_ratio = 1.0 if np.isnan(grid.step) else grid.step / self.res
        if abs(step_ratio - round(step_ratio)) > 1e-6 or round(step_ratio) < 1:
            raise ValueError(f"pose step {grid.step} is not a whole multiple of the voxel size {self.res}")
        self.stride = max(1, round(step_ratio))
        self.u0 = (grid.x[0] - lattice.origin[0]) / self.res
        self.v0 = (grid.y[0] - lattice.origin[1]) / self.res
        self.nx, self.ny = len(grid.x), len(grid.y)
        self.shape = lattice.shape

    def level(self, torso_z: float, skeleton: Skeleton) -> dict:
        """Everything that depends on the torso height only: fields interpolated in z."""
        joint_heights = torso_z + skeleton.joints[:, 2]
        sample_heights = torso_z + self.layout.sample_positions()
        return {
            # (X, Y, 15); the truncated field is what is interpolated, so a read depends on no distance
            # beyond the cap
            "distance": self._lerp_z(self.fields.distance, joint_heights, self.layout.distance_cap),
            "occupancy": self._lerp_z(self.fields.collision, joint_heights),  # (X, Y, 15)
            # (X, Y, cells, 3)
            "normals": self._cell_heights(self._lerp_z(self.fields.normals, sample_heights)),
        }

    def _cell_heights(self, samples: np.ndarray) -> np.ndarray:
        """Average the z samples of each cell (averaging commutes with the bilinear read in x, y)."""
        per_cell = self.layout.samples_per_cell
        if per_cell == 1:
            return samples
        x, y, n_s, _ = samples.shape
        return samples.reshape(x, y, n_s // per_cell, per_cell, 3).mean(axis=3)

    def slab(self, level: dict, skeleton: Skeleton, theta: float) -> _Slab:
        rotation = rotation_z(theta)
        joint_xy = (skeleton.joints @ rotation.T)[:, :2]
        axis = self.layout.sample_positions()
        grid_xy = np.stack(np.meshgrid(axis, axis, indexing="ij"), axis=-1).reshape(-1, 2)
        sample_xy = grid_xy @ rotation[:2, :2].T
        # n_skeleton = R^T n_world; for row vectors that is n_world @ R.
        normals = level["normals"] @ rotation.astype(np.float32)
        return _Slab(self, level, joint_xy, sample_xy, normals.reshape(*normals.shape[:2], -1))

    def _lerp_z(self, field: np.ndarray, heights: np.ndarray, cap: float | None = None) -> np.ndarray:
        k = (np.asarray(heights) - self.fields.lattice.origin[2]) / self.res
        base = np.floor(k).astype(int)
        frac = (k - base).astype(np.float32)
        if base.min() < 0 or base.max() + 1 >= self.shape[2]:
            raise ReachError(
                f"heights {np.min(heights):.2f}..{np.max(heights):.2f} m leave the voxel fields "
                f"({self.fields.lattice.origin[2]:.2f}..{self.fields.lattice.upper[2]:.2f} m); raise "
                "voxel.min_height or margin"
            )
        below = field[:, :, base]
        above = field[:, :, base + 1]
        if cap is not None:
            np.minimum(below, np.float32(cap), out=below)
            np.minimum(above, np.float32(cap), out=above)
        frac = frac.reshape((1, 1, -1) + (1,) * (field.ndim - 3))
        return below * (1 - frac) + above * frac

    def corners(self, dx: float, dy: float) -> list[tuple[int, int, float]]:
        """(x index, y index, weight) of the bilinear corners for pose (0, 0) shifted by (dx, dy) metres."""
        (bu, bv), (fu, fv) = self.floor_and_fraction(np.asarray(dx), np.asarray(dy))
        bu, bv, fu, fv = int(bu), int(bv), float(fu), float(fv)
        weights = ((0, 0, (1 - fu) * (1 - fv)), (1, 0, fu * (1 - fv)), (0, 1, (1 - fu) * fv), (1, 1, fu * fv))
        return [(bu + cu, bv + cv, w) for cu, cv, w in weights if w > 1e-12]

    def floor_and_fraction(self, dx: np.ndarray, dy: np.ndarray) -> tuple[tuple, tuple]:
        """((floor u, floor v), (fraction u, fraction v)) in voxels for pose (0, 0) shifted by (dx, dy)
        metres; raises ReachError when a shifted pose of the grid would read outside the fields."""
        u, v = self.u0 + dx / self.res, self.v0 + dy / self.res
        bu, bv = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
        last_u, last_v = bu + 1 + (self.nx - 1) * self.stride, bv + 1 + (self.ny - 1) * self.stride
        if (
            np.any(bu < 0)
            or np.any(bv < 0)
            or np.any(last_u >= self.shape[0])
            or np.any(last_v >= self.shape[1])
        ):
            raise ReachError(
                "placed skeletons reach beyond the voxel fields in x or y; compute the fields with a larger "
                "voxel.margin"
            )
        return (bu, bv), (u - bu, v - bv)


class _Slab:
    """One (z, theta) slab: joint and cube offsets fixed, pose (x, y) varying."""

    def __init__(self, sampler: _SlabSampler, level: dict, joint_xy, sample_xy, normals):
        self.sampler, self.level, self.normals = sampler, level, normals
        self._buffers: dict = {}
        self.joint_corners = [sampler.corners(*xy) for xy in joint_xy]
        self.sample_corners = [sampler.corners(*xy) for xy in sample_xy]

    def _read_into(
        self, dest: np.ndarray, plane: np.ndarray, corners, rows: slice, accumulate: bool = False
    ) -> None:
        """dest (rows, ny, ...) = (or +=) the bilinear read of plane for these rows.

        Corners are summed in reused contiguous scratch arrays and written to the strided destination once:
        read-modify-writes of feature columns, and fresh temporaries (page faults), each cost as much again.
        """
        s, n_rows, ny = self.sampler.stride, rows.stop - rows.start, self.sampler.ny
        shape = (n_rows, ny, *plane.shape[2:])
        total, term = self._scratch(shape, 0), self._scratch(shape, 1)
        for index, (cu, cv, weight) in enumerate(corners):
            u = cu + rows.start * s
            view = plane[u : u + (n_rows - 1) * s + 1 : s, cv : cv + (ny - 1) * s + 1 : s]
            if index == 0:
                np.multiply(view, np.float32(weight), out=total)
            else:
                np.multiply(view, np.float32(weight), out=term)
                total += term
        if accumulate:
            dest += total
        else:
            dest[...] = total

    def _scratch(self, shape: tuple, slot: int) -> np.ndarray:
        key = (shape, slot)
        if key not in self._buffers:
            self._buffers[key] = np.empty(shape, dtype=np.float32)
        return self._buffers[key]

    def features(self, rows: slice, out: np.ndarray | None = None) -> np.ndarray:
        layout = self.sampler.layout
        n_rows, ny = rows.stop - rows.start, self.sampler.ny
        if out is None:
            out = np.empty((n_rows, ny, layout.n_features), dtype=np.float32)
        n_joints = len(JOINTS)
        for j, corners in enumerate(self.joint_corners):
            self._read_into(out[:, :, j], self.level["distance"][:, :, j], corners, rows)
            self._read_into(out[:, :, n_joints + j], self.level["occupancy"][:, :, j], corners, rows)
        # Cells are averaged from per_cell x per_cell sample columns (z is averaged already, per level).
        n_s, per_cell, cells = layout.samples_per_axis, layout.samples_per_cell, layout.cells_per_axis
        width = cells * 3  # one column of cells: `cells` heights x 3 normal components
        normal_block = out[:, :, 2 * n_joints :]
        for index, corners in enumerate(self.sample_corners):
            a, b = divmod(index, n_s)
            cell = (a // per_cell) * cells + b // per_cell
            first = a % per_cell == 0 and b % per_cell == 0
            self._read_into(
                normal_block[:, :, cell * width : (cell + 1) * width], self.normals, corners, rows, not first
            )
        if per_cell > 1:
            normal_block *= np.float32(1.0 / per_cell**2)
        return out.reshape(n_rows * ny, layout.n_features)


def compile_reads() -> None:
    """Compile `features_at`'s kernel now (or read it from numba's cache), with the argument types its reads
    pass, so that a service's first map does not wait for it and the workers it forks afterwards share it."""
    from .pose_reads import read_rows

    index, table = np.zeros(1, np.int64), np.zeros((1, 1, 4), np.int64)
    field, weights = np.zeros((4, 3), np.float32), np.zeros((1, 1, 4), np.float32)
    read_rows(
        index, index, field, field, field, table, weights, table, weights, 1, 1, np.zeros((1, 5), np.float32)
    )
