"""Next views: where a robot still mapping a room should look, from the never-seen body space of the places
its maps are unsure of."""

from __future__ import annotations

import numpy as np
import pytest

from affordcore.example import box_surface_points
from affordcore.geometry.fields import compute_fields, disc
from affordcore.geometry.visibility import FREE, OCCUPIED, voxel_states
from affordcore.mapping.next_views import entropy_bits, next_views, seen_by_view
from affordcore.settings import NextViewSettings, NormalSettings, VoxelSettings

SENSOR = np.array([[1.0, 2.0, 1.2]])  # one look, from the room's west end
# the views of the candidates alone (no weight on never-seen space where none stands): what most tests here
# are about
CANDIDATES_ONLY = NextViewSettings(unseen_prior=0.0)


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
    views = next_views(room, candidates, np.array([0.5, 0.5]), 3, CANDIDATES_ONLY)
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


def test_a_camera_sees_what_its_range_and_field_of_view_hold_and_no_surface_hides(room):
    """From the sensor's corner of the room, a camera 1 m up, level, of 58 x 45 degrees and 0.5-4.5 m (the
    defaults, 24 headings 15 degrees apart): which points it sees, turned to which headings."""
    eye, level = np.array([1.0, 2.0, 1.0]), NextViewSettings()
    points = {
        "ahead": (2.0, 2.0, 0.6),
        "behind the cabinet": (4.0, 2.0, 0.6),  # the cabinet (1.2 m tall) stands on the line
        "over the cabinet": (4.0, 2.0, 1.8),  # the line passes 0.3 m above it
        "on the cabinet's face": (2.85, 2.0, 0.6),  # a target's own surroundings hide nothing
        "too far": (5.5, 3.8, 1.8),  # 4.9 m, past the cabinet's top
        "too high": (1.5, 2.0, 2.0),  # 63 degrees above the horizon
        "to the right": (1.0, 0.5, 1.0),  # azimuth -90 degrees: heading 18 of 24
        "too near": (1.3, 2.0, 1.0),
    }
    targets = np.array(list(points.values()))
    seen = {}
    for heading in range(level.headings):
        for name, sees in zip(points, seen_by_view(room, eye, heading, targets, level)):
            if sees:
                seen.setdefault(name, set()).add(heading)
    # 29 degrees either side of the heading: the headings -15, 0 and +15 degrees see a point straight ahead
    assert seen == {
        "ahead": {23, 0, 1},
        "over the cabinet": {23, 0, 1},
        "on the cabinet's face": {23, 0, 1},
        "to the right": {17, 18, 19},
    }
    far = NextViewSettings(max_range=6.0)
    assert seen_by_view(room, eye, 1, targets, far)[list(points).index("too far")]  # 21 degrees off ahead
    tilted = NextViewSettings(pitch_deg=45.0)  # the point is 18 degrees above the tilted axis
    assert seen_by_view(room, eye, 0, targets, tilted)[list(points).index("too high")]
    assert not seen_by_view(room, eye, 0, targets, tilted)[list(points).index("ahead")]  # 66 degrees below it


def test_places_the_maps_are_sure_of_and_seen_places_ask_for_no_view(room):
    sure = next_views(room, np.array([[4.0, 2.0]]), np.array([0.999]), 3, CANDIDATES_ONLY)
    assert not sure or sure[0].gain < 0.02
    seen = next_views(room, np.array([[1.8, 1.0]]), np.array([0.5]), 3, CANDIDATES_ONLY)
    assert seen == []  # its body space was seen: nothing a look could add


def test_a_narrower_range_sees_less_and_a_cloud_without_positions_is_refused(room):
    candidates, p = np.array([[4.0, 2.0], [5.2, 3.2]]), np.array([0.5, 0.5])
    far = next_views(room, candidates, p, 1, CANDIDATES_ONLY)[0].gain
    near = next_views(room, candidates, p, 1, NextViewSettings(max_range=1.2, unseen_prior=0.0))
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


def _candidates(affordance: str, rows) -> object:
    """What `suggest_views` reads of an affordance map: its name and its candidates (x, y, z, theta, score,
    probability)."""
    from types import SimpleNamespace

    candidates = np.array([[x, y, 0.45, 0.0, 1.0, p] for x, y, p in rows]).reshape(-1, 6)
    return SimpleNamespace(affordance=affordance, candidates=candidates)


