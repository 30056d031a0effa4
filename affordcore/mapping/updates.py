"""Map updates in proportion to the change: when a room's fields change in one corner (the assembler's map
grew), a model's scores are recomputed only for the poses that can read a changed voxel, and carried over
for the rest from the previous map of the same room.

A pose's score reads the fields within its skeleton's reach (its joints and normal-cube samples, at any angle,
plus a voxel for the bilinear read) and at the heights its torso levels put them. So:

1. the voxel columns whose fields differ from the previous fields' (over those heights; beyond a small
   tolerance, since the same surface estimated from points in another order differs in its last bits) are
   the changed columns; columns the previous fields did not cover are changed too. Under the local layout
   (docs/geometry.md) a new surface changes the truncated distance only within the cap of itself, and flips
   no normal far away; under the paper's the changed columns can be anywhere (still exact, less cheap);
2. the pose cells within reach of a changed column are stale;
3. each connected patch of stale cells is scored afresh over its bounding box (`inference.score_poses` on
   those poses and the fields around them, which is exact: a pose's score does not depend on which other
   poses are scored with it), and every other pose keeps its previous score;
4. a cascade's second stage rescores only the poses of its best set that it did not rescore last time or
   whose cell is stale (`inference.model_scores`' `known`): its trees read the same fields within the same
   reach.

The result equals a full scoring of the new fields (tests/test_updates.py). Cells away from scanned floor,
the room's median and the map itself are recomputed on the merged scores: they are cheap. A change of
resolution, torso levels, angles or pose step, or no previous map, means a full scoring.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.cells import cell_keys, cells_of_keys
from ..geometry.features import FeatureLayout
from ..geometry.fields import (
    SceneFields,
    VoxelLattice,
    disc,
    estimate_normals,
    normals_at,
    thin_cells,
)
from ..geometry.grid import PoseGrid
from ..geometry.skeleton import Skeleton
from .maps import RULED_OUT

FIELD_TOLERANCE = 1e-4  # field values closer than this count as unchanged (normals, metres, occupancy)
_SAME_MEAN = 1e-7  # m: thinned points closer than this to the last cloud's keep their normals


@dataclass
class ModelState:
    """One model's scores of one room: what the next update starts from."""

    fields: SceneFields
    grid: PoseGrid
    linear: np.ndarray  # the first stage's scores (z, theta, x, y) float32, every cell
    scores: np.ndarray  # the final scores (cells off the floor ruled out, a cascade's second stage)


@dataclass
class UpdateReport:
    rescored_poses: int  # poses whose first-stage score was computed afresh
    total_poses: int
    patches: int  # boxes of poses scored afresh
    reason: str  # why the scoring was full ("" for an update)

    @property
    def fraction(self) -> float:
        return self.rescored_poses / max(self.total_poses, 1)


def reach_voxels(skeleton: Skeleton, layout: FeatureLayout, resolution: float) -> int:
    """How many voxel columns from its own a pose's score can read, at any angle."""
    joints = float(np.linalg.norm(skeleton.joints[:, :2], axis=1).max())
    samples = float(np.abs(layout.sample_positions()).max()) * np.sqrt(2)
    return int(np.ceil(max(joints, samples) / resolution)) + 2  # the bilinear corner, and rounding


