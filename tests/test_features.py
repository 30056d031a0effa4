"""Per-pose features against a slow, obviously-correct reference, and the properties they must have."""

from __future__ import annotations

import numpy as np
import pytest

from affordcore.example import box_surface_points
from affordcore.geometry.features import (
    FeatureLayout,
    ReachError,
    compute_features,
    features_at,
    iter_features,
)
from affordcore.geometry.fields import compute_fields
from affordcore.geometry.grid import PoseGrid
from affordcore.geometry.skeleton import JOINTS, get_skeleton, place_joints
from affordcore.settings import NormalSettings, VoxelSettings

RNG_SEED = 7


def _room(seed: int = 0, size: float = 3.2, shift: float = 0.0) -> np.ndarray:
    """A small furnished room: floor, two walls, a table, a seat block and a shelf (shifted in x and y)."""
    rng = np.random.default_rng(seed)
    boxes = [
        ((0, 0, 0), (size, size, 0)),
        ((0, -0.1, 0), (size, 0, 2.4)),
        ((-0.1, 0, 0), (0, size, 2.4)),
        ((1.0, 1.2, 0.70), (2.0, 2.0, 0.74)),
        ((2.3, 0.4, 0.0), (2.8, 0.9, 0.45)),
        ((0.05, 2.2, 0.0), (0.4, 3.0, 1.6)),
    ]
    offset = np.array([shift, shift, 0.0])
    return np.concatenate(
        [box_surface_points(np.array(a) + offset, np.array(b) + offset, 700, rng) for a, b in boxes]
    )


def _trilinear(field: np.ndarray, origin: np.ndarray, res: float, points: np.ndarray) -> np.ndarray:
    """Field values at points (n, 3): the weighted sum over the 8 voxel centres around each point."""
    u = (points - origin) / res
    base = np.floor(u).astype(int)
    frac = u - base
    value = 0.0
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                weight = np.prod(np.where([dx, dy, dz], frac, 1 - frac), axis=1)
                corner = field[base[:, 0] + dx, base[:, 1] + dy, base[:, 2] + dz]
                value = value + (weight[:, None] * corner if corner.ndim == 2 else weight * corner)
    return value


def reference_features(fields, skeleton, pose, layout: FeatureLayout) -> np.ndarray:
    """One pose, the slow way: place every joint and cube sample, read the fields, rotate the normals."""
    x, y, z, theta = pose
    c, s = np.cos(theta), np.sin(theta)
    rotation = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    torso = np.array([x, y, z])
    origin, res = fields.lattice.origin, fields.lattice.resolution
    joints = np.array([torso + rotation @ h for h in skeleton.joints])
    distance = fields.distance
    if layout.distance_cap is not None:  # the truncated field is what is interpolated
        distance = np.minimum(distance, layout.distance_cap)
    dist = list(_trilinear(distance, origin, res, joints))
    coll = list(_trilinear(fields.occupancy, origin, res, joints))
    n, cell, per = layout.cells_per_axis, layout.cell_size, layout.samples_per_cell
    # Every sample of every cell, cells in C order over (forward, left, up), samples grouped per cell.
    offsets = np.array(
        [
            -layout.cube_size / 2 + np.array([i, j, k]) * cell + (np.array([a, b, d]) + 0.5) * cell / per
            for i in range(n)
            for j in range(n)
            for k in range(n)
            for a in range(per)
            for b in range(per)
            for d in range(per)
        ]
    )
    world_normals = _trilinear(fields.normals, origin, res, torso + offsets @ rotation.T)
    skeleton_normals = np.array([rotation.T @ w for w in world_normals])
    normals = list(skeleton_normals.reshape(n**3, per**3, 3).mean(axis=1).ravel())
    return np.array(dist + coll + normals)


def _fields(resolution: float = 0.10):
    return compute_fields(_room(), VoxelSettings(resolution=resolution), NormalSettings())


