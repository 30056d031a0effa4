"""Scores of every pose of a grid under a linear model, without materialising a single feature vector.

A linear model's score is w . f + b, and every feature is a bilinear read of a field at an offset fixed per
(z, theta) slab (`features.py`). So the weights can be applied to the fields first:

* joints: w_dist,j D_j + w_coll,j O_j is one plane per joint, read once at the joint's offset;
* the normal cube: a cell's normal enters in the skeleton frame, n . (R_theta w) with R_theta a turn about z,
  which is cos(theta) (w_x n_x + w_y n_y) + sin(theta) (w_x n_y - w_y n_x) + w_z n_z. The three planes in
  brackets, summed over the cell's heights, do not depend on theta: they are computed once per z level and
  cell column, and each slab combines them and reads them at its rotated sample offsets.

Per slab that is (15 + samples) bilinear reads of one plane each, against (30 + 3 x cells) feature columns
written when features are materialised: the whole grid's scores cost about as much as one slab's features.
Equal to `compute_features(...) @ w + b` up to float32 rounding (tests/test_inference.py).
"""

from __future__ import annotations

import numpy as np

from ..geometry.columns import column_reads
from ..geometry.features import FeatureLayout, _SlabSampler, features_at
from ..geometry.fields import SceneFields
from ..geometry.grid import PoseGrid
from ..geometry.skeleton import JOINTS, Skeleton, rotation_z
from .maps import RULED_OUT


