"""The furniture real rooms have: counter-height seating (bar stools, high chairs), lounge chairs, chaises,
chairs pushed as far as they go, swivel chairs turned away from desks, things left on seats, and in the
extended furniture round tables, low loveseats and ottomans; their labels and the pose grid that must reach
them."""

from __future__ import annotations

import numpy as np
import pytest

from affordcore.geometry.grid import PoseGrid
from affordcore.geometry.skeleton import JOINTS, get_skeleton, place_joints
from affordcore.labels import polygon_contains
from affordcore.synth import furniture as F
from affordcore.synth.dataset import SynthOptions
from affordcore.synth.rooms import generate_room, role_affordances
from affordcore.synth.shapes import Box, boxes_overlap, disc

SEEDS = range(25)
COUNTER_SEATING = {
    "kitchen island": F.kitchen_island,
    "bar table": F.bar_table,
    "breakfast bar": lambda rng: F.bar_table(rng, both_sides=False),
}


@pytest.fixture
def no_chairs(monkeypatch):
    """Every place's chair missing: what is left of a piece is the furniture a person must not enter."""
    monkeypatch.setattr(F, "chair_state", lambda rng, seat_depth: ("missing", 0.0, 0.0))


def _skeleton_of(anchor):
    return get_skeleton(role_affordances()[anchor.role])


def _torso(anchor) -> float:
    return _skeleton_of(anchor).torso_height if anchor.torso_height is None else anchor.torso_height


HANDS = [JOINTS.index("L_HAND"), JOINTS.index("R_HAND")]
RESTING = 0.10  # work surfaces are 0.70-1.05 m high, the skeletons' hands at one height: they rest on it


def _joints_inside(piece, anchor) -> list[str]:
    """Which of the anchor's skeleton joints (at its torso height, anywhere along it) are inside a part; a
    hand may be in a work surface whose top is at most RESTING above it (it rests on that surface)."""
    skeleton, hits = _skeleton_of(anchor), []
    for t in (0.0, 0.5, 1.0):
        xy = np.add(anchor.start, t * np.subtract(anchor.end, anchor.start))
        joints = place_joints(skeleton.joints, np.array([[*xy, _torso(anchor), anchor.facing]]))[0]
        for k, joint in enumerate(joints):
            dot = Box(tuple(joint), (0.02, 0.02, 0.02))
            hits += [
                f"{JOINTS[k]} in {part}"
                for part in piece.parts
                if boxes_overlap(dot, part) and not (k in HANDS and part.z_range[1] - joint[2] <= RESTING)
            ]
    return hits


def _seat_places(piece):
    return [anchor for anchor in piece.anchors if anchor.role == F.DESK_SEAT]


def test_bar_stool_seats_are_counter_seat_height_below_their_top():
    rng = np.random.default_rng(0)
    for top in np.linspace(*F.BAR_TOP, 40):
        seat = F.bar_seat_height(rng, top)
        assert F.BAR_SEAT[0] <= seat <= F.BAR_SEAT[1]
        assert F.BAR_GAP[0] - 1e-9 <= top - seat <= F.BAR_GAP[1] + 1e-9
        for back in (False, True):
            stool = F.bar_stool(rng, seat, back)
            assert stool[0].z_range[1] == pytest.approx(seat)  # the seat comes first, its top at seat
            assert max(part.z_range[1] for part in stool) > seat + 0.25 if back else True


@pytest.mark.parametrize("name", COUNTER_SEATING)
def test_high_chair_places_lie_within_the_sitting_working_grid(name):
    """Every counter-height place's torso lies within half a voxel of a torso level the grid tries."""
    checked = 0
    for seed in SEEDS:
        piece = COUNTER_SEATING[name](np.random.default_rng(seed))
        for anchor in _seat_places(piece):
            skeleton = _skeleton_of(anchor)
            grid = PoseGrid.over_footprint(
                (0, 0, 1, 1), skeleton.torso_height, 0.1, None, skeleton.torso_reach_above
            )
            assert anchor.torso_height is not None and anchor.torso_height > skeleton.torso_height + 0.15
            assert np.abs(grid.z - anchor.torso_height).min() <= 0.05 + 1e-9, (piece.note, grid.z)
            checked += 1
    assert checked >= len(SEEDS)


def test_a_skeleton_without_the_reach_keeps_design_s_three_levels():
    grid = PoseGrid.over_footprint((0, 0, 1, 1), 0.635, 0.1)
    np.testing.assert_allclose(grid.z, [0.535, 0.635, 0.735])
    high = PoseGrid.over_footprint((0, 0, 1, 1), 0.635, 0.1, None, 0.35)
    np.testing.assert_allclose(high.z, [0.535, 0.635, 0.735, 0.835, 0.935])
    assert get_skeleton("sitting-working").torso_reach_above == 0.35
    assert get_skeleton("standing-working").torso_reach_above == 0.0


