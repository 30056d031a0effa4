"""Voxel fields: occupancy, distance transform, sign-free normals."""

from __future__ import annotations

import numpy as np

from affordcore.example import box_surface_points
from affordcore.geometry.cells import cell_keys, cells_of_keys
from affordcore.geometry.fields import (
    compute_fields,
    lattice_around,
    orientation_signs,
    towards_centre,
    towards_floor,
)
from affordcore.settings import VoxelSettings


def test_lattice_centres_sit_on_multiples_of_the_resolution_and_cover_the_margin():
    points = np.array([[0.31, -0.42, 0.05], [2.77, 1.93, 1.2]])
    lattice = lattice_around(points, VoxelSettings(resolution=0.1, margin=0.5, min_height=2.0))
    np.testing.assert_allclose(lattice.origin / 0.1, np.round(lattice.origin / 0.1), atol=1e-9)
    assert np.all(lattice.origin <= points.min(axis=0) - 0.5 + 1e-9)
    assert np.all(lattice.upper >= np.array([2.77, 1.93, 2.0]) + 0.5 - 1e-9)
    # The floor (z = 0) is a voxel centre, not a face.
    k = (0.0 - lattice.origin[2]) / 0.1
    assert abs(k - round(k)) < 1e-9


def test_occupancy_marks_exactly_the_voxels_holding_points():
    rng = np.random.default_rng(0)
    points = rng.uniform([0, 0, 0], [2, 2, 1], size=(300, 3))
    fields = compute_fields(points, normals=np.tile([0.0, 0.0, 1.0], (len(points), 1)))
    expected = np.zeros(fields.lattice.shape, bool)
    expected[tuple(fields.lattice.voxel_of(points).T)] = True
    np.testing.assert_array_equal(fields.occupancy > 0, expected)


def test_distance_transform_is_the_distance_to_the_nearest_occupied_centre():
    rng = np.random.default_rng(1)
    points = rng.uniform([0, 0, 0], [1.5, 1.5, 1.0], size=(40, 3))
    fields = compute_fields(
        points, VoxelSettings(margin=0.3, min_height=1.0), normals=np.tile([0.0, 0.0, 1.0], (40, 1))
    )
    lattice = fields.lattice
    occupied = lattice.centres(np.argwhere(fields.occupancy > 0))
    every = np.argwhere(np.ones(lattice.shape, bool))
    sample = every[rng.choice(len(every), 500, replace=False)]
    brute = np.linalg.norm(lattice.centres(sample)[:, None] - occupied[None], axis=2).min(axis=1)
    np.testing.assert_allclose(fields.distance[tuple(sample.T)], brute, atol=1e-5)
    assert np.all(fields.distance[fields.occupancy > 0] == 0)


def test_normals_with_random_signs_do_not_cancel():
    """A floor whose point normals point up or down at random still gets a unit, upward voxel normal."""
    rng = np.random.default_rng(2)
    floor = box_surface_points(np.array([0.0, 0.0, 0.0]), np.array([2.0, 2.0, 0.0]), 2000, rng)
    signs = rng.choice([-1.0, 1.0], size=len(floor))
    normals = np.column_stack([np.zeros(len(floor)), np.zeros(len(floor)), signs])
    assert abs(normals[:, 2].mean()) < 0.1  # a plain mean would nearly cancel
    fields = compute_fields(floor, normals=normals)
    field = fields.normals[fields.occupancy > 0]
    np.testing.assert_allclose(field, np.tile([0.0, 0.0, 1.0], (len(field), 1)), atol=1e-6)


def test_estimated_normals_of_a_box_room_face_up_and_inwards():
    rng = np.random.default_rng(3)
    floor = box_surface_points(np.array([0.0, 0.0, 0.0]), np.array([4.0, 4.0, 0.0]), 900, rng)
    west_wall = box_surface_points(np.array([0.0, 0.0, 0.0]), np.array([0.0, 4.0, 2.4]), 900, rng)
    fields = compute_fields(np.concatenate([floor, west_wall]))
    lattice = fields.lattice
    floor_voxel = tuple(lattice.voxel_of(np.array([2.0, 2.0, 0.0])))
    wall_voxel = tuple(lattice.voxel_of(np.array([0.0, 2.0, 1.2])))
    np.testing.assert_allclose(fields.normals[floor_voxel], [0, 0, 1], atol=0.05)
    np.testing.assert_allclose(fields.normals[wall_voxel], [1, 0, 0], atol=0.05)  # faces the room (+x)
    magnitudes = np.linalg.norm(fields.normals[fields.occupancy > 0], axis=1)
    assert np.mean(np.abs(magnitudes - 1) < 1e-4) > 0.9  # unit where a surface is


AXES = np.array([[0.1, 0.0, -0.9], [0.0, 0.2, 0.6], [-1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.3]])


def test_orientation_rule_towards_the_centre():
    lattice = lattice_around(np.array([[0.0, -3.0, 0.0], [5.0, 0.0, 1.0]]), VoxelSettings(margin=0.0))
    columns = np.rint((np.array([[0, 0], [0, 0], [0, 0], [5, 0], [0, -3]]) - lattice.origin[:2]) / 0.1)
    steep = towards_centre(AXES, columns.astype(int), lattice, np.array([2.0, 0.0, 1.0]))
    # up-facing ones point up; steep ones point at the centre
    np.testing.assert_array_equal(orientation_signs(AXES, steep), [-1, 1, -1, -1, -1])


