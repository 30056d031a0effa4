"""Furniture with real dimensions (and their spread), built from boxes, with the semantics labels come from.

Every builder returns a `Piece` in its own frame: x forward (the side a person uses), y left, z up, origin
on the floor under the footprint's centre. Anchors carry a *role*, not an affordance name: which affordance a
role stands for is data (`affordcore/data/furniture_roles.json`), so the code lists no affordance types.

Roles: ``lounge-seat`` (a seat with a backrest to lean on: sofas, armchairs), ``desk-seat`` (a chair that
serves a desk or table: labelled where a person who pulled it out would sit, 0.25 m outside the table edge
on the chair's line, facing the table), ``standing-work-edge`` (a free edge of a counter or bench at
0.85-1.00 m: labelled 0.30 m in front of it, inset 0.25 m from its ends, facing it).
"""

from __future__ import annotations

import numpy as np

from .shapes import Anchor, Box, Piece, rot2

LOUNGE, DESK_SEAT, STANDING_EDGE = "lounge-seat", "desk-seat", "standing-work-edge"

SEAT_INSET = 0.25  # sofa labels stop this far from each armrest (DESIGN.md)
DESK_LABEL_OFFSET = 0.25  # a desk seat's label is this far outside the table edge
STANDING_OFFSET, STANDING_INSET = 0.30, 0.25  # standing labels: in front of the edge, in from its ends
SEAT_HEIGHT = (0.35, 0.60)  # a flat top in this range, at least 0.30 m across, is somewhere to sit

FABRIC = [(0.30, 0.35, 0.55), (0.55, 0.50, 0.45), (0.35, 0.45, 0.35), (0.60, 0.30, 0.30), (0.45, 0.45, 0.48)]
WOOD = [(0.55, 0.40, 0.25), (0.70, 0.58, 0.40), (0.40, 0.28, 0.18), (0.80, 0.75, 0.65)]
METAL = [(0.25, 0.25, 0.27), (0.55, 0.56, 0.58), (0.15, 0.15, 0.15)]
LAMINATE = [(0.85, 0.85, 0.82), (0.25, 0.25, 0.25), (0.75, 0.20, 0.20), (0.60, 0.65, 0.70)]


def _pick(rng: np.random.Generator, palette) -> tuple[float, float, float]:
    return palette[int(rng.integers(len(palette)))]


def _legs(rng, x_half, y_half, height, thickness, color, inset=0.03) -> list[Box]:
    return [
        Box.span(
            (sx * (x_half - inset) - thickness / 2, sy * (y_half - inset) - thickness / 2, 0),
            (sx * (x_half - inset) + thickness / 2, sy * (y_half - inset) + thickness / 2, height),
            color,
        )
        for sx in (-1, 1)
        for sy in (-1, 1)
    ]


def _free_space(x0: float, x1: float, y0: float, y1: float, height: float = 1.8) -> Box:
    return Box.span((x0, y0, 0.0), (x1, y1, height), (0, 0, 0))


# ---------------------------------------------------------------- seating for relaxing