def updated_scores(
    previous: ModelState | None,
    fields: SceneFields,
    grid: PoseGrid,
    skeleton: Skeleton,
    layout: FeatureLayout,
    weights: np.ndarray,
    bias: float,
) -> tuple[np.ndarray, np.ndarray, UpdateReport]:
    """(the linear scores of every pose of `grid` on `fields`, as `inference.score_poses` gives them; the
    (nx, ny) cells scored afresh; a report), scoring afresh only the poses within reach of a field that
    changed since `previous`."""
    from scipy.ndimage import find_objects, label

    from .inference import score_poses

    reason = _why_full(previous, fields, grid)
    if reason:
        scores = score_poses(fields, skeleton, grid, layout, weights, bias)
        return scores, np.ones(grid.shape[2:], dtype=bool), UpdateReport(grid.size, grid.size, 0, reason)
    reach = reach_voxels(skeleton, layout, fields.lattice.resolution)
    low = grid.z.min() + min(skeleton.joints[:, 2].min(), -layout.cube_size / 2)
    high = grid.z.max() + max(skeleton.joints[:, 2].max(), layout.cube_size / 2)
    changed = _changed_columns(previous.fields, fields, (low, high), layout.distance_cap)
    stale = _stale_cells(changed, fields.lattice, grid, reach)
    scores, known = carried_over(previous.linear, previous.grid, grid)
    stale |= ~known
    patches = find_objects(label(stale, structure=np.ones((3, 3)))[0])
    for box in patches:
        window = PoseGrid(grid.x[box[0]], grid.y[box[1]], grid.z, grid.theta)
        around = _fields_around(fields, window, reach)
        scores[:, :, box[0], box[1]] = score_poses(around, skeleton, window, layout, weights, bias)
        stale[box] = True  # the whole box was scored afresh
    rescored = int(stale.sum()) * len(grid.z) * len(grid.theta)
    return scores, stale, UpdateReport(rescored, grid.size, len(patches), "")


def known_second_stage(previous: ModelState, grid: PoseGrid, stale: np.ndarray) -> np.ndarray:
    """The previous final scores carried onto `grid` (after an update, not a full scoring), float32's lowest
    in stale cells and cells the previous grid did not cover: the second-stage scores that still hold
    (`inference.model_scores`' `known`)."""
    known, covered = carried_over(previous.scores, previous.grid, grid)
    known[:, :, stale | ~covered] = RULED_OUT
    return known


def _why_full(previous: ModelState | None, fields: SceneFields, grid: PoseGrid) -> str:
    if previous is None:
        return "no previous map"
    old = previous.grid
    if abs(previous.fields.lattice.resolution - fields.lattice.resolution) > 1e-12:
        return "the voxel size changed"
    if len(old.z) != len(grid.z) or not np.allclose(old.z, grid.z):
        return "the torso levels changed"
    if len(old.theta) != len(grid.theta) or not np.allclose(old.theta, grid.theta):
        return "the angles changed"
    if not np.isclose(old.step, grid.step, equal_nan=True):
        return "the pose step changed"
    return ""


def _changed_columns(
    old: SceneFields, new: SceneFields, heights: tuple[float, float], distance_cap: float | None
) -> np.ndarray:
    """(nx, ny) of the new lattice: True where any field differs from the old one's over `heights`, or the
    old fields do not cover the column at those heights."""
    res, shape = new.lattice.resolution, new.lattice.shape
    changed = np.ones(shape[:2], dtype=bool)
    offset = np.rint((new.lattice.origin - old.lattice.origin) / res).astype(int)  # new index + offset = old
    k0 = max(int(np.floor((heights[0] - new.lattice.origin[2]) / res)) - 1, 0)
    k1 = min(int(np.ceil((heights[1] - new.lattice.origin[2]) / res)) + 2, shape[2])
    if k0 + offset[2] < 0 or k1 + offset[2] > old.lattice.shape[2]:
        return changed  # the old fields do not reach these heights
    i0, j0 = max(0, -offset[0]), max(0, -offset[1])
    i1 = min(shape[0], old.lattice.shape[0] - offset[0])
    j1 = min(shape[1], old.lattice.shape[1] - offset[1])
    if i1 <= i0 or j1 <= j0:
        return changed
    new_part = (slice(i0, i1), slice(j0, j1), slice(k0, k1))
    old_part = tuple(slice(s.start + o, s.stop + o) for s, o in zip(new_part, offset, strict=True))
    differs = np.zeros((i1 - i0, j1 - j0), dtype=bool)
    # soft fields' collision field beside the binary occupancy; for binary fields the two are the same array
    soft = ("collision",) if new.soft_occupancy is not None else ()
    for name in ("occupancy", *soft, "distance", "normals"):
        a, b = getattr(new, name)[new_part], getattr(old, name)[old_part]
        if name == "distance" and distance_cap is not None:  # the features read the truncated field
            a, b = np.minimum(a, distance_cap), np.minimum(b, distance_cap)
        gap = np.abs(a - b) > FIELD_TOLERANCE
        differs |= gap.reshape(*differs.shape, -1).any(axis=2)
    changed[i0:i1, j0:j1] = differs
    return changed