def test_a_robot_s_views_settle_every_affordance_s_candidates_together(room):
    """One robot, two maps: the hidden candidate is the working map's; the pooled views look at it and name
    its affordance, and its gain is what the same candidate alone gives. No count, or no sensor positions:
    no views."""
    from affordcore.mapping.next_views import suggest_views
    from affordcore.settings import Settings

    settings = Settings()
    settings.next_views.count, settings.next_views.unseen_prior = 2, 0.0  # the candidates' views alone
    relaxing = _candidates("sitting-relaxing", [(1.8, 1.0, 0.5)])  # in full view
    working = _candidates("sitting-working", [(4.0, 2.0, 0.5)])  # behind the cabinet
    views = suggest_views(room, [relaxing, working], settings)
    assert views and views[0].affordances[0] == "sitting-working"
    np.testing.assert_allclose(views[0].looks_at[0], [4.0, 2.0, 0.5])
    alone = next_views(room, working.candidates[:, :2], working.candidates[:, 5], 1, CANDIDATES_ONLY)
    assert views[0].gain == pytest.approx(alone[0].gain)
    assert views[0].to_json()["looks_at"][0]["affordance"] == "sitting-working"
    settings.next_views.count = 0
    assert suggest_views(room, [relaxing, working], settings) == []
    settings.next_views.count = 2
    room.visibility, kept = None, room.visibility
    try:
        assert suggest_views(room, [relaxing, working], settings) == []
    finally:
        room.visibility = kept


def test_next_views_on_the_wire_carry_each_view_s_pose_gain_places_and_the_camera(room):
    from affordwire import messages

    working = _candidates("sitting-working", [(4.0, 2.0, 0.5), (5.2, 3.2, 0.4)])
    views = next_views(room, working.candidates[:, :2], working.candidates[:, 5], 2, CANDIDATES_ONLY)
    for view in views:
        view.affordances = ["sitting-working"] * len(view.places)
    fields = messages.SceneFieldsMessage(frames=3, scans_received=4)
    fields.cloud_timestamp.FromNanoseconds(1_700_000_000_500_000_000)
    camera = NextViewSettings(pitch_deg=-10.0)
    wire = messages.parse(
        messages.NextViewsMessage, messages.next_views_message(views, camera, fields).SerializeToString()
    )
    assert wire.frame_id == "world" and (wire.frames, wire.scans_received) == (3, 4)
    assert wire.cloud_timestamp.ToNanoseconds() == 1_700_000_000_500_000_000
    assert wire.camera.pitch == pytest.approx(np.radians(-10.0))
    assert wire.camera.fov_horizontal == pytest.approx(np.radians(58.0))
    assert len(wire.views) == len(views) > 0
    for sent, view in zip(wire.views, views):
        p, q = sent.pose.position, sent.pose.orientation
        assert (p.x, p.y, p.z) == pytest.approx((view.x, view.y, view.z))
        yaw = np.arctan2(2 * q.w * q.z, 1 - 2 * q.z**2)
        assert abs(q.x) + abs(q.y) < 1e-12 and np.angle(np.exp(1j * (yaw - view.heading))) == pytest.approx(0)
        assert sent.gain == pytest.approx(view.gain)
        assert [(s.affordance, s.x, s.y) for s in sent.places] == [
            ("sitting-working", x, y) for x, y, _ in view.looks_at
        ]


def _room_with_a_hidden_seat():
    """The cabinet room of `_room` with a seat east of the cabinet, which the sensor west of it never saw:
    (points, fields with the sensor's visibility)."""
    rng = np.random.default_rng(1)
    boxes = [((0, 0, 0), (6, 4, 0)), ((0, -0.1, 0), (6, 0, 2.4)), ((2.9, 1.0, 0), (3.1, 3.0, 1.2))]
    boxes += [((4.2, 1.5, 0), (5.0, 2.3, 0.45)), ((4.9, 1.5, 0.45), (5.0, 2.3, 0.9))]
    points = np.concatenate([box_surface_points(np.array(a), np.array(b), 3000, rng) for a, b in boxes])
    fields = compute_fields(points, VoxelSettings(), NormalSettings())
    fields.visibility = voxel_states(fields.occupancy, fields.lattice, SENSOR)
    return points, fields