def sofa(rng: np.random.Generator, seats: int | None = None, armrests: bool | None = None) -> Piece:
    """A sofa of 1 to 4 seats with a backrest (and usually armrests): one lounge segment."""
    seats = int(rng.integers(1, 5)) if seats is None else seats
    armrests = bool(rng.random() < 0.85) if armrests is None else armrests
    seat_width = rng.uniform(0.55, 0.68)
    arm = rng.uniform(0.10, 0.22) if armrests else 0.0
    depth, seat_h = rng.uniform(0.80, 0.98), rng.uniform(0.38, 0.50)
    back_h, back_t, leg_h = rng.uniform(0.75, 0.95), rng.uniform(0.15, 0.25), rng.uniform(0.05, 0.12)
    length = seats * seat_width + 2 * arm
    color = _pick(rng, FABRIC)
    x0, x1, y_half = -depth / 2, depth / 2, length / 2
    parts = [
        Box.span((x0 + back_t, -y_half + arm, leg_h), (x1, y_half - arm, seat_h), color),  # seat cushions
        Box.span((x0, -y_half, leg_h), (x0 + back_t, y_half, back_h), color),  # backrest
        *_legs(rng, depth / 2, y_half, leg_h, 0.05, _pick(rng, WOOD)),
    ]
    if armrests:
        arm_h = rng.uniform(0.55, 0.68)
        parts += [
            Box.span(
                (x0, side * y_half - (arm if side > 0 else 0), leg_h),
                (x1, side * y_half + (0 if side > 0 else arm), arm_h),
                color,
            )
            for side in (-1, 1)
        ]
    seat_centre_x = (x0 + back_t + x1) / 2
    reach = max(0.0, y_half - arm - SEAT_INSET)
    legroom = _free_space(x1, x1 + 0.45, -y_half + arm, y_half - arm, 0.35)
    anchor = Anchor(
        LOUNGE, (seat_centre_x, -reach), (seat_centre_x, reach), 0.0, [legroom], f"{seats}-seat sofa"
    )
    return Piece("sofa", parts, [anchor], note=f"{seats}-seat sofa, seat {seat_h:.2f} m")


def corner_sofa(rng: np.random.Generator) -> Piece:
    """An L-shaped sofa: a main run and a wing at its left end, one lounge segment each (none in the
    corner)."""
    main = sofa(rng, seats=int(rng.integers(2, 4)), armrests=True)
    lo, hi = main.local_bounds()
    depth, length = hi[0] - lo[0], hi[1] - lo[1]
    wing_len = rng.uniform(1.2, 1.8)
    back_part = next(p for p in main.parts if p.size[0] < depth / 2 and p.size[1] >= length - 1e-6)
    seat_part = main.parts[0]
    color, seat_top, leg_h = seat_part.color, seat_part.z_range[1], seat_part.z_range[0]
    back_top, back_t = back_part.z_range[1], back_part.size[0]
    # The wing runs forward (+x) along the left end, its back on the far-left side (+y), facing -y.
    y1 = hi[1]
    wing = [
        Box.span((hi[0], y1 - depth, leg_h), (hi[0] + wing_len, y1 - back_t, seat_top), color),
        Box.span((hi[0], y1 - back_t, leg_h), (hi[0] + wing_len, y1, back_top), color),
        Box.span(
            (hi[0] + wing_len - 0.15, y1 - depth, leg_h), (hi[0] + wing_len, y1, seat_top + 0.15), color
        ),
    ]
    # Drop the main run's left armrest: the wing replaces it.
    parts = [
        p for p in main.parts if not (p.centre[1] > hi[1] - 0.3 and p.size[1] < 0.3 and p.size[2] > 0.3)
    ] + wing
    anchor = main.anchors[0]
    main_end = min(anchor.end[1], y1 - depth - SEAT_INSET + 0.1)
    wing_x = y1 - (depth + back_t) / 2  # the wing seat's centre line
    wing_anchor = Anchor(
        LOUNGE,
        (hi[0] + SEAT_INSET, wing_x),
        (hi[0] + wing_len - 0.15 - SEAT_INSET, wing_x),
        -np.pi / 2,
        [_free_space(hi[0], hi[0] + wing_len - 0.15, y1 - depth - 0.45, y1 - depth, 0.35)],
        "corner sofa, wing",
    )
    anchors = [
        Anchor(
            LOUNGE, anchor.start, (anchor.end[0], main_end), 0.0, anchor.clearance, "corner sofa, main run"
        )
    ]
    if wing_anchor.start[0] <= wing_anchor.end[0]:
        anchors.append(wing_anchor)
    piece = Piece("corner-sofa", parts, anchors, note="L-shaped sofa")
    # the corner seat, where the two runs meet, is a seat with no label (neither run's facing fits it)
    piece.unlabelled_seats = [((lo[0], y1 - depth), (hi[0], y1))]
    return piece


def armchair(rng: np.random.Generator) -> Piece:
    piece = sofa(rng, seats=1, armrests=True)
    anchor = piece.anchors[0]
    centre = ((anchor.start[0] + anchor.end[0]) / 2, 0.0)
    piece.anchors = [Anchor(LOUNGE, centre, centre, 0.0, anchor.clearance, "armchair")]
    piece.kind, piece.note = "armchair", "armchair"
    return piece


