"""Unknown is not empty (`affordcore.geometry.visibility`): space a sensor looked through is free, space no
sensor position could see is unknown, and a place whose body space nobody saw is not mapped."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from affordcore.geometry.fields import compute_fields
from affordcore.geometry.visibility import FREE, OCCUPIED, UNKNOWN, body_seen, spread_origins, voxel_states
from affordcore.settings import NormalSettings, Settings, VisibilitySettings, VoxelSettings

SPACING = 0.03


def _box(low, high) -> np.ndarray:
    """Points on the six faces of an axis-aligned box, SPACING apart."""
    low, high = np.asarray(low, float), np.asarray(high, float)
    faces = []
    for axis in range(3):
        others = [a for a in range(3) if a != axis]
        u, v = (np.arange(low[a], high[a] + 1e-9, SPACING) for a in others)
        uu, vv = np.meshgrid(u, v, indexing="ij")
        for level in (low[axis], high[axis]):
            face = np.empty((uu.size, 3))
            face[:, others[0]], face[:, others[1]], face[:, axis] = uu.ravel(), vv.ravel(), level
            faces.append(face)
    return np.concatenate(faces)


def _room(partition: bool = False) -> np.ndarray:
    """A 4 m x 3 m room (floor, walls, ceiling at 2.4 m) holding a closed cabinet at x 3.0-3.6, y 2.0-2.6;
    with `partition`, a full wall at x = 2.5 cuts the room in two."""
    points = [_box([0, 0, 0], [4, 3, 2.4]), _box([3.0, 2.0, 0.0], [3.6, 2.6, 0.9])]
    if partition:
        y, z = np.meshgrid(np.arange(0, 3, SPACING), np.arange(0, 2.4, SPACING), indexing="ij")
        points.append(np.column_stack([np.full(y.size, 2.5), y.ravel(), z.ravel()]))
    return np.concatenate(points)


def _fields(points):
    return compute_fields(points, VoxelSettings(), NormalSettings(downsample=0.05))


def _state_at(fields, state, xyz) -> int:
    index = fields.lattice.voxel_of(np.asarray([xyz]))[0]
    return int(state[tuple(index)])


@pytest.fixture(scope="module")
def room_state():
    fields = _fields(_room())
    origins = np.array([[1.0, 1.0, 1.5]])
    return fields, voxel_states(fields.occupancy, fields.lattice, origins)


def test_open_air_is_free_and_surfaces_stay_occupied(room_state):
    fields, state = room_state
    for xyz in [(2.0, 1.5, 1.0), (1.0, 2.5, 0.3), (3.5, 0.5, 2.0), (0.3, 0.3, 0.2)]:
        assert _state_at(fields, state, xyz) == FREE, xyz
    assert _state_at(fields, state, (2.0, 1.5, 0.0)) == OCCUPIED  # the floor
    assert np.all(state[fields.occupancy > 0] == OCCUPIED)


def test_space_no_sensor_could_see_is_unknown(room_state):
    fields, state = room_state
    assert _state_at(fields, state, (3.3, 2.3, 0.45)) == UNKNOWN  # inside the closed cabinet
    assert _state_at(fields, state, (2.0, 1.5, -0.5)) == UNKNOWN  # under the floor
    assert _state_at(fields, state, (4.6, 1.5, 1.0)) == UNKNOWN  # behind a wall
    # the floor's shadow behind the cabinet, seen from the far corner: below the cabinet's top edge
    assert _state_at(fields, state, (3.8, 2.8, 0.2)) == UNKNOWN


def test_a_table_top_seen_from_above_hides_all_the_space_under_it():
    """Looked down on from just above, a voxel spans many more bins in azimuth than in elevation: its
    outline must cover them all, or the space under the top is carved free through the gaps."""
    u, v = np.meshgrid(np.arange(1.0, 2.2, SPACING), np.arange(0.9, 2.1, SPACING), indexing="ij")
    top = np.column_stack([u.ravel(), v.ravel(), np.full(u.size, 0.75)])
    fields = _fields(np.concatenate([_box([0, 0, 0], [4, 3, 2.4]), top]))
    state = voxel_states(fields.occupancy, fields.lattice, np.array([[1.6, 1.5, 1.6]]))
    low, high = fields.lattice.voxel_of(np.array([[1.15, 1.05, 0.1], [2.05, 1.95, 0.65]]))
    under = state[low[0] : high[0] + 1, low[1] : high[1] + 1, low[2] : high[2] + 1]
    assert under.size > 500 and np.all(under == UNKNOWN)
    assert _state_at(fields, state, (1.6, 1.5, 1.2)) == FREE  # between the sensor and the top
    assert _state_at(fields, state, (3.0, 1.5, 0.3)) == FREE  # beside the table, under the sensor's view


def test_without_sensor_positions_nothing_is_free(room_state):
    fields, _ = room_state
    state = voxel_states(fields.occupancy, fields.lattice, np.zeros((0, 3)))
    assert set(np.unique(state)) == {UNKNOWN, OCCUPIED}


def test_more_sensor_positions_see_more_and_never_less(room_state):
    fields, one = room_state
    two = voxel_states(fields.occupancy, fields.lattice, np.array([[1.0, 1.0, 1.5], [3.8, 1.2, 1.5]]))
    assert np.all(two[one == FREE] == FREE)
    assert (two == FREE).sum() > (one == FREE).sum()
    assert _state_at(fields, two, (3.8, 2.8, 0.2)) == FREE  # the shadow, seen from its own side


def test_spread_origins_keeps_count_and_the_far_ends():
    walk = np.column_stack([np.linspace(0, 10, 1000), np.zeros(1000), np.full(1000, 1.5)])
    kept = spread_origins(walk, 5)
    assert len(kept) == 5
    assert {0.0, 10.0} <= set(np.round(kept[:, 0], 6))
    assert np.allclose(np.sort(kept[:, 0]), [0, 2.5, 5, 7.5, 10], atol=0.02)
    assert spread_origins(walk[:3], 5).shape == (3, 3)


def test_a_place_nobody_saw_is_not_mapped():
    """Behind a partition the floor was scanned (from somewhere the file does not say), but none of the
    given sensor positions saw that half: its cells are vetoed, the seen half's are not."""
    from affordcore.mapping.pipeline import unseen_cells

    fields = _fields(_room(partition=True))
    fields.visibility = voxel_states(fields.occupancy, fields.lattice, np.array([[1.0, 1.5, 1.5]]))
    grid = SimpleNamespace(x=np.array([0.6, 1.2, 2.0, 3.0, 3.6]), y=np.array([1.0, 1.5]))
    seen = body_seen(fields, grid.x, grid.y, VisibilitySettings())
    assert np.all(seen[:3] > 0.5) and np.all(seen[3:] < 0.05)
    settings = Settings()
    np.testing.assert_array_equal(unseen_cells(fields, grid, settings)[:, 0], [False] * 3 + [True] * 2)
    settings.visibility.min_seen = 0.0  # the rule off
    assert unseen_cells(fields, grid, settings) is None
    fields.visibility = None  # a file without sensor positions: no rule, whatever the setting
    assert unseen_cells(fields, grid, settings) is None