def test_the_inference_service_publishes_a_robot_s_next_views_on_the_wire_on_ros_2_and_in_its_recording(
    tmp_path, monkeypatch
):
    """With AFFORD_NEXT_VIEWS__COUNT, the maps of fields that carry the sensor's visibility are followed by
    one NextViews over every affordance on next-views (answered to a late get too), the views as a PoseArray
    and the best as a PoseStamped goal on the floor on ROS 2, and frusta in the recording."""
    pytest.importorskip("rosbags")

    from conftest import eventually
    from test_ros_maps import running_inference

    from affordcore.geometry.features import FeatureLayout
    from affordcore.learn.model import choose_models
    from affordcore.mapping.recording import recorded_entities
    from affordwire import messages, ros, ros_maps
    from services.ros_maps import rmw_zenoh_key, view_topics
    from services.settings import ServiceSettings
    from services.transport import Keys, put_message

    monkeypatch.setenv("AFFORD_NEXT_VIEWS__COUNT", "2")
    monkeypatch.setenv("AFFORD_ROS__MAPS", "true")
    settings = ServiceSettings()
    models = choose_models([], [], FeatureLayout.from_settings(settings))
    points, fields = _room_with_a_hidden_seat()
    cloud = messages.cloud_message(points, np.eye(4), "test", at=1.7e9)
    sent = messages.fields_message(fields, cloud, at=1.7e9)
    topics = view_topics(settings.ros.maps_namespace, "robot-1")
    ros_keys = {"views": rmw_zenoh_key(0, topics["views"], ros_maps.VIEWS)}
    ros_keys["goal"] = rmw_zenoh_key(0, topics["goal"], ros_maps.GOAL)

    keys, heard = Keys("robot-1"), {}
    with running_inference(settings, models, tmp_path / "i.rrd") as client:
        held = [client.declare_subscriber(keys.next_views, lambda s: heard.setdefault("wire", []).append(s))]
        held += [
            client.declare_subscriber(key, lambda s, kind=kind: heard.setdefault(kind, []).append(s))
            for kind, key in ros_keys.items()
        ]
        put_message(client, keys.fields, sent)
        assert eventually(lambda: {"wire", "views", "goal"} <= heard.keys(), timeout=120, poll=0.1), heard
        wire = messages.parse(messages.NextViewsMessage, heard["wire"][0].payload.to_bytes())
        replies = [r.ok for r in client.get(keys.next_views, timeout=5) if r.ok is not None]
        assert [r.payload.to_bytes() for r in replies] == [heard["wire"][-1].payload.to_bytes()]
    assert 1 <= len(wire.views) <= 2 and wire.views[0].gain > 0
    from services.clients import describe  # what afford watch prints of it
    from services.transport import schema_of

    said = describe(keys.next_views, schema_of(heard["wire"][0]), heard["wire"][0].payload.to_bytes())
    best = wire.views[0].pose.position
    assert f"next views, the best at ({best.x:.2f}, {best.y:.2f}) facing" in said, said
    assert {place.affordance for view in wire.views for place in view.places} <= {
        m.affordance for m in models
    }
    store = ros.typestore()
    poses = store.deserialize_cdr(heard["views"][-1].payload.to_bytes(), ros_maps.VIEWS).poses
    goal = store.deserialize_cdr(heard["goal"][-1].payload.to_bytes(), ros_maps.GOAL)
    np.testing.assert_allclose(
        [(p.position.x, p.position.y, p.position.z) for p in poses],
        [(v.pose.position.x, v.pose.position.y, v.pose.position.z) for v in wire.views],
    )
    assert (goal.pose.position.x, goal.pose.position.y, goal.pose.position.z) == pytest.approx(
        (best.x, best.y, 0)
    )
    assert goal.header.frame_id == "world"
    entities = recorded_entities(tmp_path / "i.rrd")
    assert {f"/world/next_views/{rank}" for rank in range(len(wire.views))} <= entities
    assert {"/plan/next_views", "/plan/next_views/fov", "/plan/next_views/looks"} <= entities