# ---------------------------------------------------------------- tables, desks, chairs


def table(rng, length, depth, height, color=None, legs=True) -> list[Box]:
    color = color or _pick(rng, WOOD)
    top_t = rng.uniform(0.025, 0.045)
    parts = [Box.span((-depth / 2, -length / 2, height - top_t), (depth / 2, length / 2, height), color)]
    if legs:
        parts += _legs(rng, depth / 2, length / 2, height - top_t, 0.05, color)
    return parts


def office_chair(rng: np.random.Generator) -> list[Box]:
    """Seat, backrest, optional armrests, gas post and a five-star base, facing +x, centred on the seat."""
    seat_h, width, depth = rng.uniform(0.42, 0.50), rng.uniform(0.46, 0.52), rng.uniform(0.44, 0.50)
    color, metal = _pick(rng, METAL + FABRIC[:1]), _pick(rng, METAL)
    parts = [
        Box.span((-depth / 2, -width / 2, seat_h - 0.07), (depth / 2, width / 2, seat_h), color),
        Box.span(
            (-depth / 2 - 0.06, -width / 2 + 0.03, seat_h + 0.05),
            (-depth / 2, width / 2 - 0.03, seat_h + rng.uniform(0.40, 0.60)),
            color,
        ),
        Box.span((-0.03, -0.03, 0.08), (0.03, 0.03, seat_h - 0.07), metal),
    ]
    for k in range(5):
        parts.append(
            Box(
                (0.15 * np.cos(2 * np.pi * k / 5), 0.15 * np.sin(2 * np.pi * k / 5), 0.05),
                (0.32, 0.05, 0.05),
                2 * np.pi * k / 5,
                metal,
            )
        )
    if rng.random() < 0.6:
        parts += [
            Box.span(
                (-0.15, side * width / 2 - 0.03, seat_h + 0.16),
                (0.15, side * width / 2 + 0.03, seat_h + 0.20),
                metal,
            )
            for side in (-1, 1)
        ]
    return parts


def dining_chair(rng: np.random.Generator) -> list[Box]:
    seat_h, width, depth = rng.uniform(0.43, 0.48), rng.uniform(0.40, 0.48), rng.uniform(0.40, 0.46)
    color = _pick(rng, WOOD)
    return [
        Box.span((-depth / 2, -width / 2, seat_h - 0.04), (depth / 2, width / 2, seat_h), color),
        Box.span(
            (-depth / 2, -width / 2, seat_h),
            (-depth / 2 + 0.03, width / 2, seat_h + rng.uniform(0.40, 0.50)),
            color,
        ),
        *_legs(rng, depth / 2, width / 2, seat_h - 0.04, 0.035, color, inset=0.02),
    ]


# How a place at a table is left (shares per place; DESIGN: the label does not depend on it). Real rooms have
# most chairs pushed in (10 of the 11 in the two real rooms), some places without a chair.
CHAIR_STATES = {"pushed-in": 0.50, "pulled-out": 0.25, "turned": 0.13, "missing": 0.12}
MAX_PULL = 0.45  # the farthest a pulled-out chair's seat front stands outside the table edge (m)
STEP_BACK = 0.03  # a chair that hits something is drawn back this far at a time until it fits


def chair_state(rng: np.random.Generator, seat_depth: float) -> tuple[str, float, float]:
    """(state, push, swivel) of one place's chair. `push` is how far the seat's front reaches past the table
    edge, under the top: from `seat_depth` (fully under, backrest against the edge) down to -MAX_PULL (pulled
    out); `swivel` turns the chair away from facing the table."""
    state = str(rng.choice(list(CHAIR_STATES), p=list(CHAIR_STATES.values())))
    if state == "pushed-in":
        return state, rng.uniform(0.0, seat_depth), rng.normal(0, 0.08)
    if state == "pulled-out":
        return state, -rng.uniform(0.0, MAX_PULL), rng.normal(0, 0.35)
    if state == "turned":  # sideways or away, left where someone got up
        away = rng.random() < 0.5
        swivel = np.pi + rng.normal(0, 0.4) if away else rng.choice([-1, 1]) * np.pi / 2 + rng.normal(0, 0.3)
        return state, -rng.uniform(0.15, MAX_PULL), swivel
    return state, 0.0, 0.0