def _sparse_grid(fields, skeleton, n_theta: int = 9, seed: int = RNG_SEED) -> PoseGrid:
    """The room's pose grid, with a handful of orientations (0, pi/2 and random ones) to keep it small."""
    full = PoseGrid.over_footprint(fields.footprint, skeleton.torso_height, fields.lattice.resolution)
    rng = np.random.default_rng(seed)
    thetas = np.concatenate([[0.0, np.pi / 2], rng.uniform(0, 2 * np.pi, n_theta - 2)])
    return PoseGrid(full.x, full.y, full.z, thetas)


def _streamed_rows(fields, skeleton, grid, layout, wanted: np.ndarray) -> np.ndarray:
    """Rows for the wanted pose indices, picked out of the stream (the full matrix is never held)."""
    rows = np.empty((len(wanted), layout.n_features), dtype=np.float32)
    for chunk in iter_features(fields, skeleton, grid, layout, chunk_mb=8, reuse_buffer=True):
        hit = (wanted >= chunk.start) & (wanted < chunk.stop)
        rows[hit] = chunk.values[wanted[hit] - chunk.start]
    return rows


@pytest.mark.parametrize(
    "affordance, cube_size, cell_size, resolution, cap",
    [
        ("sitting-working", 1.0, 0.10, 0.10, None),  # the paper's layout
        ("standing-working", 1.0, 0.20, 0.10, 0.3),  # coarse cells: 2 x 2 x 2 samples each; truncated
        # finer voxels than the pose step (slab stride 2), 4^3 samples a cell
        ("sitting-relaxing", 0.6, 0.20, 0.05, 0.5),
    ],
)
def test_features_match_slow_reference_on_random_poses(affordance, cube_size, cell_size, resolution, cap):
    fields = _fields(resolution)
    skeleton = get_skeleton(affordance)
    grid = _sparse_grid(fields, skeleton)
    layout = FeatureLayout(cube_size, cell_size, resolution, cap)
    wanted = np.sort(np.random.default_rng(RNG_SEED).choice(grid.size, 200, replace=False))
    fast = _streamed_rows(fields, skeleton, grid, layout, wanted)
    reference = np.array([reference_features(fields, skeleton, pose, layout) for pose in grid.poses(wanted)])
    # Every block must be non-trivial somewhere, or the comparison proves little.
    assert (
        reference[:, :15].max() > 0.29
        and (cap is None or (fields.distance.max() > cap and reference[:, :15].max() <= cap + 1e-6))
        and reference[:, 15:30].max() > 0.5
        and np.abs(reference[:, 30:]).max() > 0.4
    )
    np.testing.assert_allclose(fast, reference, atol=2e-5, rtol=1e-5)
    # the same poses asked for one by one, in any order (shuffled, one repeated): the same rows
    order = np.random.default_rng(1).permutation(len(wanted))
    asked = np.append(wanted[order], wanted[order[0]])
    picked = features_at(fields, skeleton, grid, layout, asked)
    np.testing.assert_allclose(picked[:-1], fast[order], atol=1e-6, rtol=1e-6)
    np.testing.assert_array_equal(picked[-1], picked[0])


def test_place_joints_is_translation_plus_rotation_about_z():
    skeleton = get_skeleton("standing-working")
    rng = np.random.default_rng(1)
    poses = np.column_stack([rng.uniform(-5, 5, (50, 3)), rng.uniform(0, 2 * np.pi, 50)])
    placed = place_joints(skeleton.joints, poses)
    for pose, joints in zip(poses, placed):
        c, s = np.cos(pose[3]), np.sin(pose[3])
        expected = pose[:3] + skeleton.joints @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T
        np.testing.assert_allclose(joints, expected, atol=1e-12)
    # Facing +y (theta = pi/2): a hand reaching forward ends up at larger y, left is -x.
    hand, shoulder = JOINTS.index("L_HAND"), JOINTS.index("L_SHOULDER")
    quarter = place_joints(skeleton.joints, np.array([[0, 0, 0, np.pi / 2]]))[0]
    assert quarter[hand, 1] > 0.3 and quarter[shoulder, 0] < -0.1