def test_body_seen_needs_visibility():
    fields = _fields(_room())
    with pytest.raises(ValueError, match="sensor positions"):
        body_seen(fields, np.array([1.0]), np.array([1.0]), VisibilitySettings())


def test_a_cloud_file_brings_its_sensor_positions_along(tmp_path):
    """`<stem>.origins.npy` beside a cloud (what afford synth writes) comes with it, through levelling."""
    from affordcore.geometry.scene import Cloud, CloudError, load_cloud, save_cloud
    from affordcore.mapping.pipeline import prepare_scene

    tilted = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float)  # the room's up is the file's -y
    save_cloud(tmp_path / "room.ply", Cloud(_room() @ tilted.T))
    assert load_cloud(tmp_path / "room.ply").origins is None
    np.save(tmp_path / "room.origins.npy", np.array([[1.0, 1.0, 1.5]]) @ tilted.T)
    cloud = load_cloud(tmp_path / "room.ply")
    np.testing.assert_allclose(cloud.origins, [[1.0, -1.5, 1.0]])
    scene = prepare_scene(cloud, Settings(), np.array([0.0, 1.0, 0.0]))  # gravity along the file's +y
    np.testing.assert_allclose(scene.cloud.origins[0, 2], 1.5, atol=0.02)  # the sensor's height, levelled
    assert scene.fields.visibility is not None
    assert _state_at(scene.fields, scene.fields.visibility, scene.cloud.origins[0] + [1.0, 0, -0.5]) == FREE

    np.save(tmp_path / "room.origins.npy", np.array([[1.0, np.nan, 1.5]]))
    with pytest.raises(CloudError, match="room.origins.npy: sensor positions must be finite"):
        load_cloud(tmp_path / "room.ply")
    np.save(tmp_path / "room.origins.npy", np.zeros((4, 2)))
    with pytest.raises(CloudError, match=r"must be an \(M, 3\) array"):
        load_cloud(tmp_path / "room.ply")