def _stale_cells(changed: np.ndarray, lattice: VoxelLattice, grid: PoseGrid, reach: int) -> np.ndarray:
    """(nx, ny) of the grid: the pose cells with a changed column within `reach` voxels (a disc)."""
    from scipy.ndimage import binary_dilation

    near = binary_dilation(changed, disc(reach), border_value=1)
    u = np.rint((grid.x - lattice.origin[0]) / lattice.resolution).astype(int)
    v = np.rint((grid.y - lattice.origin[1]) / lattice.resolution).astype(int)
    inside_u = (u >= 0) & (u < lattice.shape[0])
    inside_v = (v >= 0) & (v < lattice.shape[1])
    stale = np.ones((len(grid.x), len(grid.y)), dtype=bool)
    iu, iv = np.flatnonzero(inside_u), np.flatnonzero(inside_v)
    stale[np.ix_(iu, iv)] = near[np.ix_(u[iu], v[iv])]
    return stale


def carried_over(values: np.ndarray, old: PoseGrid, grid: PoseGrid) -> tuple[np.ndarray, np.ndarray]:
    """(`values` of the `old` grid's poses placed on `grid`, float32's lowest where the grids do not overlap;
    (nx, ny) True where they do). The grids share their step, levels and angles (`_why_full`)."""
    step = grid.step if np.isfinite(grid.step) else old.step
    dx = int(np.rint((old.x[0] - grid.x[0]) / step)) if np.isfinite(step) else 0
    dy = int(np.rint((old.y[0] - grid.y[0]) / step)) if np.isfinite(step) else 0
    out = np.full(grid.shape, RULED_OUT, dtype=np.float32)
    covered = np.zeros(grid.shape[2:], dtype=bool)
    i0, j0 = max(dx, 0), max(dy, 0)
    i1, j1 = min(len(grid.x), dx + len(old.x)), min(len(grid.y), dy + len(old.y))
    if i1 > i0 and j1 > j0:
        out[:, :, i0:i1, j0:j1] = values[:, :, i0 - dx : i1 - dx, j0 - dy : j1 - dy]
        covered[i0:i1, j0:j1] = True
    return out, covered


def _fields_around(fields: SceneFields, window: PoseGrid, reach: int) -> SceneFields:
    """The fields of the voxel columns a window of poses can read (its cells and `reach` beyond them)."""
    lattice = fields.lattice
    res = lattice.resolution
    u = (window.x[[0, -1]] - lattice.origin[0]) / res
    v = (window.y[[0, -1]] - lattice.origin[1]) / res
    i0 = max(int(np.floor(u[0])) - reach, 0)
    i1 = min(int(np.ceil(u[1])) + reach + 1, lattice.shape[0])
    j0 = max(int(np.floor(v[0])) - reach, 0)
    j1 = min(int(np.ceil(v[1])) + reach + 1, lattice.shape[1])
    origin = lattice.origin + np.array([i0, j0, 0]) * res
    part = (slice(i0, i1), slice(j0, j1))
    return SceneFields(
        VoxelLattice(origin, res, (i1 - i0, j1 - j0, lattice.shape[2])),
        fields.occupancy[part],
        fields.distance[part],
        fields.normals[part],
        fields.footprint,
        fields.steep_facing,
        soft_occupancy=None if fields.soft_occupancy is None else fields.soft_occupancy[part],
        normal_estimator=fields.normal_estimator,
        columns=fields.columns,  # in world coordinates: a window reads them as the whole room does
    )