@pytest.mark.parametrize("estimator", ["nearest", "cube"])
def test_features_turn_with_the_skeleton(estimator):
    """Rotating the room and the pose together by a quarter turn leaves every feature unchanged.

    The room is shifted off the voxel faces: a point exactly on a face belongs to the voxel above it, which
    no rotation preserves. The cube's normals read world-anchored 5 cm cells, whose faces a turn maps onto
    faces of the other side: a thinned point within a rounding error of one (its mean summed in another
    order) changes cell, so a few values move, by a fraction of a degree of normal."""
    points = _room(seed=3, shift=0.013)
    turned = points @ np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]], float).T
    skeleton = get_skeleton("sitting-working")
    layout = FeatureLayout(normal_estimator=estimator)
    theta = 0.7
    normals = NormalSettings(estimator=estimator)
    plain, rotated = (compute_fields(p, VoxelSettings(), normals) for p in (points, turned))
    # Pose positions on the half-step lattice map onto it under (x, y) -> (-y, x).
    x, y = np.array([1.25, 1.55, 1.85]), np.array([0.85, 1.15])
    grid_a = PoseGrid(x, y, np.array([skeleton.torso_height]), np.array([theta]))
    grid_b = PoseGrid(-y[::-1], x, np.array([skeleton.torso_height]), np.array([theta + np.pi / 2]))
    a = compute_features(plain, skeleton, grid_a, layout).reshape(len(x), len(y), -1)
    b = compute_features(rotated, skeleton, grid_b, layout).reshape(len(y), len(x), -1)
    b = b[::-1].transpose(1, 0, 2)
    np.testing.assert_allclose(a[..., :30], b[..., :30], atol=1e-5)
    if estimator == "nearest":
        np.testing.assert_allclose(a[..., 30:], b[..., 30:], atol=1e-5)
    else:
        gap = np.abs(a[..., 30:] - b[..., 30:])
        assert gap.max() < 1e-3 and np.mean(gap > 1e-5) < 1e-3, (gap.max(), np.mean(gap > 1e-5))


def test_a_wall_ahead_faces_the_skeleton():
    """Standing 0.3 m in front of a wall and facing it, the cube cells at the wall hold a normal pointing back
    at the person (-x in the skeleton frame), whatever the wall's direction in the world."""
    rng = np.random.default_rng(0)
    whole_floor = box_surface_points(np.array([-2.0, -2.0, 0.0]), np.array([2.0, 2.0, 0.0]), 600, rng)
    for phi in (0.0, 1.1, 2.5):
        wall_direction = np.array([np.cos(phi), np.sin(phi)])
        floor = whole_floor[whole_floor[:, :2] @ wall_direction < 0.35]  # a scan sees no floor behind a wall
        along = np.array([-wall_direction[1], wall_direction[0]])
        s, h = rng.uniform(-1.5, 1.5, 20000), rng.uniform(0, 2.2, 20000)
        wall = np.column_stack(
            [0.35 * wall_direction[0] + s * along[0], 0.35 * wall_direction[1] + s * along[1], h]
        )
        fields = compute_fields(np.concatenate([floor, wall]))
        skeleton = get_skeleton("standing-working")
        grid = PoseGrid(
            np.array([0.05]), np.array([0.05]), np.array([skeleton.torso_height]), np.array([phi])
        )
        # Place the pose at the origin-ish lattice point, facing the wall.
        values = compute_features(fields, skeleton, grid, FeatureLayout())[0]
        cells = values[30:].reshape(10, 10, 10, 3)
        ahead = cells[6:, 3:7, 3:7]  # cells 0.1 to 0.5 m ahead, central columns, around torso height
        strongest = ahead[..., 0].argmin(axis=0)
        facing = np.take_along_axis(ahead, strongest[None, ..., None], axis=0)[0]
        assert np.all(facing[..., 0] < -0.5), facing[..., 0]
        assert np.all(np.abs(facing[..., 1:]) < 0.25), facing[..., 1:]
        assert np.all(np.abs(cells[:4, 3:7, 3:7]) < 1e-6)  # nothing behind