@pytest.mark.parametrize(
    "builder",
    [
        *COUNTER_SEATING.values(),
        lambda rng: F.lounge_chair(rng, things=False),
        F.chaise_sofa,
        lambda rng: F.armchair(rng, things=False),
        F.meeting_table,
        F.desk,
        F.round_table,
        lambda rng: F.loveseat(rng, things=False),
    ],
)
def test_every_new_piece_s_label_has_room_for_its_skeleton(builder, no_chairs):
    """At its own torso height (a bar stool's place higher than a desk chair's), no joint of a place's
    skeleton is inside the furniture it uses (its chair left out: the label is where a person who pulled it
    out sits)."""
    for seed in SEEDS:
        piece = builder(np.random.default_rng(seed))
        assert piece.anchors, piece.note
        for anchor in piece.anchors:
            assert not _joints_inside(piece, anchor), (seed, piece.note, anchor.note)


def test_counter_height_places_are_labelled_like_table_places(no_chairs):
    for seed in SEEDS:
        island = F.kitchen_island(np.random.default_rng(seed))
        top = island.parts[0]
        edge = top.corners_xy()[:, 0].max()
        places = _seat_places(island)
        assert 2 <= len(places) <= 4 or top.size[1] < 1.4
        for anchor in places:
            assert anchor.start[0] == pytest.approx(edge + F.DESK_LABEL_OFFSET) and anchor.is_point
            assert anchor.facing == pytest.approx(np.pi)
        standing = [a for a in island.anchors if a.role == F.STANDING_EDGE]
        assert len(standing) == 2  # the kitchen side and the free edge over the stools


def _office_chair_without_armrests():
    for seed in range(50):
        chair = F.office_chair(np.random.default_rng(seed))
        if len(chair) == 8:  # seat, backrest, post, five feet: no armrests
            return chair
    raise AssertionError("no office chair without armrests")


@pytest.mark.parametrize("maker, backrest", [("office", 0.0), ("dining", 0.03), ("stool", 0.0)])
def test_a_chair_pushed_as_far_as_it_goes_has_its_seat_under_the_top(monkeypatch, maker, backrest):
    """Seat entirely under the top in plan (a dining chair's backrest, standing on the seat's rear, against
    the edge), nothing of it inside the table."""
    monkeypatch.setattr(F, "chair_state", lambda rng, seat_depth: ("pushed-in", np.inf, 0.0))
    makers = {
        "office": lambda rng: _office_chair_without_armrests(),
        "dining": F.dining_chair,
        "stool": lambda rng: F.bar_stool(rng, 0.50),
    }
    for seed in range(10):
        rng = np.random.default_rng(seed)
        parts = F.table(rng, 1.6, 0.8, 0.74 if maker != "stool" else 0.74)
        top, edge = parts[0], 0.4
        anchor = F._add_chair(rng, parts, edge, 0.0, makers[maker])
        assert "as far as it goes" in anchor.note, anchor.note
        seat = parts[len(F.table(np.random.default_rng(0), 1.6, 0.8, 0.74))]
        assert seat.corners_xy()[:, 0].max() <= edge + backrest + 1e-6  # under the top, but for the backrest
        assert seat.corners_xy()[:, 0].min() < edge - 0.3  # well under, not at the edge
        if maker == "office":
            assert seat.corners_xy()[:, 0].max() == pytest.approx(edge, abs=1e-6)  # backrest touches the edge
        assert top.contains_xy(seat.corners_xy() - [backrest + 1e-6, 0]).all()


def test_pushed_in_chairs_are_often_as_far_as_they_go():
    notes = [a.note for seed in range(40) for a in F.meeting_table(np.random.default_rng(seed)).anchors]
    pushed = [note for note in notes if "pushed in" in note]
    fully = [note for note in pushed if "as far as it goes" in note]
    assert 0.15 * len(pushed) <= len(fully) <= 0.6 * len(pushed)


def test_desks_get_swivel_chairs_turned_away_and_the_label_stays_at_the_desk():
    turned = 0
    for seed in range(80):
        desk = F.desk(np.random.default_rng(seed))
        (anchor,) = desk.anchors
        edge = desk.parts[0].corners_xy()[:, 0].max()
        assert anchor.start[0] == pytest.approx(edge + F.DESK_LABEL_OFFSET)
        assert anchor.facing == pytest.approx(np.pi)
        turned += "turned" in anchor.note
    assert turned >= 5


