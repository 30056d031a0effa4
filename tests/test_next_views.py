"""Next views: where a robot still mapping a room should look, from the never-seen body space of the places
its maps are unsure of."""

from __future__ import annotations

import numpy as np
import pytest

from affordcore.example import box_surface_points
from affordcore.geometry.fields import compute_fields, disc
from affordcore.geometry.visibility import FREE, OCCUPIED, voxel_states
from affordcore.mapping.next_views import entropy_bits, next_views
from affordcore.settings import NextViewSettings, NormalSettings, VoxelSettings

SENSOR = np.array([[1.0, 2.0, 1.2]])  # one look, from the room's west end


def _room():
    """A 6 m x 4 m room, walls 2.4 m high, and a cabinet 1.2 m tall and 2 m wide across the middle (x 2.9 to
    3.1), the sensor west of it: the space east of the cabinet, behind it, is never seen."""
    rng = np.random.default_rng(0)
    boxes = [
        ((0, 0, 0), (6, 4, 0)),
        ((0, -0.1, 0), (6, 0, 2.4)),
        ((0, 4, 0), (6, 4.1, 2.4)),
        ((-0.1, 0, 0), (0, 4, 2.4)),
        ((6, 0, 0), (6.1, 4, 2.4)),
        ((2.9, 1.0, 0), (3.1, 3.0, 1.2)),
    ]
    points = np.concatenate([box_surface_points(np.array(a), np.array(b), 4000, rng) for a, b in boxes])
    fields = compute_fields(points, VoxelSettings(), NormalSettings())
    fields.visibility = voxel_states(fields.occupancy, fields.lattice, SENSOR)
    return fields


@pytest.fixture(scope="module")
def room():
    return _room()


def test_entropy_is_a_bit_at_even_odds_and_nothing_when_sure():
    np.testing.assert_allclose(entropy_bits([0.5, 0.0, 1.0, 0.1]), [1.0, 0.0, 0.0, 0.469], atol=1e-3)


def test_the_best_view_looks_behind_what_hid_the_unsure_place(room):
    """Two candidates at even odds: one west of the cabinet in full view, one east of it, behind it. The best
    view is the one that sees behind the cabinet: it looks at the hidden candidate, from where the robot can
    stand, and turned towards it."""
    candidates = np.array([[1.8, 1.0], [4.0, 2.0]])
    views = next_views(room, candidates, np.array([0.5, 0.5]), 3)
    assert views and views[0].places[0] == 1
    best = views[0]
    towards = np.arctan2(2.0 - best.y, 4.0 - best.x)
    assert abs(np.angle(np.exp(1j * (best.heading - towards)))) <= np.radians(29 + 8)
    assert best.gain > 0.3  # most of a bit: most of its body space was never seen, and now would be
    assert [v.gain for v in views] == sorted((v.gain for v in views), reverse=True)
    # it stands where the robot can: nothing within its footprint, most of its own column seen free
    lattice = room.lattice
    for view in views:
        i, j = np.rint((np.array([view.x, view.y]) - lattice.origin[:2]) / lattice.resolution).astype(int)
        floor = 10  # the lattice's layer of the floor (it starts a metre below it)
        around = room.visibility[i - 3 : i + 4, j - 3 : j + 4, floor + 2 : floor + 11][disc(3)]
        assert not (around == OCCUPIED).any()
        assert (room.visibility[i, j, floor + 2 : floor + 11] == FREE).mean() >= 0.5
        assert view.z == pytest.approx(1.0)  # the camera's height above the floor (at z = 0)


def test_places_the_maps_are_sure_of_and_seen_places_ask_for_no_view(room):
    sure = next_views(room, np.array([[4.0, 2.0]]), np.array([0.999]), 3)
    assert not sure or sure[0].gain < 0.02
    seen = next_views(room, np.array([[1.8, 1.0]]), np.array([0.5]), 3)
    assert seen == []  # its body space was seen: nothing a look could add


def test_a_narrower_range_sees_less_and_a_cloud_without_positions_is_refused(room):
    candidates, p = np.array([[4.0, 2.0], [5.2, 3.2]]), np.array([0.5, 0.5])
    far = next_views(room, candidates, p, 1)[0].gain
    near = next_views(room, candidates, p, 1, NextViewSettings(max_range=1.2))
    assert not near or near[0].gain < far
    room.visibility, kept = None, room.visibility
    try:
        with pytest.raises(ValueError, match="sensor positions"):
            next_views(room, candidates, p, 1)
    finally:
        room.visibility = kept


def test_afford_map_writes_next_views_into_each_map_and_refuses_them_without_sensor_positions(tmp_path):
    import json
    import subprocess
    import sys

    from affordcore.geometry.scene import Cloud, save_cloud

    rng = np.random.default_rng(1)
    boxes = [((0, 0, 0), (6, 4, 0)), ((0, -0.1, 0), (6, 0, 2.4)), ((2.9, 1.0, 0), (3.1, 3.0, 1.2))]
    boxes += [((4.2, 1.5, 0), (5.0, 2.3, 0.45)), ((4.9, 1.5, 0.45), (5.0, 2.3, 0.9))]  # a seat behind it
    points = np.concatenate([box_surface_points(np.array(a), np.array(b), 3000, rng) for a, b in boxes])
    cloud = tmp_path / "room.ply"
    save_cloud(cloud, Cloud(points))
    afford = [sys.executable, "-m", "affordcli", "map", str(cloud), "--gravity", "none", "--no-rrd", "-q"]
    refused = subprocess.run(
        afford + ["--out", str(tmp_path / "a"), "--next-views", "2"], capture_output=True, text=True
    )
    assert refused.returncode == 2 and "--next-views needs the sensor positions" in refused.stderr
    np.save(tmp_path / "room.origins.npy", SENSOR.astype(np.float32))
    done = subprocess.run(
        afford + ["--out", str(tmp_path / "b"), "--next-views", "2"], capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    documents = [json.loads(p.read_text()) for p in sorted((tmp_path / "b").glob("*.json"))]
    assert len(documents) == 3
    for document in documents:
        for view in document.get("next_views", []):
            assert set(view) == {"x", "y", "z", "heading", "gain", "looks_at"} and view["gain"] >= 0.01
    assert any(document.get("next_views") for document in documents), done.stdout