class NormalCache:
    """`fields.estimate_normals` for one room cloud after another (a robot's map as it grows): the thinned
    cloud's normals are estimated afresh only in the blocks around cells whose mean changed, appeared or went,
    and carried over elsewhere. A normal reads the points within `NormalSettings.radius`; blocks are at least
    that big, so the points of the blocks next to a changed one, and of the ring beyond them, hold every
    neighbour of every normal that can change. Equal to estimating all of them up to the order open3d sums
    a neighbourhood in (tests/test_updates.py). Pass it as `compute_fields(..., estimator=cache)`."""

    def __init__(self) -> None:
        self.key: tuple | None = None  # the settings the cache holds normals for
        self.cells = np.empty(0, dtype=np.int64)  # thinned cells, sorted (fields.thin_cells)
        self.points = np.empty((0, 3))
        self.normals = np.empty((0, 3))
        self.estimated = 0  # how many normals the last call estimated

    def __call__(self, points: np.ndarray, settings) -> tuple[np.ndarray, np.ndarray]:
        if settings.downsample <= 0:  # no cells to compare by
            self.key, self.estimated = None, len(points)
            return estimate_normals(points, settings)
        thinned, cells = thin_cells(points, settings.downsample)
        key = (settings.estimator, settings.downsample, settings.radius, settings.max_neighbours)
        if key != self.key:
            normals = normals_at(thinned, settings)
            self.estimated = len(thinned)
        else:
            normals = self._carried(thinned, cells, settings)
        self.key, self.cells, self.points, self.normals = key, cells, thinned, normals
        return thinned, normals

    def _carried(self, thinned: np.ndarray, cells: np.ndarray, settings) -> np.ndarray:
        position = np.clip(np.searchsorted(self.cells, cells), 0, max(len(self.cells) - 1, 0))
        same = (self.cells[position] == cells) if len(self.cells) else np.zeros(len(cells), dtype=bool)
        # a mean summed in another order (the same points, listed anew) differs in its last bits only
        same[same] = np.all(np.abs(self.points[position[same]] - thinned[same]) <= _SAME_MEAN, axis=1)
        gone = ~np.isin(self.cells, cells[same])  # old cells that changed or went
        block = max(settings.radius, settings.downsample)
        per_block = settings.downsample / block

        def blocks(which_cells: np.ndarray) -> np.ndarray:
            ijk = cells_of_keys(which_cells)
            return np.floor(ijk * per_block).astype(np.int64)

        changed = np.unique(cell_keys(np.concatenate([blocks(cells[~same]), blocks(self.cells[gone])])))
        own = blocks(cells)
        near = _within(own, changed, 1)  # normals that can change
        support = _within(own, changed, 2)  # and every point they read
        normals = np.empty_like(thinned)
        normals[~near] = self.normals[position[~near]]
        if near.any():
            fresh = normals_at(thinned[support], settings)
            normals[near] = fresh[near[support]]
        self.estimated = int(near.sum())
        return normals


def _within(blocks: np.ndarray, changed: np.ndarray, rings: int) -> np.ndarray:
    """Whether each block (n, 3) lies within `rings` blocks (in every axis) of a changed block (keys)."""
    if not len(changed):
        return np.zeros(len(blocks), dtype=bool)
    span = range(-rings, rings + 1)
    offsets = np.array([(a, b, c) for a in span for b in span for c in span])
    # the few changed blocks, dilated
    around = (cells_of_keys(changed)[:, None, :] + offsets[None]).reshape(-1, 3)
    return np.isin(cell_keys(blocks), np.unique(cell_keys(around)))