def test_lounge_chairs_are_low_with_a_reclined_back():
    for seed in SEEDS:
        chair = F.lounge_chair(np.random.default_rng(seed), things=False)
        seat = chair.parts[0]
        assert 0.35 <= seat.z_range[1] <= 0.42
        (anchor,) = chair.anchors
        assert anchor.torso_height == pytest.approx(seat.z_range[1] + F.TORSO_ABOVE_SEAT)
        backs = sorted(
            (p for p in chair.parts if p.z_range[0] >= seat.z_range[1] - 1e-9), key=lambda p: p.centre[2]
        )
        fronts = [p.corners_xy()[:, 0].max() for p in backs if p.size[1] >= seat.size[1] - 1e-6]
        assert len(fronts) >= 3 and np.all(np.diff(fronts) < 0)  # each step of the backrest further back


def test_a_chaise_is_a_seat_with_no_label_beside_the_labelled_seats():
    for seed in SEEDS:
        piece = F.chaise_sofa(np.random.default_rng(seed))
        ((x0, y0), (x1, y1)) = piece.unlabelled_seats[-1]
        assert x1 - x0 > piece.parts[0].size[0] + 0.45  # the seat runs on forward
        (anchor,) = piece.anchors
        ys = np.array([anchor.start[1], anchor.end[1]])
        gap = np.minimum(np.abs(ys - y0), np.abs(ys - y1)).min()
        assert gap >= F.SEAT_INSET - 1e-9 and not ((ys > y0) & (ys < y1)).any()


def _room_with(piece):
    room = generate_room("living", np.random.default_rng(0), "seat-things")
    piece.x, piece.y, piece.yaw = 2.0, 2.0, 0.3
    room.pieces = [piece]
    return room


@pytest.mark.slow
def test_a_big_box_filling_a_seat_makes_it_an_unlabelled_region(monkeypatch):
    monkeypatch.setattr(F, "BIG_BOX_SHARE", 1.0)
    for seed in range(8):
        for builder in (F.armchair, F.lounge_chair, lambda rng: F.sofa(rng, seats=3)):
            piece = builder(np.random.default_rng(seed))
            box = piece.parts[-1]
            room = _room_with(piece)
            labels = room.labels()
            centre = piece.world_point(box.centre[:2])
            regions = [np.array(r["polygon"]) for r in labels["unlabelled_regions"]]
            assert any(polygon_contains(region, centre[None])[0] for region in regions), piece.note
            points = room.label_points()
            assert not len(points) or np.linalg.norm(points - centre, axis=1).min() > 0.25
            if piece.kind != "sofa":
                assert labels["labels"] == []  # a one-seat piece with a box on it is no place


def test_small_things_on_a_seat_keep_its_label(monkeypatch):
    monkeypatch.setattr(F, "BIG_BOX_SHARE", 0.0)
    monkeypatch.setattr(F, "SMALL_THINGS_SHARE", 1.0)
    for seed in range(8):
        bare = F.sofa(np.random.default_rng(seed), things=False)
        cluttered = F.sofa(np.random.default_rng(seed))
        assert len(cluttered.parts) > len(bare.parts)
        assert [(a.start, a.end) for a in cluttered.anchors] == [(a.start, a.end) for a in bare.anchors]
        assert not cluttered.unlabelled_seats


def test_rooms_hold_the_new_pieces_and_the_same_seed_makes_the_same_room():
    kinds = {}
    for kind in ("living", "mixed"):
        for seed in range(15):
            room = generate_room(kind, np.random.default_rng(seed), f"{kind}-{seed}")
            kinds |= {piece.kind: room.name for piece in room.pieces}
    assert {"kitchen-island", "lounge-chair", "chaise-sofa"} <= set(kinds), sorted(kinds)
    assert {"bar-table", "breakfast-bar"} & set(kinds)
    a = generate_room("living", np.random.default_rng(7), "same")
    b = generate_room("living", np.random.default_rng(7), "same")
    assert a.labels() == b.labels()
    assert [(p.note, p.x, p.y, p.yaw, p.parts) for p in a.pieces] == [
        (p.note, p.x, p.y, p.yaw, p.parts) for p in b.pieces
    ]