def test_chunks_cover_every_pose_once_in_order_and_bound_memory():
    fields = _fields()
    skeleton = get_skeleton("sitting-working")
    grid = _sparse_grid(fields, skeleton, n_theta=3)
    layout = FeatureLayout(1.0, 0.25, 0.10)
    chunk_mb = 0.05
    expected_start = 0
    for chunk in iter_features(fields, skeleton, grid, layout, chunk_mb=chunk_mb):
        assert chunk.start == expected_start
        assert chunk.values.shape == (chunk.stop - chunk.start, layout.n_features)
        assert chunk.values.nbytes <= max(chunk_mb * 2**20, len(grid.y) * layout.n_features * 4)
        expected_start = chunk.stop
    assert expected_start == grid.size


def test_reuse_buffer_gives_the_same_values_as_fresh_chunks():
    fields = _fields()
    skeleton = get_skeleton("sitting-relaxing")
    grid = _sparse_grid(fields, skeleton, n_theta=2)
    layout = FeatureLayout(1.0, 0.5, 0.10)
    fresh = [c.values for c in iter_features(fields, skeleton, grid, layout, chunk_mb=0.1)]
    reused = [
        c.values.copy()
        for c in iter_features(fields, skeleton, grid, layout, chunk_mb=0.1, reuse_buffer=True)
    ]
    np.testing.assert_array_equal(np.concatenate(fresh), np.concatenate(reused))


def test_features_at_refuses_indices_outside_the_grid_and_takes_none():
    fields = _fields()
    skeleton = get_skeleton("sitting-working")
    grid = _sparse_grid(fields, skeleton, n_theta=2)
    layout = FeatureLayout(1.0, 0.25, 0.10)
    assert features_at(fields, skeleton, grid, layout, np.array([], dtype=int)).shape == (
        0,
        layout.n_features,
    )
    with pytest.raises(IndexError, match="pose indices"):
        features_at(fields, skeleton, grid, layout, np.array([grid.size]))


def test_poses_beyond_the_fields_are_a_clear_error():
    fields = _fields()
    skeleton = get_skeleton("standing-working")
    beyond = PoseGrid(
        np.array([fields.footprint[2] + 5.05]), np.array([0.05]), np.array([1.1]), np.array([0.0])
    )
    with pytest.raises(ReachError, match="margin"):
        compute_features(fields, skeleton, beyond, FeatureLayout())
    too_high = PoseGrid(np.array([1.05]), np.array([1.05]), np.array([9.0]), np.array([0.0]))
    with pytest.raises(ReachError, match="height"):
        compute_features(fields, skeleton, too_high, FeatureLayout())


def test_layout_names_and_fingerprint():
    paper = FeatureLayout()
    assert paper.n_features == 3030 and len(paper.names()) == 3030
    assert paper.names()[0] == "dist:HEAD" and paper.names()[15] == "coll:HEAD"
    assert paper.names()[30:33] == ["normal:0,0,0:x", "normal:0,0,0:y", "normal:0,0,0:z"]
    coarse = FeatureLayout(cell_size=0.25)
    assert coarse.n_features == 30 + 3 * 64
    assert paper.fingerprint != coarse.fingerprint
    assert paper.fingerprint == FeatureLayout().fingerprint
    with pytest.raises(ValueError, match="whole number of cells"):
        FeatureLayout(cube_size=1.0, cell_size=0.3)


def test_compute_features_refuses_a_matrix_that_does_not_fit():
    fields = _fields()
    skeleton = get_skeleton("sitting-working")
    grid = PoseGrid.over_footprint(fields.footprint, skeleton.torso_height, 0.1)
    with pytest.raises(MemoryError, match="iter_features"):
        compute_features(fields, skeleton, grid, FeatureLayout(), max_mb=10)