def test_with_a_prior_on_unseen_space_a_view_looks_where_no_candidate_stands_yet(room):
    """A map sure of its one candidate asks for no view; told that never-seen body space holds a place one
    time in five, it asks for the view that sees behind the cabinet, where the room was never seen, and that
    view names no candidate."""
    sure = np.array([[1.8, 1.0]]), np.array([0.999])
    assert next_views(room, *sure, 2, CANDIDATES_ONLY) == []
    views = next_views(room, *sure, 2, NextViewSettings(unseen_prior=0.2))
    assert views and views[0].gain > 0.05 and views[0].places == []
    heading = np.array([np.cos(views[0].heading), np.sin(views[0].heading)])
    behind = np.array([4.5, 2.0]) - np.array([views[0].x, views[0].y])
    assert heading @ behind / np.linalg.norm(behind) > np.cos(np.radians(29 + 15))  # facing the hidden half


def test_maps_with_no_candidate_yet_still_ask_to_look_where_places_may_hide(room):
    """A robot's first frame may show no candidate at all: its views look at the never-seen room, unless
    the prior on unseen space is 0."""
    from affordcore.mapping.next_views import suggest_views
    from affordcore.settings import Settings

    settings = Settings()
    settings.next_views.count = 2
    empty = [_candidates(name, []) for name in ("sitting-relaxing", "standing-working")]
    views = suggest_views(room, empty, settings)
    assert views and views[0].places == [] and views[0].affordances == []
    assert views[0].x > 1.5  # it walks east, towards the cabinet and the room behind it
    settings.next_views.unseen_prior = 0.0
    assert suggest_views(room, empty, settings) == []


def test_a_robot_can_be_sent_back_to_where_its_sensor_stood():
    """A camera never sees the floor at its own feet: with the floor within 1.5 m of the sensor unscanned
    (a depth camera's first frame), the spot it stood on reads as never seen. The carrier's space
    (`VisibilitySettings.carrier_radius`) makes it standable, so a view can turn the robot where it is."""
    from affordcore.mapping.next_views import _standable
    from affordcore.settings import VisibilitySettings

    rng = np.random.default_rng(2)
    floor = box_surface_points(np.array((0, 0, 0)), np.array((6, 4, 0)), 20000, rng)
    floor = floor[np.hypot(*(floor[:, :2] - SENSOR[0, :2]).T) > 1.5]
    walls = [((0, -0.1, 0), (6, 0, 2.4)), ((0, 4, 0), (6, 4.1, 2.4)), ((-0.1, 0, 0), (0, 4, 2.4))]
    walls = [box_surface_points(np.array(a), np.array(b), 4000, rng) for a, b in walls]
    points = np.concatenate([floor, *walls])
    fields = compute_fields(points, VoxelSettings(), NormalSettings())
    spots = {}
    for radius in (0.0, 0.2):
        fields.visibility = voxel_states(
            fields.occupancy, fields.lattice, SENSOR, VisibilitySettings(carrier_radius=radius)
        )
        positions = _standable(fields, CANDIDATES_ONLY, 1.0)
        spots[radius] = np.hypot(*(positions - SENSOR[0, :2]).T).min()
    assert spots[0.0] > 0.3 and spots[0.2] < 0.15


def test_a_view_in_json_names_each_place_it_looks_at_where_it_is_and_how_likely():
    from affordcore.mapping.next_views import NextView

    view = NextView(
        1.23456,
        -2.5,
        1.0,
        0.123456,
        1.98766,
        [4, 1],
        np.array([[0.12345, 3.45678, 0.512345], [2, -1, 1]]),
        ["a", "b"],
    )
    assert view.to_json() == {
        "x": 1.235,
        "y": -2.5,
        "z": 1.0,
        "heading": 0.1235,
        "gain": 1.9877,
        "looks_at": [
            {"x": 0.123, "y": 3.457, "probability": 0.5123, "affordance": "a"},
            {"x": 2.0, "y": -1.0, "probability": 1.0, "affordance": "b"},
        ],
    }