def test_a_disc_fills_its_polygon_and_stays_inside_its_circle():
    radius, sides = 0.55, 16
    boxes = disc(radius, 0.70, 0.73, (0.5, 0.5, 0.5), sides)
    assert len(boxes) == sides // 2
    xy = np.stack(np.meshgrid(*[np.linspace(-0.7, 0.7, 141)] * 2), axis=-1).reshape(-1, 2)
    inside = np.any([box.contains_xy(xy) for box in boxes], axis=0)
    distance = np.hypot(*xy.T)
    apothem = radius * np.cos(np.pi / sides)
    assert inside[distance < apothem - 1e-9].all()  # no hole between the boxes
    assert not inside[distance > radius + 1e-9].any()
    assert all(box.z_range == pytest.approx((0.70, 0.73)) for box in boxes)


def test_round_table_places_face_its_centre_evenly_spread_outside_its_edge():
    spreads = set()
    for seed in SEEDS:
        table = F.round_table(np.random.default_rng(seed))
        top = table.parts[0]
        radius = np.hypot(*top.size[:2]) / 2  # the polygon's corners lie on the circle
        places = np.array([anchor.start for anchor in table.anchors])
        assert 3 <= len(places) <= 6 and all(anchor.is_point for anchor in table.anchors)
        distance = np.hypot(*places.T)
        assert distance == pytest.approx(radius * np.cos(np.pi / 16) + F.DESK_LABEL_OFFSET)
        for (x, y), anchor in zip(places, table.anchors):  # facing the centre
            assert np.cos(anchor.facing - np.arctan2(-y, -x)) == pytest.approx(1.0)
        angles = np.sort(np.arctan2(places[:, 1], places[:, 0]))
        gaps = np.diff(np.append(angles, angles[0] + 2 * np.pi))
        assert gaps == pytest.approx(2 * np.pi / len(places))
        assert np.pi * 2 * radius / len(places) >= F.ROUND_PLACE_SPACING or len(places) == 3
        spreads.add(len(places))
    assert len(spreads) >= 3  # small and large tables


def test_round_table_chairs_are_pushed_under_its_top_or_left_out():
    """Pushed-in chairs reach inside the top's circle; every chair stays out of the top and its base."""
    under = 0
    for seed in SEEDS:
        table = F.round_table(np.random.default_rng(seed))
        radius = np.hypot(*table.parts[0].size[:2]) / 2
        chairs = [anchor for anchor in table.anchors if anchor.labelled]
        furniture = [p for p in table.parts if not any(p in anchor.support for anchor in chairs)]
        for anchor in chairs:
            seat = anchor.support[0]
            assert not any(boxes_overlap(part, other) for part in anchor.support for other in furniture)
            if "pushed in" in anchor.note:
                inner = np.hypot(*seat.corners_xy().T).min()
                under += inner < radius - 0.05
    assert under >= 10


def test_loveseats_are_low_two_seat_sofas_with_a_reclined_back():
    for seed in SEEDS:
        sofa = F.loveseat(np.random.default_rng(seed), things=False)
        seat = sofa.parts[0]
        assert F.LOW_SOFA["seat"][0] <= seat.z_range[1] <= F.LOW_SOFA["seat"][1]
        assert max(part.z_range[1] for part in sofa.parts) <= F.LOW_SOFA["back"][1]
        (anchor,) = sofa.anchors
        assert anchor.role == F.LOUNGE and not anchor.is_point
        backs = sorted(
            (p for p in sofa.parts if p.z_range[0] >= seat.z_range[1] - 1e-9 and p.size[1] >= seat.size[1]),
            key=lambda p: p.centre[2],
        )
        rears = [p.corners_xy()[:, 0].min() for p in backs]
        assert len(rears) == 3 and np.all(np.diff(rears) < 0)  # each step of the backrest further back


def test_an_ottoman_is_a_seat_no_label_describes():
    for seed in range(5):
        ottoman = F.ottoman(np.random.default_rng(seed))
        assert not ottoman.anchors and ottoman.unlabelled_seats
        assert 0.38 <= ottoman.parts[0].z_range[1] <= 0.46


def test_only_extended_rooms_hold_the_extended_pieces():
    extended = {"round-table", "low-sofa", "ottoman"}
    held = {"base": set(), "extended": set()}
    for furniture in held:
        for kind in ("living", "office"):
            for seed in range(12):
                room = generate_room(kind, np.random.default_rng(seed), f"{kind}-{seed}", furniture)
                held[furniture] |= {piece.kind for piece in room.pieces}
    assert not held["base"] & extended
    assert extended <= held["extended"]
    with pytest.raises(ValueError, match="unknown furniture"):
        generate_room("living", np.random.default_rng(0), "x", "fancy")
    with pytest.raises(ValueError, match="furniture must be one of"):
        SynthOptions(rooms=1, furniture="fancy")