def _chair_note(state: str, push: float) -> str:
    if state == "missing":
        return "no chair"
    if state == "turned":
        return f"chair turned, {-push:.2f} m out"
    return f"chair pushed in {push:.2f} m" if push >= 0 else f"chair pulled out {-push:.2f} m"


def _place_anchor(edge_x: float, along: float, turn: float, note: str) -> Anchor:
    """A place at a table edge at x = edge_x (table on the -x side): labelled where a person who pulled the
    chair out would sit, 0.25 m outside the edge on the place's line, facing the table, whatever the chair's
    state; turned by `turn` about the table's centre."""
    label_x = edge_x + DESK_LABEL_OFFSET
    room = _free_space(edge_x + 0.05, edge_x + 0.75, along - 0.30, along + 0.30, 1.3)
    anchor = Anchor(DESK_SEAT, (label_x, along), (label_x, along), np.pi, [room], note)
    return _rotated_anchor(anchor, turn) if turn else anchor


def desk(rng: np.random.Generator, place: bool = True, cluttered: bool = False) -> Piece:
    """A desk against its back (-x) side with a monitor and clutter on top. With `place`, one labelled place
    in front, its office chair in any of the CHAIR_STATES (missing included); without, nobody works there (no
    chair, no label: a distractor, which the room program always clutters so that it does not look like a
    place whose chair is missing)."""
    length, depth, height = rng.uniform(1.1, 1.8), rng.uniform(0.60, 0.80), rng.uniform(0.70, 0.78)
    parts = table(rng, length, depth, height, _pick(rng, WOOD + LAMINATE[:2]))
    monitor_w = rng.uniform(0.45, 0.70)
    along = rng.uniform(-length / 2 + monitor_w / 2 + 0.05, length / 2 - monitor_w / 2 - 0.05)
    parts.append(
        Box.span(
            (-depth / 2 + 0.08, along - monitor_w / 2, height + 0.10),
            (-depth / 2 + 0.11, along + monitor_w / 2, height + 0.10 + monitor_w * 0.6),
            METAL[2],
        )
    )
    parts.append(
        Box.span(
            (-depth / 2 + 0.12, along - 0.1, height),
            (-depth / 2 + 0.22, along + 0.1, height + 0.10),
            METAL[2],
        )
    )
    parts += _clutter(
        rng,
        (-depth / 2 + 0.25, depth / 2 - 0.05),
        (-length / 2 + 0.05, length / 2 - 0.05),
        height,
        count=int(rng.integers(6, 12)) if cluttered else int(rng.integers(0, 3)),
    )
    if rng.random() < 0.5:  # a drawer pedestal under one end
        end = rng.choice([-1, 1]) * (length / 2 - 0.25)
        parts.append(
            Box.span(
                (-depth / 2 + 0.02, end - 0.2, 0.0),
                (depth / 2 - 0.05, end + 0.2, height - 0.05),
                _pick(rng, LAMINATE),
            )
        )
    along = rng.uniform(-length / 2 + 0.35, length / 2 - 0.35)
    anchors = [_add_chair(rng, parts, depth / 2, along, office_chair)] if place else []
    return Piece("desk", parts, anchors, note=f"desk {height:.2f} m" + ("" if place else ", nobody's place"))