def test_orientation_rule_towards_the_floor():
    columns = np.array([[10, 10], [10, 10], [10, 10], [9, 5], [5, 10]])
    floor = np.zeros((20, 20), dtype=np.float32)
    floor[10:] = 1.0  # scanned floor on the +x side only
    steep = towards_floor(AXES, columns, floor, 0.1)
    # up-facing ones point up; steep ones face the floor 0.6 m out (+x here); with floor on neither side,
    # the larger horizontal component is made positive
    np.testing.assert_array_equal(orientation_signs(AXES, steep), [-1, 1, -1, 1, -1])


def test_cell_keys_order_cells_lexicographically_and_give_them_back():
    cells = np.random.default_rng(4).integers(-(1 << 20), 1 << 20, size=(500, 3))
    keys = cell_keys(cells)
    np.testing.assert_array_equal(cells_of_keys(keys), cells)
    order = np.lexsort(cells.T[::-1])  # by x, then y, then z
    assert np.all(np.diff(keys[order]) >= 0)


SOFT = VoxelSettings(margin=0.3, min_height=1.0, fields="soft")


def test_soft_occupancy_is_the_nearest_points_trilinear_weight():
    """A point at a voxel centre weighs 1 there; one on a face 0.5 on both sides; a denser cloud of the same
    surface does not weigh more (the most of any point, not a sum)."""
    up = np.array([[0.0, 0.0, 1.0]])
    centre = np.array([[0.5, 0.5, 0.5]])
    fields = compute_fields(centre, SOFT, normals=up)
    at = tuple(fields.lattice.voxel_of(centre)[0])
    assert fields.soft_occupancy[at] == 1.0
    assert fields.soft_occupancy.sum() == 1.0
    face = np.array([[0.55, 0.5, 0.5]])  # half-way between the centres at x = 0.5 and x = 0.6
    fields = compute_fields(face, SOFT, normals=up)
    i, j, k = fields.lattice.voxel_of(centre)[0]
    np.testing.assert_allclose(fields.soft_occupancy[i : i + 2, j, k], [0.5, 0.5], atol=1e-6)
    np.testing.assert_allclose(fields.soft_occupancy.sum(), 1.0, atol=1e-6)
    rng = np.random.default_rng(3)
    sparse = box_surface_points(np.array([0.0, 0.0, 0.42]), np.array([1.0, 1.0, 0.42]), 400, rng)
    dense = np.concatenate([sparse, sparse])  # every point twice: a sum would double
    one = compute_fields(sparse, SOFT, normals=np.tile(up, (len(sparse), 1)))
    two = compute_fields(dense, SOFT, normals=np.tile(up, (len(dense), 1)))
    np.testing.assert_array_equal(one.soft_occupancy, two.soft_occupancy)
    # the binary occupancy is the binary fields' own: it still decides what was scanned
    binary = compute_fields(
        sparse, VoxelSettings(margin=0.3, min_height=1.0), normals=np.tile(up, (len(sparse), 1))
    )
    np.testing.assert_array_equal(one.occupancy, binary.occupancy)
    assert binary.soft_occupancy is None and binary.collision is binary.occupancy


def test_soft_distance_is_the_distance_to_the_nearest_point_near_surfaces():
    rng = np.random.default_rng(4)
    points = rng.uniform([0, 0, 0], [1.5, 1.5, 1.0], size=(40, 3))
    fields = compute_fields(points, SOFT, normals=np.tile([0.0, 0.0, 1.0], (40, 1)))
    binary = compute_fields(
        points, VoxelSettings(margin=0.3, min_height=1.0), normals=np.tile([0, 0, 1.0], (40, 1))
    )
    every = np.argwhere(np.ones(fields.lattice.shape, bool))
    brute = np.linalg.norm(fields.lattice.centres(every)[:, None] - points[None], axis=2).min(axis=1)
    near = binary.distance[tuple(every.T)] <= 0.5
    assert near.sum() > 1000 and (~near).sum() > 100
    np.testing.assert_allclose(fields.distance[tuple(every[near].T)], brute[near], atol=1e-5)
    # beyond the exact reach the binary distance, within a voxel's half-diagonal of the exact one
    np.testing.assert_array_equal(
        fields.distance[tuple(every[~near].T)], binary.distance[tuple(every[~near].T)]
    )
    assert np.abs(binary.distance[tuple(every.T)] - brute).max() <= np.sqrt(3) / 2 * 0.1 + 1e-6


def test_soft_fields_change_smoothly_as_the_room_moves_against_the_lattice():
    """A wall moved by a fifth of a millimetre across a voxel face changes the binary fields by a whole voxel
    there, the soft ones (within their exact reach of the wall) by about that fifth of a millimetre."""
    rng = np.random.default_rng(5)
    wall = box_surface_points(np.array([0.0, 0.0, 0.0]), np.array([0.0, 1.0, 1.0]), 3000, rng)
    normals = np.tile([1.0, 0.0, 0.0], (len(wall), 1))
    changes = {}
    for style in ("binary", "soft"):
        settings = VoxelSettings(margin=0.3, min_height=1.0, fields=style)
        before = compute_fields(wall + [0.0499, 0, 0], settings, normals=normals)
        after = compute_fields(wall + [0.0501, 0, 0], settings, normals=normals)
        assert before.lattice.shape == after.lattice.shape
        near = (before.distance <= 0.4) & (after.distance <= 0.4)
        changes[style] = [
            np.abs(after.collision - before.collision).max(),
            np.abs(after.distance - before.distance)[near].max(),
            np.abs(after.normals - before.normals).max(),
        ]
    assert min(changes["binary"]) > 0.09  # a whole voxel: occupied to empty, 10 cm, a unit normal
    assert max(changes["soft"]) < 0.01