def score_poses(
    fields: SceneFields,
    skeleton: Skeleton,
    grid: PoseGrid,
    layout: FeatureLayout,
    weights: np.ndarray,
    bias: float,
) -> np.ndarray:
    """w . f + b of every pose, shaped like the grid (z, theta, x, y), float32."""
    from threadpoolctl import threadpool_limits

    weights = np.asarray(weights, dtype=np.float64)
    if weights.shape != (layout.n_features,):
        raise ValueError(
            f"the model has {weights.shape[0]} weights; the feature layout has {layout.n_features} features"
        )
    sampler = _SlabSampler(fields, grid, layout)
    nz, nt, nx, ny = grid.shape
    n_joints, cells, per_cell, n_s = (
        len(JOINTS),
        layout.cells_per_axis,
        layout.samples_per_cell,
        layout.samples_per_axis,
    )
    w_dist, w_coll = weights[:n_joints], weights[n_joints : 2 * n_joints]
    # (cell column i*cells+j, height k, axis)
    w_cube = weights[2 * n_joints :].reshape(cells * cells, cells, 3)
    # which cell column each sample column (a, b) of the n_s x n_s sample lattice falls in
    a, b = np.divmod(np.arange(n_s * n_s), n_s)
    column_of_sample = (a // per_cell) * cells + b // per_cell
    # every torso level at once, so that one strided read serves all levels: (plane, z level, X, Y)
    joint_planes, along, across, vertical = [], [], [], []
    for z in grid.z:
        level = sampler.level(z, skeleton)
        planes = level["distance"] * w_dist.astype(np.float32) + level["occupancy"] * w_coll.astype(
            np.float32
        )
        joint_planes.append(np.moveaxis(planes, 2, 0))
        n = level["normals"]  # (X, Y, cells in z, 3), world frame
        along.append(
            np.einsum("xykc,qkc->qxy", n[..., :2], w_cube[..., :2], optimize=True)
        )  # w_x n_x + w_y n_y
        across.append(
            np.einsum("xyk,qk->qxy", n[..., 1], w_cube[..., 0])
            - np.einsum("xyk,qk->qxy", n[..., 0], w_cube[..., 1])
        )
        vertical.append(np.einsum("xyk,qk->qxy", n[..., 2], w_cube[..., 2]))
    joint_planes = np.ascontiguousarray(np.stack(joint_planes, axis=1))
    # a cell's normal is the mean of its sample columns, hence the 1 / per_cell^2
    scale = 1.0 / per_cell**2
    vertical = [v * scale for v in vertical]  # the same for every theta
    along, across, vertical = (np.stack(v, axis=1).astype(np.float32) for v in (along, across, vertical))
    reader = _PlaneReader(sampler, joint_planes.shape[1:])
    scores = np.empty((nz, nt, nx, ny), dtype=np.float32)
    with threadpool_limits(1, user_api="blas"):  # a read is too short to share: a second thread spin-waits
        for it in range(nt):
            theta = float(grid.theta[it])
            joint_reads, column_reads = _slab_reads(sampler, skeleton, theta, column_of_sample)
            reader.start()
            for plane, cu, cv, weight in joint_reads:
                reader.add(joint_planes[plane], cu, cv, weight)
            cos, sin = np.cos(theta) * scale, np.sin(theta) * scale
            for column, reads in column_reads.items():
                plane = reader.cube_plane(along[column], across[column], vertical[column], cos, sin)
                for cu, cv, weight in reads:
                    reader.add(plane, cu, cv, weight)
            scores[:, it] = bias + reader.total()
    return scores


def _slab_reads(
    sampler: _SlabSampler, skeleton: Skeleton, theta: float, column_of_sample: np.ndarray
) -> tuple[list, dict]:
    """The bilinear reads of one theta's slab: ([(joint plane, x index, y index, weight)] at the 15 joints'
    offsets, {cell column: [(x index, y index, weight)]} at the cube's sample offsets). Weights of reads that
    share a plane and a voxel corner are summed first (the samples of one cell column read the same plane at
    offsets about a voxel apart: 2 x 2 samples make 9 corners, not 16), as `_SlabSampler.corners` computes
    them, for all offsets at once."""
    rotation = rotation_z(theta)
    joint_xy = (skeleton.joints @ rotation.T)[:, :2]
    axis = sampler.layout.sample_positions()
    sample_xy = np.stack(np.meshgrid(axis, axis, indexing="ij"), axis=-1).reshape(-1, 2) @ rotation[:2, :2].T
    offsets = np.concatenate([joint_xy, sample_xy])
    n_joints = len(joint_xy)
    plane = np.concatenate([np.arange(n_joints), n_joints + column_of_sample])
    (bu, bv), (fu, fv) = sampler.floor_and_fraction(offsets[:, 0], offsets[:, 1])
    # (offset, corner), corners in `corners`' order: (0, 0), (1, 0), (0, 1), (1, 1)
    weight = np.stack([(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv], axis=1)
    cu = bu[:, None] + np.array([0, 1, 0, 1])
    cv = bv[:, None] + np.array([0, 0, 1, 1])
    kept = weight > 1e-12
    plane = np.broadcast_to(plane[:, None], kept.shape)[kept]
    cu, cv, weight = cu[kept], cv[kept], weight[kept]
    key = (plane * sampler.shape[0] + cu) * sampler.shape[1] + cv
    _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    summed = np.bincount(inverse, weights=weight)  # in the reads' order, as a running sum would add them
    order = np.argsort(first)
    k = first[order]
    # plain Python numbers: the caller's loop indexes with them once per read
    reads = zip(plane[k].tolist(), cu[k].tolist(), cv[k].tolist(), summed[order].astype(np.float32))
    joints, columns = [], {}
    for p, u, v, w in reads:
        if p < n_joints:
            joints.append((p, u, v, w))
        else:
            columns.setdefault(p - n_joints, []).append((u, v, w))
    return joints, columns


class _PlaneReader:
    """Sums weighted shifted reads of (level, X, Y) planes into one slab's scores (level, nx, ny).

    With poses a voxel apart (stride 1), a read at corner (cu, cv) of every pose is one contiguous run of the
    flattened plane, offset by cu * Y + cv: the sum is taken over the whole flattened plane (rows wrap into
    the next, and those sums are thrown away), one long vector operation per read rather than one per row.
    A cube plane is made column by column just before its reads, so that it is still in the cache."""

    def __init__(self, sampler: _SlabSampler, plane_shape: tuple[int, int, int]):
        from scipy.linalg.blas import saxpy  # y += a x, in place on float32 y

        self._saxpy = saxpy
        self.stride, self.nx, self.ny = sampler.stride, sampler.nx, sampler.ny
        self.plane_shape = plane_shape
        self.flat = self.stride == 1
        shape = (int(np.prod(plane_shape)),) if self.flat else (plane_shape[0], self.nx, self.ny)
        self._total = np.empty(shape, np.float32)
        self._term = None if self.flat else np.empty(shape, np.float32)  # strided reads' product, in place
        self._cube = np.empty(plane_shape, np.float32)
        self._part = np.empty(plane_shape, np.float32)

    def start(self) -> None:
        self._total[:] = 0

    def cube_plane(self, along, across, vertical, cos: float, sin: float) -> np.ndarray:
        """One cell column's normal plane at this theta (as float32): cos (w_x n_x + w_y n_y) + sin (w_x n_y -
        w_y n_x) + w_z n_z, the three terms scaled already but the first two's cos and sin."""
        np.multiply(along, np.float32(cos), out=self._cube)
        np.add(self._cube, np.multiply(across, np.float32(sin), out=self._part), out=self._cube)
        return np.add(self._cube, vertical, out=self._cube)

    def add(self, plane: np.ndarray, cu: int, cv: int, weight) -> None:
        if self.flat:  # total[:n - offset] += weight * plane[offset:], in one pass (BLAS's saxpy)
            offset = cu * self.plane_shape[2] + cv
            self._saxpy(plane.reshape(-1), self._total, n=len(self._total) - offset, a=weight, offx=offset)
            return
        s, nx, ny = self.stride, self.nx, self.ny
        read = plane[:, cu : cu + (nx - 1) * s + 1 : s, cv : cv + (ny - 1) * s + 1 : s]
        np.multiply(read, weight, out=self._term)
        self._total += self._term

    def total(self) -> np.ndarray:
        if self.flat:
            return self._total.reshape(self.plane_shape)[:, : self.nx, : self.ny]
        return self._total


def model_scores(
    model,
    fields: SceneFields,
    grid: PoseGrid,
    layout: FeatureLayout,
    allowed: np.ndarray | None = None,
    linear: np.ndarray | None = None,
    known: np.ndarray | None = None,
    max_poses: int | None = None,
) -> np.ndarray:
    """A model's score of every pose (z, theta, x, y), float32; poses outside `allowed` (nx, ny) cells hold
    float32's lowest. A linear model scores every pose as above. A cascade's linear first stage scores every
    pose, and its second stage rescores the best `fraction` of them (at most `max_poses`) from their full
    features (log-odds); every other pose holds float32's lowest: the first stage ruled it out.

    For updates (affordcore.mapping.updates): `linear` is the first stage's scores when the caller has them,
    and `known` (shaped like the grid) holds second-stage scores that still hold, float32's lowest elsewhere;
    a pose of the best set with a known score is not rescored. `max_poses` caps the second stage's poses
    below the model's own (`MapSettings.rescore_max_poses`)."""
    skeleton = model.as_skeleton()
    if linear is None:
        scores = score_poses(fields, skeleton, grid, layout, model.weights, model.bias)
    else:
        scores = linear.copy()
    if allowed is not None:
        scores[:, :, ~allowed] = RULED_OUT
    if not model.rescorer:
        return scores
    flat = scores.ravel()
    cap = min(filter(None, (model.rescorer.get("max_poses"), max_poses)), default=None)
    best = best_poses(flat, model.rescorer["fraction"], cap)
    rescored = known.ravel()[best] if known is not None else np.full(len(best), RULED_OUT, np.float32)
    fresh = rescored <= RULED_OUT
    rows = second_stage_rows(fields, skeleton, grid, layout, best[fresh], model.local_detail)
    rescored[fresh] = model.trees.log_odds(rows)
    flat[:] = RULED_OUT
    flat[best] = rescored
    return scores


def second_stage_rows(
    fields: SceneFields,
    skeleton: Skeleton,
    grid: PoseGrid,
    layout: FeatureLayout,
    index: np.ndarray,
    local_detail: bool = False,
) -> np.ndarray:
    """What the second stage reads of the given poses (flat grid indices): their features, and with
    `local_detail` the fine columns around each (`columns.column_reads`) after them."""
    rows = features_at(fields, skeleton, grid, layout, index)
    if not local_detail:
        return rows
    if fields.columns is None:
        raise ValueError(
            "this model's second stage reads the room's fine columns, and these fields were made without "
            "them: compute the fields again from the cloud"
        )
    iz, it, ix, iy = np.unravel_index(np.asarray(index, dtype=np.int64), grid.shape)
    feet = grid.z[iz] - skeleton.torso_height
    columns = column_reads(fields.columns, grid.x[ix], grid.y[iy], grid.theta[it], feet)
    return np.hstack([rows, columns])


def best_poses(flat_scores: np.ndarray, fraction: float, max_poses: int | None = None) -> np.ndarray:
    """Flat indices of the best `fraction` (rounded up), and at most `max_poses`, of the poses not ruled out,
    in no order: what the second stage rescores, at inference and in training alike."""
    candidates = int(np.count_nonzero(flat_scores > RULED_OUT))
    keep = min(candidates, int(np.ceil(fraction * candidates)), max_poses or candidates)
    return (
        np.argpartition(flat_scores, len(flat_scores) - keep)[len(flat_scores) - keep :]
        if keep
        else np.empty(0, np.int64)
    )