def test_the_room_cache_keeps_the_visibility(tmp_path):
    from affordcore.learn.cache import load_fields, save_fields

    fields = _fields(_room())
    fields.visibility = voxel_states(fields.occupancy, fields.lattice, np.array([[1.0, 1.0, 1.5]]))
    save_fields(tmp_path / "a.npz", fields)
    np.testing.assert_array_equal(load_fields(tmp_path / "a.npz").visibility, fields.visibility)
    fields.visibility = None
    save_fields(tmp_path / "b.npz", fields)
    assert load_fields(tmp_path / "b.npz").visibility is None


def _numpy_states(occupancy, lattice, origins, settings: VisibilitySettings) -> np.ndarray:
    """`voxel_states` as numpy computed it before the range images' loops were compiled (the outlines
    expanded bin by bin and drawn with `np.minimum.at`, every voxel tested in one broadcast): the reference
    the kernels must equal to the bit."""
    from scipy import ndimage

    from affordcore.geometry import visibility as v

    occupied = occupancy > 0
    state = np.where(occupied, OCCUPIED, UNKNOWN).astype(np.uint8)
    surface = lattice.centres(np.argwhere(occupied))
    axes = [
        (lattice.origin[k] + np.arange(n, dtype=np.float64) * lattice.resolution).astype(np.float32)
        for k, n in enumerate(lattice.shape)
    ]
    n_el, n_az = v._bins(settings.angular_step)
    free = np.zeros(occupied.shape, bool)
    for origin in spread_origins(origins, settings.max_origins):
        first_row, rows, first_column, columns, distance = v._outlines(
            surface - origin, lattice.resolution, settings.angular_step
        )
        count = rows * columns
        owner = np.repeat(np.arange(len(count)), count)
        k = np.arange(owner.size) - np.repeat(np.cumsum(count) - count, count)
        width = columns[owner]
        bins = (first_row[owner] + k // width) * n_az + (first_column[owner] + k % width) % n_az
        image = np.full(n_el * n_az, np.inf)
        np.minimum.at(image, bins, distance[owner])
        image = image.reshape(n_el, n_az)
        gaps = np.isinf(image)
        image[gaps] = ndimage.minimum_filter(image, size=3, mode=("nearest", "wrap"))[gaps]
        image[np.isinf(image)] = 0.0
        x, y, z = (axis - np.float32(o) for axis, o in zip(axes, origin))
        across, column = v._plan(x[:, None], y[None, :], settings.angular_step)
        across = across[:, :, None]
        distance = np.sqrt(across * across + z * z)
        sine = z / np.maximum(distance, np.float32(1e-6))
        to_table = np.float32((v._SINE_TABLE - 1) / 2)
        row = v._elevation_rows(settings.angular_step)[((sine + 1) * to_table).astype(np.int32)]
        free |= distance + lattice.resolution <= image[row, column[:, :, None]]
    state[free & ~occupied] = FREE
    return state


def test_the_compiled_range_images_give_numpy_states_to_the_bit():
    """From inside the partitioned room, from above a wall, from outside it and from under the cabinet's top
    (voxels right beside and right above a sensor span most of the image): the same state in every voxel."""
    from affordcore.geometry import range_images
    from affordcore.geometry.visibility import compile_range_images

    fields = _fields(_room(partition=True))
    origins = np.array(
        [[1.0, 1.0, 1.5], [2.45, 1.5, 2.3], [5.0, -1.0, 1.0], [3.3, 2.3, 0.95], [3.9, 0.2, 0.1]]
    )
    settings = VisibilitySettings(carrier_radius=0)  # the reference knows only what the sensors saw
    compile_range_images()
    compiled = [len(range_images.draw_outlines.signatures), len(range_images.mark_in_front.signatures)]
    state = voxel_states(fields.occupancy, fields.lattice, origins, settings)
    reference = _numpy_states(fields.occupancy, fields.lattice, origins, settings)
    assert (state == FREE).sum() > 1000 and (state == UNKNOWN).sum() > 1000  # both sides of the partition
    np.testing.assert_array_equal(state, reference)
    # compiled once, for the types voxel_states passes: a service's first fields compile nothing more
    assert [
        len(range_images.draw_outlines.signatures),
        len(range_images.mark_in_front.signatures),
    ] == compiled


def test_a_sensor_facing_one_wall_leaves_the_open_side_behind_it_unknown():
    """Directions in which the sensor saw no surface say nothing of the space along them: a wall ahead frees
    the air before it, and the air behind the sensor, where nothing was seen, stays unknown (not free all
    the way to the lattice's edge)."""
    y, z = np.meshgrid(np.arange(0, 3, SPACING), np.arange(0, 2.4, SPACING), indexing="ij")
    wall = np.column_stack([np.full(y.size, 3.0), y.ravel(), z.ravel()])
    x, y = np.meshgrid(np.arange(2.0, 3.0, SPACING), np.arange(0, 3, SPACING), indexing="ij")
    floor = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    fields = _fields(np.concatenate([wall, floor]))
    state = voxel_states(fields.occupancy, fields.lattice, np.array([[2.2, 1.5, 1.2]]))
    behind = np.array([[1.4, 1.5, 1.2], [1.2, 0.8, 1.8], [1.2, 2.2, 0.6]])
    assert np.all(fields.lattice.voxel_of(behind) > 0), "the lattice reaches behind the sensor"
    for xyz in behind:
        assert _state_at(fields, state, xyz) == UNKNOWN, xyz
    for xyz in [(2.6, 1.5, 1.2), (2.8, 1.2, 0.9), (2.6, 1.9, 1.5)]:  # between the sensor and the wall
        assert _state_at(fields, state, xyz) == FREE, xyz


def test_the_space_the_sensor_s_carrier_stood_in_is_free_down_to_the_first_surface_under_it():
    """A camera never sees its own feet: with no floor scanned under it, the column under it, within the
    carrier's radius, is free from the room's lowest surface up to the sensor; beyond the radius, and under
    a top a sensor was held over, space stays as the sensors saw it."""
    x, y = np.meshgrid(np.arange(0, 3, SPACING), np.arange(0, 3, SPACING), indexing="ij")
    x, y = x.ravel(), y.ravel()
    floor = np.column_stack([x, y, np.zeros(x.size)])[x >= 1.5]  # nothing scanned under the first sensor
    top = np.column_stack([x, y, np.full(x.size, 0.7)])[(x > 1.6) & (y > 1.6)]
    fields = _fields(np.concatenate([floor, top]))
    sensors = np.array([[1.0, 1.0, 1.2], [2.5, 2.5, 1.2]])
    seen = voxel_states(fields.occupancy, fields.lattice, sensors, VisibilitySettings(carrier_radius=0))
    state = voxel_states(fields.occupancy, fields.lattice, sensors, VisibilitySettings(carrier_radius=0.2))

    def at(states, xyz):
        return _state_at(fields, states, xyz)

    for xyz in [(1.0, 1.0, 0.1), (1.0, 1.0, 0.6), (1.0, 1.0, 1.2), (1.1, 0.9, 0.3), (1.0, 0.8, 0.2)]:
        assert (at(seen, xyz), at(state, xyz)) == (UNKNOWN, FREE), xyz
    assert at(state, (1.0, 1.0, -0.3)) == UNKNOWN  # not below the room's floor
    for xyz in [(1.4, 1.0, 0.3), (1.0, 1.4, 0.6), (1.0, 1.0, 1.6)]:  # past the radius, above the sensor
        assert at(state, xyz) == at(seen, xyz), xyz
    assert at(state, (2.5, 2.5, 0.7)) == OCCUPIED and at(state, (2.5, 2.5, 1.0)) == FREE  # over the top
    assert at(seen, (2.5, 2.5, 0.2)) == at(state, (2.5, 2.5, 0.2)) == UNKNOWN  # under it, never stood in