def meeting_table(rng: np.random.Generator, chair_maker=None, kind: str = "meeting-table") -> Piece:
    """A table with places every 0.65 m or more along its long sides, every place labelled; each place's chair
    is in one of the CHAIR_STATES (some places have none)."""
    length, depth, height = rng.uniform(1.4, 2.6), rng.uniform(0.80, 1.10), rng.uniform(0.72, 0.76)
    parts = table(rng, length, depth, height)
    places = max(1, int((length - 0.2) // 0.65))
    chair_maker = chair_maker or (office_chair if rng.random() < 0.5 else dining_chair)
    anchors = [
        _add_chair(rng, parts, depth / 2, -length / 2 + (k + 0.5) * length / places, chair_maker, turn)
        for turn in (0.0, np.pi)
        for k in range(places)
    ]
    chairs = sum(anchor.note != "no chair" for anchor in anchors)
    name = kind.replace("-", " ")
    return Piece(kind, parts, anchors, note=f"{name} {height:.2f} m, {len(anchors)} places, {chairs} chairs")


def dining_table(rng: np.random.Generator) -> Piece:
    return meeting_table(rng, dining_chair, "dining-table")


def _add_chair(
    rng, parts: list[Box], edge_x: float, along: float, chair_maker, turn: float = 0.0, tries: int = 10
) -> Anchor:
    """A labelled place at the edge (turned by `turn` about the table's centre) and its chair, added to
    `parts`. A chair that hits something already there (the top, a leg, a pedestal, a neighbour) is drawn back
    until it fits, as a real one stops where its armrests meet the top; after `tries` draws in which it never
    fits, the place has no chair."""
    from .rooms import any_overlap

    state, push = "missing", 0.0
    # only what is near the place can stop its chair (a top, at most 2.6 m long, has its centre within 2 m)
    place = rot2(turn) @ (edge_x, along)
    nearby = [part for part in parts if np.hypot(*np.subtract(part.centre[:2], place)) < 2.0]
    for _ in range(tries):
        chair = chair_maker(rng)
        seat_depth = chair[0].size[0]
        state, push, swivel = chair_state(rng, seat_depth)
        if state == "missing":
            break
        for depth in np.arange(push, -MAX_PULL - STEP_BACK, -STEP_BACK):
            centre = edge_x + seat_depth / 2 - depth
            placed = [part.placed(centre, along, np.pi + swivel).placed(0, 0, turn) for part in chair]
            if not any_overlap(placed, nearby):
                parts += placed
                return _place_anchor(edge_x, along, turn, _chair_note(state, float(depth)))
        state = "missing"
    return _place_anchor(edge_x, along, turn, _chair_note(state, push))


def _rotated_anchor(anchor: Anchor, yaw: float) -> Anchor:
    turn = rot2(yaw)
    return Anchor(
        anchor.role,
        tuple(turn @ anchor.start),
        tuple(turn @ anchor.end),
        anchor.facing + yaw,
        [box.placed(0, 0, yaw) for box in anchor.clearance],
        anchor.note,
    )


def lone_chair(rng: np.random.Generator) -> Piece:
    """A chair with no desk: a distractor (it serves nothing)."""
    chair = office_chair(rng) if rng.random() < 0.5 else dining_chair(rng)
    return _seat_everywhere(Piece("lone-chair", chair, note="chair without a desk"))


def _seat_everywhere(piece: Piece) -> Piece:
    """Mark the whole footprint as a seat no label describes (the room makes it an unlabelled region)."""
    lo, hi = piece.local_bounds()
    piece.unlabelled_seats = [(tuple(lo), tuple(hi))]
    return piece


# ---------------------------------------------------------------- standing work surfaces


def counter(rng: np.random.Generator, wall_cabinets: bool | None = None, cluttered: bool = False) -> Piece:
    """A kitchen counter against the wall behind it (-x): plinth recess, overhanging top, wall cabinets."""
    length, depth, height = rng.uniform(1.2, 3.2), rng.uniform(0.58, 0.66), rng.uniform(0.86, 0.96)
    body, top = _pick(rng, LAMINATE + WOOD), _pick(rng, LAMINATE)
    x0, x1, y = -depth / 2, depth / 2, length / 2
    parts = [
        Box.span((x0, -y, 0.10), (x1 - 0.03, y, height - 0.04), body),
        Box.span((x0, -y, 0.0), (x1 - 0.09, y, 0.10), METAL[0]),  # recessed plinth
        Box.span((x0, -y, height - 0.04), (x1, y, height), top),
    ]
    if wall_cabinets if wall_cabinets is not None else rng.random() < 0.6:
        parts.append(Box.span((x0, -y, rng.uniform(1.40, 1.55)), (x0 + 0.35, y, rng.uniform(2.0, 2.2)), body))
    parts += _clutter(
        rng,
        (x0 + 0.05, x1 - 0.05),
        (-y + 0.05, y - 0.05),
        height,
        count=int(rng.integers(10, 18)) if cluttered else int(rng.integers(0, 4)),
        tall=cluttered,
    )
    anchors = [] if cluttered else [_standing_edge(x1, length)]
    return Piece(
        "counter", parts, anchors, note=f"counter {height:.2f} m" + (", cluttered" if cluttered else "")
    )


def workbench(rng: np.random.Generator, both_sides: bool = False, cluttered: bool = False) -> Piece:
    """A bench on legs with a lower shelf; a free-standing one can be worked at from both long sides."""
    length, depth, height = rng.uniform(1.2, 2.4), rng.uniform(0.60, 0.90), rng.uniform(0.85, 1.00)
    color = _pick(rng, WOOD + METAL[:2])
    parts = table(rng, length, depth, height, color)
    if rng.random() < 0.5:  # a lower shelf
        parts.append(
            Box.span(
                (-depth / 2 + 0.05, -length / 2 + 0.05, 0.15),
                (depth / 2 - 0.05, length / 2 - 0.05, 0.18),
                color,
            )
        )
    parts += _clutter(
        rng,
        (-depth / 2 + 0.05, depth / 2 - 0.05),
        (-length / 2 + 0.05, length / 2 - 0.05),
        height,
        count=int(rng.integers(10, 16)) if cluttered else int(rng.integers(0, 4)),
        tall=cluttered,
    )
    anchors = [] if cluttered else [_standing_edge(depth / 2, length)]
    if both_sides and not cluttered:
        anchors.append(_rotated_anchor(_standing_edge(depth / 2, length), np.pi))
    return Piece(
        "workbench", parts, anchors, note=f"workbench {height:.2f} m" + (", cluttered" if cluttered else "")
    )


def high_table(rng: np.random.Generator) -> Piece:
    """A high lab table (standing height) on legs, worked at from its long sides."""
    length, depth, height = rng.uniform(0.9, 1.5), rng.uniform(0.6, 0.8), rng.uniform(0.90, 1.00)
    parts = table(rng, length, depth, height, _pick(rng, LAMINATE))
    return Piece(
        "high-table",
        parts,
        [_standing_edge(depth / 2, length), _rotated_anchor(_standing_edge(depth / 2, length), np.pi)],
        note=f"high table {height:.2f} m",
    )


def _standing_edge(edge_x: float, length: float) -> Anchor:
    reach = max(0.0, length / 2 - STANDING_INSET)
    x = edge_x + STANDING_OFFSET
    half_width = 0.30  # a person's shoulders and elbows reach this far either side of the label
    room = _free_space(edge_x + 0.02, edge_x + 0.65, -reach - half_width, reach + half_width, 1.9)
    return Anchor(STANDING_EDGE, (x, -reach), (x, reach), np.pi, [room], "free edge of a work surface")


# ---------------------------------------------------------------- context and distractors


def coffee_table(rng: np.random.Generator) -> Piece:
    return Piece(
        "coffee-table",
        table(rng, rng.uniform(0.8, 1.3), rng.uniform(0.45, 0.70), rng.uniform(0.35, 0.45)),
        note="coffee table (seat height, not a seat)",
    )


def tv_unit(rng: np.random.Generator) -> Piece:
    length, depth, height = rng.uniform(1.2, 1.9), rng.uniform(0.35, 0.45), rng.uniform(0.40, 0.55)
    tv_w = rng.uniform(0.9, min(1.5, length))
    parts = [
        Box.span((-depth / 2, -length / 2, 0), (depth / 2, length / 2, height), _pick(rng, WOOD + LAMINATE)),
        Box.span((-0.05, -tv_w / 2, height + 0.05), (0.0, tv_w / 2, height + 0.05 + tv_w * 0.58), METAL[2]),
        Box.span((-0.10, -0.15, height), (0.05, 0.15, height + 0.05), METAL[2]),
    ]
    # a seat-height top with the screen behind it like a backrest: someone could sit on its free ends
    return _seat_everywhere(Piece("tv-unit", parts, note="TV unit"))


def shelf(rng: np.random.Generator, low: bool | None = None) -> Piece:
    """A bookshelf; a low one (counter height, shallow, things on top) looks workable and is not."""
    low = bool(rng.random() < 0.4) if low is None else low
    length, depth = rng.uniform(0.8, 1.8), rng.uniform(0.28, 0.38)
    height = rng.uniform(0.85, 1.0) if low else rng.uniform(1.6, 2.1)
    color = _pick(rng, WOOD + LAMINATE)
    x0, x1, y = -depth / 2, depth / 2, length / 2
    parts = [
        Box.span((x0, -y, 0), (x0 + 0.02, y, height), color),
        Box.span((x0, -y, 0), (x1, -y + 0.02, height), color),
        Box.span((x0, y - 0.02, 0), (x1, y, height), color),
    ]
    levels = np.linspace(0.02, height, max(2, int(height / 0.35)) + 1)
    for z in levels:
        parts.append(Box.span((x0, -y + 0.02, z - 0.02), (x1, y - 0.02, z), color))
    for z0, z1 in zip(levels[:-1], levels[1:]):  # books
        parts += _clutter(
            rng,
            (x0 + 0.03, x1 - 0.02),
            (-y + 0.03, y - 0.03),
            z0,
            count=int(rng.integers(1, 4)),
            max_height=max(0.05, z1 - z0 - 0.06),
        )
    if low:
        parts += _clutter(
            rng,
            (x0 + 0.02, x1 - 0.02),
            (-y + 0.03, y - 0.03),
            height,
            count=int(rng.integers(3, 7)),
            tall=True,
        )
    return Piece("shelf", parts, note="low shelf, things on top" if low else "bookshelf")


def cabinet(rng: np.random.Generator) -> Piece:
    length, depth, height = rng.uniform(0.5, 1.2), rng.uniform(0.40, 0.60), rng.uniform(0.7, 1.9)
    return Piece(
        "cabinet",
        [
            Box.span(
                (-depth / 2, -length / 2, 0), (depth / 2, length / 2, height), _pick(rng, LAMINATE + METAL)
            )
        ],
        note=f"cabinet {height:.2f} m",
    )


def bench(rng: np.random.Generator) -> Piece:
    """A bench without a backrest: seat height, but nothing to lean on."""
    length, depth, height = rng.uniform(1.0, 1.8), rng.uniform(0.32, 0.45), rng.uniform(0.42, 0.48)
    return _seat_everywhere(Piece("bench", table(rng, length, depth, height), note="bench without backrest"))


def stool(rng: np.random.Generator, high: bool | None = None) -> Piece:
    high = bool(rng.random() < 0.5) if high is None else high
    height, size = (rng.uniform(0.62, 0.75), 0.36) if high else (rng.uniform(0.42, 0.50), 0.34)
    return _seat_everywhere(
        Piece("stool", table(rng, size, size, height, _pick(rng, METAL + WOOD)), note="stool")
    )


def storage_box(rng: np.random.Generator) -> Piece:
    """A box at seat height with no backrest and no room for knees in front when against things."""
    size = rng.uniform(0.35, 0.6, 2)
    height = rng.uniform(0.38, 0.50)
    box = Box.span(
        (-size[0] / 2, -size[1] / 2, 0), (size[0] / 2, size[1] / 2, height), _pick(rng, WOOD + FABRIC)
    )
    return _seat_everywhere(Piece("box", [box], note="box at seat height"))


# ---------------------------------------------------------------- decor: what makes a room more than a box


def picture(rng: np.random.Generator) -> Piece:
    """A framed picture or a wall shelf with things on it, hung at eye height (depth gives ICP something to
    hold)."""
    width, bottom = rng.uniform(0.3, 1.2), rng.uniform(1.1, 1.6)
    if rng.random() < 0.6:
        height, depth = rng.uniform(0.3, 0.8), rng.uniform(0.02, 0.05)
        parts = [
            Box.span(
                (-depth / 2, -width / 2, bottom),
                (depth / 2, width / 2, bottom + height),
                tuple(rng.uniform(0.1, 0.9, 3)),
            )
        ]
        return Piece("picture", parts, note="picture")
    depth = rng.uniform(0.18, 0.28)
    parts = [
        Box.span((-depth / 2, -width / 2, bottom), (depth / 2, width / 2, bottom + 0.025), _pick(rng, WOOD))
    ]
    parts += _clutter(
        rng,
        (-depth / 2 + 0.02, depth / 2 - 0.02),
        (-width / 2 + 0.03, width / 2 - 0.03),
        bottom + 0.025,
        count=int(rng.integers(1, 5)),
    )
    return Piece("wall-shelf", parts, note="wall shelf")


def radiator(rng: np.random.Generator) -> Piece:
    width, height = rng.uniform(0.6, 1.4), rng.uniform(0.4, 0.6)
    fins = [
        Box.span((-0.05, y - 0.01, 0.12), (0.05, y + 0.01, 0.12 + height), METAL[1])
        for y in np.arange(-width / 2 + 0.02, width / 2, 0.06)
    ]
    return Piece("radiator", fins, note="radiator")


def floor_clutter(rng: np.random.Generator) -> Piece:
    """A plant, a bin, a bag or a stack of boxes on the floor."""
    kind = rng.choice(["plant", "bin", "boxes"])
    if kind == "plant":
        pot = rng.uniform(0.2, 0.4)
        parts = [Box.span((-pot / 2, -pot / 2, 0), (pot / 2, pot / 2, pot), (0.6, 0.35, 0.25))]
        parts += [
            Box(
                (rng.normal(0, 0.08), rng.normal(0, 0.08), pot + h / 2),
                (0.12, 0.12, h),
                rng.uniform(0, np.pi),
                (0.2, 0.5, 0.2),
            )
            for h in rng.uniform(0.2, 0.9, 4)
        ]
    elif kind == "bin":
        size = rng.uniform(0.25, 0.4)
        parts = [
            Box.span(
                (-size / 2, -size / 2, 0),
                (size / 2, size / 2, rng.uniform(0.3, 0.6)),
                _pick(rng, METAL + LAMINATE),
            )
        ]
    else:
        parts, z = [], 0.0
        for _ in range(int(rng.integers(1, 4))):
            sx, sy, sz = rng.uniform(0.25, 0.55, 3)
            parts.append(
                Box(
                    (rng.normal(0, 0.03), rng.normal(0, 0.03), z + sz / 2),
                    (sx, sy, sz),
                    rng.normal(0, 0.2),
                    (0.65, 0.5, 0.32),
                )
            )
            z += sz
        piece = Piece("boxes", parts, note="stack of boxes")
        if (
            SEAT_HEIGHT[0] <= z <= SEAT_HEIGHT[1] and min(parts[-1].size[:2]) >= 0.30
        ):  # a top one could sit on
            return _seat_everywhere(piece)
        return piece
    return Piece(str(kind), parts, note=str(kind))


def _clutter(rng, x_range, y_range, z, count: int, tall: bool = False, max_height: float = 0.35) -> list[Box]:
    items = []
    for _ in range(count):
        sx, sy = rng.uniform(0.05, 0.30, 2)
        sx, sy = min(sx, np.ptp(x_range)), min(sy, np.ptp(y_range))
        h = rng.uniform(0.10, 0.45) if tall else rng.uniform(0.02, 0.25)
        h = min(h, max_height)
        cx = rng.uniform(x_range[0] + sx / 2, max(x_range[0] + sx / 2, x_range[1] - sx / 2))
        cy = rng.uniform(y_range[0] + sy / 2, max(y_range[0] + sy / 2, y_range[1] - sy / 2))
        items.append(Box((cx, cy, z + h / 2), (sx, sy, h), 0.0, tuple(rng.uniform(0.1, 0.9, 3))))
    return items
