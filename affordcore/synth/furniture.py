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

from dataclasses import replace

import numpy as np

from .shapes import Anchor, Box, Piece, any_overlap, disc, rot2

LOUNGE, DESK_SEAT, STANDING_EDGE = "lounge-seat", "desk-seat", "standing-work-edge"

SEAT_INSET = 0.25  # sofa labels stop this far from each armrest (DESIGN.md)
DESK_LABEL_OFFSET = 0.25  # a desk seat's label is this far outside the table edge
STANDING_OFFSET, STANDING_INSET = 0.30, 0.25  # standing labels: in front of the edge, in from its ends
# how far in front of a work edge a standing person's torso can be: the label's offset plus DESIGN's place
# tolerance (a skeleton that near the label is standing at that edge)
STANDING_REACH = STANDING_OFFSET + 0.15
SEAT_HEIGHT = (0.35, 0.60)  # a flat top in this range, at least 0.30 m across, is somewhere to sit
# A seated adult's torso above the seat top: the sitting skeletons' torso heights (0.62-0.64 m) over the
# seats they were fitted to (0.45 m). Places on seats of other heights (bar stools, lounge chairs) carry
# seat + this as their torso height.
TORSO_ABOVE_SEAT = 0.18

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


# A low sofa's shape (the loveseats of real listening and living rooms): seat, backrest top and armrest
# heights, and how far its backrest leans back from the vertical (degrees)
LOW_SOFA = {"seat": (0.36, 0.42), "back": (0.62, 0.74), "arms": (0.52, 0.62), "recline": (10.0, 20.0)}


def sofa(
    rng: np.random.Generator,
    seats: int | None = None,
    armrests: bool | None = None,
    things: bool = True,
    low: bool = False,
) -> Piece:
    """A sofa of 1 to 4 seats with a backrest (and usually armrests): one lounge segment; with `things`,
    now and then things left on its seats (`_things_on_seats`); `low`: a seat and back of LOW_SOFA's, the
    back reclined."""
    seats = int(rng.integers(1, 5)) if seats is None else seats
    armrests = bool(rng.random() < 0.85) if armrests is None else armrests
    seat_width = rng.uniform(0.55, 0.68)
    arm = rng.uniform(0.10, 0.22) if armrests else 0.0
    depth, seat_h = rng.uniform(0.80, 0.98), rng.uniform(*(LOW_SOFA["seat"] if low else (0.38, 0.50)))
    back_h, back_t = rng.uniform(*(LOW_SOFA["back"] if low else (0.75, 0.95))), rng.uniform(0.15, 0.25)
    leg_h = rng.uniform(0.05, 0.12)
    length = seats * seat_width + 2 * arm
    color = _pick(rng, FABRIC)
    x0, x1, y_half = -depth / 2, depth / 2, length / 2
    seat = Box.span((x0 + back_t, -y_half + arm, leg_h), (x1, y_half - arm, seat_h), color)  # seat cushions
    if low:  # the back leans away from the seat's rear as it rises
        recline = np.radians(rng.uniform(*LOW_SOFA["recline"]))
        span = (-y_half, y_half)
        back = _reclined_back(x0 + back_t, seat_h, back_h - seat_h, recline, back_t, span, color, leg_h)
    else:
        back = [Box.span((x0, -y_half, leg_h), (x0 + back_t, y_half, back_h), color)]
    parts = [seat, *back, *_legs(rng, depth / 2, y_half, leg_h, 0.05, _pick(rng, WOOD))]
    if armrests:
        arm_h = rng.uniform(*(LOW_SOFA["arms"] if low else (0.55, 0.68)))
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
    kind = "low-sofa" if low else "sofa"
    piece = Piece(kind, parts, [anchor], note=f"{seats}-seat {'low ' * low}sofa, seat {seat_h:.2f} m")
    return _things_on_seats(rng, piece, parts[0], seat_width) if things else piece


def loveseat(rng: np.random.Generator, things: bool = True) -> Piece:
    """A low two-seat sofa with a reclined back, as the real rooms' listening and living sofas are."""
    return sofa(rng, seats=2, armrests=rng.random() < 0.85, things=things, low=True)


def corner_sofa(rng: np.random.Generator) -> Piece:
    """An L-shaped sofa: a main run and a wing at its left end, one lounge segment each (none in the
    corner)."""
    main = sofa(rng, seats=int(rng.integers(2, 4)), armrests=True, things=False)
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


def armchair(rng: np.random.Generator, things: bool = True) -> Piece:
    piece = sofa(rng, seats=1, armrests=True, things=False)
    anchor = piece.anchors[0]
    centre = ((anchor.start[0] + anchor.end[0]) / 2, 0.0)
    piece.anchors = [Anchor(LOUNGE, centre, centre, 0.0, anchor.clearance, "armchair")]
    piece.kind, piece.note = "armchair", "armchair"
    seat = piece.parts[0]
    return _things_on_seats(rng, piece, seat, seat.size[1]) if things else piece


def chaise_sofa(rng: np.random.Generator) -> Piece:
    """A sofa of 2-3 seats whose end seat runs on forward into a chaise longue (0.5-0.8 m longer). The other
    seats are one lounge segment, stopping SEAT_INSET short of the chaise as at an armrest; the chaise is a
    seat with no label: on it the legs lie along the cushion, not the pose the sitting skeleton has (feet on
    the floor in front), and its far end is a seat with nothing to lean on."""
    seats = int(rng.integers(2, 4))
    piece = sofa(rng, seats=seats, armrests=rng.random() < 0.7, things=False)
    seat = piece.parts[0]
    (x0, y0), (x1, y1) = seat.corners_xy().min(axis=0), seat.corners_xy().max(axis=0)
    side, width, extra = float(rng.choice([-1.0, 1.0])), (y1 - y0) / seats, rng.uniform(0.5, 0.8)
    near, far = (y1 - width, y1) if side > 0 else (y0, y0 + width)
    # the chaise's cushion on a base down to the floor (real ones stand on a plinth or low legs)
    piece.parts.append(Box.span((x1, near, 0.0), (x1 + extra, far, seat.z_range[1]), seat.color))
    piece.anchors = _stop_short_of(piece.anchors, near if side > 0 else far, side)
    piece.unlabelled_seats.append(((x0, near), (x1 + extra, far)))
    piece.kind, piece.note = (
        "chaise-sofa",
        f"{seats}-seat sofa with a chaise longue, seat {seat.z_range[1]:.2f} m",
    )
    return piece


# ---------------------------------------------------------------- things left on seats

# Per lounge piece (sofas, armchairs, lounge chairs): small things a person would just move (the place stays
# labelled), or a large box filling one seat (that seat is no place until someone clears it: an unlabelled
# region, and the segment stops short of it as at an armrest).
SMALL_THINGS_SHARE, BIG_BOX_SHARE = 0.30, 0.08
THINGS_ON_CHAIR_SHARE = 0.10  # per chair at a table: a bag or a laptop on the seat


def _small_thing(rng: np.random.Generator, seat: Box, along: float) -> Box:
    """A cushion, a bag or a laptop lying on `seat` (a box in the piece's frame) at `along` on its y axis."""
    kind = rng.choice(["cushion", "bag", "laptop"], p=[0.5, 0.3, 0.2])
    size = {
        "cushion": (rng.uniform(0.10, 0.18), rng.uniform(0.35, 0.45), rng.uniform(0.10, 0.18)),
        "bag": (rng.uniform(0.15, 0.22), rng.uniform(0.28, 0.40), rng.uniform(0.22, 0.35)),
        "laptop": (rng.uniform(0.22, 0.25), rng.uniform(0.31, 0.36), rng.uniform(0.02, 0.03)),
    }[str(kind)]
    size = (min(size[0], seat.size[0]), min(size[1], seat.size[1]), size[2])
    (x0, y0), (x1, y1) = seat.corners_xy().min(axis=0), seat.corners_xy().max(axis=0)
    x = rng.uniform(x0 + size[0] / 2, x1 - size[0] / 2)
    y = float(np.clip(along, y0 + size[1] / 2, y1 - size[1] / 2))
    top = seat.z_range[1]
    return Box((x, y, top + size[2] / 2), size, rng.normal(0, 0.15), tuple(rng.uniform(0.1, 0.9, 3)))


def _things_on_chair(rng: np.random.Generator, seat: Box) -> list[Box]:
    """Now and then a bag or a laptop on a chair's seat (the chair's frame)."""
    return [_small_thing(rng, seat, seat.centre[1])] if rng.random() < THINGS_ON_CHAIR_SHARE else []


def _things_on_seats(rng: np.random.Generator, piece: Piece, seat: Box, seat_width: float) -> Piece:
    """Leave things on a lounge piece's `seat` box (its one anchor runs along local y, facing +x): small
    things the place keeps its label under, or a big box on an end seat, which takes that seat out of the
    label into an unlabelled region."""
    draw = rng.random()
    (x0, y0), (x1, y1) = seat.corners_xy().min(axis=0), seat.corners_xy().max(axis=0)
    if draw < BIG_BOX_SHARE:
        side = float(rng.choice([-1.0, 1.0]))
        near, far = (y1 - seat_width, y1) if side > 0 else (y0, y0 + seat_width)
        height = rng.uniform(0.30, 0.55)
        piece.parts.append(
            Box.span(
                (x0 + 0.03, near + 0.02, seat.z_range[1]),
                (x1 - 0.03, far - 0.02, seat.z_range[1] + height),
                (0.65, 0.5, 0.32),
            )
        )
        piece.unlabelled_seats.append(((x0, near), (x1, far)))
        piece.anchors = _stop_short_of(piece.anchors, near if side > 0 else far, side)
        piece.note += ", a big box on a seat"
    elif draw < BIG_BOX_SHARE + SMALL_THINGS_SHARE:
        piece.parts += [_small_thing(rng, seat, rng.uniform(y0, y1)) for _ in range(int(rng.integers(1, 4)))]
        piece.note += ", things on the seat"
    return piece


def _stop_short_of(anchors: list[Anchor], boundary: float, side: float) -> list[Anchor]:
    """Anchors along local y cut to end SEAT_INSET before `boundary` on `side` (+1: their high-y end);
    anchors with nothing left are dropped."""
    kept = []
    for anchor in anchors:
        low, high = sorted((anchor.start[1], anchor.end[1]))
        low, high = (
            (low, min(high, boundary - SEAT_INSET)) if side > 0 else (max(low, boundary + SEAT_INSET), high)
        )
        if high >= low - 1e-9:
            x = anchor.start[0]
            kept.append(replace(anchor, start=(x, low), end=(x, high)))
    return kept


def lounge_chair(rng: np.random.Generator, things: bool = True) -> Piece:
    """A low lounge chair: a deep seat at 0.35-0.42 m and a backrest reclined 15-25 degrees (steps of boxes
    leaning back), armrests 70 % of the time; one lounge place on the seat's centre."""
    seat_h, width, depth = rng.uniform(0.35, 0.42), rng.uniform(0.60, 0.72), rng.uniform(0.55, 0.68)
    recline, back_h, back_t = np.radians(rng.uniform(15, 25)), rng.uniform(0.45, 0.65), 0.12
    arm = rng.uniform(0.08, 0.15) if rng.random() < 0.7 else 0.0
    color, leg_h = _pick(rng, FABRIC + WOOD[:1]), rng.uniform(0.08, 0.15)
    x_front, y_half = depth / 2, width / 2 + arm
    seat = Box.span((-depth / 2, -width / 2, leg_h), (x_front, width / 2, seat_h), color)
    parts = [seat, *_legs(rng, depth / 2, y_half, leg_h, 0.04, _pick(rng, WOOD + METAL))]
    parts += _reclined_back(
        -depth / 2, seat_h, back_h, recline, back_t, (-width / 2, width / 2), color, leg_h
    )
    if arm:
        parts += [
            Box.span(
                (-depth / 2 - back_t, side * width / 2 - (0 if side > 0 else arm), leg_h),
                (x_front, side * width / 2 + (arm if side > 0 else 0), seat_h + rng.uniform(0.15, 0.22)),
                color,
            )
            for side in (-1, 1)
        ]
    centre = (0.0, 0.0)
    legroom = _free_space(x_front, x_front + 0.45, -width / 2, width / 2, 0.35)
    anchor = Anchor(LOUNGE, centre, centre, 0.0, [legroom], "lounge chair", seat_h + TORSO_ABOVE_SEAT)
    piece = Piece("lounge-chair", parts, [anchor], note=f"lounge chair, seat {seat_h:.2f} m")
    return _things_on_seats(rng, piece, seat, width) if things else piece


def _reclined_back(
    front: float, seat_h: float, height: float, recline: float, thickness: float, span, color, bottom: float
) -> list[Box]:
    """A backrest rising `height` above a seat at `seat_h`, leaning back by `recline` from the vertical: a
    stair of four boxes, each set back by the recline over its height, the lowest with its front at x =
    `front` and reaching down to `bottom` (the frame under the seat); `span` its (low, high) y."""
    steps = 4
    boxes = []
    for k in range(steps):
        z0, z1 = seat_h + k * height / steps, seat_h + (k + 1) * height / steps
        back = front - np.tan(recline) * (z0 - seat_h)
        boxes.append(Box.span((back - thickness, span[0], z0 if k else bottom), (back, span[1], z1), color))
    return boxes


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


# How a place at a table is left (shares per place; DESIGN: the label does not depend on the chair's state,
# but a place without a chair has none). Real rooms have most chairs pushed in (10 of the 11 in the two real
# rooms), some places without a chair.
CHAIR_STATES = {"pushed-in": 0.50, "pulled-out": 0.25, "turned": 0.13, "missing": 0.12}
MAX_PULL = 0.45  # the farthest a pulled-out chair's seat front stands outside the table edge (m)
STEP_BACK = 0.03  # a chair that hits something is drawn back this far at a time until it fits


# Of the pushed-in chairs, this share is pushed in as far as it goes (the seat under the top, the backrest or
# the armrests against the edge), as most of the real rooms' chairs are; the rest to any depth short of that.
FULLY_UNDER_SHARE = 0.35


def chair_state(rng: np.random.Generator, seat_depth: float) -> tuple[str, float, float]:
    """(state, push, swivel) of one place's chair. `push` is how far the seat's front reaches past the table
    edge, under the top: from `seat_depth` (fully under, backrest against the edge) down to -MAX_PULL (pulled
    out), or inf: as far as the chair goes under this top (`_deepest_push`); `swivel` turns the chair away
    from facing the table."""
    state = str(rng.choice(list(CHAIR_STATES), p=list(CHAIR_STATES.values())))
    if state == "pushed-in":
        if rng.random() < FULLY_UNDER_SHARE:  # square to the table: its backrest lies against the edge
            return state, np.inf, 0.0
        return state, rng.uniform(0.0, seat_depth), rng.normal(0, 0.08)
    if state == "pulled-out":
        return state, -rng.uniform(0.0, MAX_PULL), rng.normal(0, 0.35)
    if state == "turned":  # sideways or away, left where someone got up
        away = rng.random() < 0.5
        swivel = np.pi + rng.normal(0, 0.4) if away else rng.choice([-1, 1]) * np.pi / 2 + rng.normal(0, 0.3)
        return state, -rng.uniform(0.15, MAX_PULL), swivel
    return state, 0.0, 0.0


def _chair_note(state: str, push: float, fully: bool = False) -> str:
    if state == "missing":
        return "no chair"
    if state == "turned":
        return f"chair turned, {-push:.2f} m out"
    if push < 0:
        return f"chair pulled out {-push:.2f} m"
    return f"chair pushed in {push:.2f} m" + (", as far as it goes" if fully else "")


def _deepest_push(chair: list[Box], underside: float) -> float:
    """How far a chair (in its own frame, facing +x, seat first) can be pushed under a top whose underside
    is at `underside`: until the first of its parts that reach that high (backrest, armrests) meets the edge;
    a chair with none (a stool) until its seat's rear is at the edge."""
    seat_depth = chair[0].size[0]
    tall = [part for part in chair if part.z_range[1] > underside - 1e-3]
    if not tall:
        return seat_depth
    front_of_tall = max(part.corners_xy()[:, 0].max() for part in tall)
    return min(seat_depth, seat_depth / 2 - front_of_tall)


def _place_anchor(
    edge_x: float,
    along: float,
    turn: float,
    note: str,
    torso_height: float | None = None,
    chair: list[Box] | None = None,
) -> Anchor:
    """A place at a table edge at x = edge_x (table on the -x side): where a person who pulled the chair out
    would sit, 0.25 m outside the edge on the place's line, facing the table, whatever the chair's state;
    turned by `turn` about the table's centre. `chair` (its parts, as placed): the place's support; None: a
    place without a chair, whose space is kept free but which carries no label (nobody can sit there)."""
    label_x = edge_x + DESK_LABEL_OFFSET
    room = _free_space(edge_x + 0.05, edge_x + 0.75, along - 0.30, along + 0.30, 1.3)
    at = (label_x, along)
    anchor = Anchor(DESK_SEAT, at, at, np.pi, [room], note, torso_height, chair is not None, chair or [])
    return _rotated_anchor(anchor, turn) if turn else anchor


def desk(rng: np.random.Generator, place: bool = True, cluttered: bool = False) -> Piece:
    """A desk against its back (-x) side with a monitor and clutter on top. With `place`, one place in front,
    its office chair in any of the CHAIR_STATES (missing: no label); without, nobody works there (no chair,
    no label, no space kept free: a distractor, which the room program clutters)."""
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
        # a labelled desk's things stay clear of where its sitter's hands rest
        (-depth / 2 + 0.25, depth / 2 - (WORK_EDGE_KEEP if place and not cluttered else 0.05)),
        (-length / 2 + 0.05, length / 2 - 0.05),
        height,
        count=int(rng.integers(6, 12)) if cluttered else int(rng.integers(0, 3)),
    )
    free = (-length / 2 + 0.35, length / 2 - 0.35)  # where the place can be along the desk
    if rng.random() < 0.5:  # a drawer pedestal under one end
        end = rng.choice([-1, 1]) * (length / 2 - 0.25)
        # the sitter's knees and feet (up to 0.17 m either side of the place) stay clear of the pedestal
        free = (free[0], length / 2 - 0.65) if end > 0 else (-length / 2 + 0.65, free[1])
        parts.append(
            Box.span(
                (-depth / 2 + 0.02, end - 0.2, 0.0),
                (depth / 2 - 0.05, end + 0.2, height - 0.05),
                _pick(rng, LAMINATE),
            )
        )
    along = rng.uniform(*free)
    anchors = [_add_chair(rng, parts, depth / 2, along, office_chair)] if place else []
    return Piece("desk", parts, anchors, note=f"desk {height:.2f} m" + ("" if place else ", nobody's place"))


def meeting_table(rng: np.random.Generator, chair_maker=None, kind: str = "meeting-table") -> Piece:
    """A table with places every 0.65 m or more along its long sides, every place labelled; each place's chair
    is in one of the CHAIR_STATES (some places have none)."""
    length, depth, height = rng.uniform(1.4, 2.6), rng.uniform(0.80, 1.10), rng.uniform(0.72, 0.76)
    parts = table(rng, length, depth, height)
    # cups, papers, a laptop, a bowl: down the middle, clear of the places' edges
    middle = (-depth / 2 + WORK_EDGE_KEEP, depth / 2 - WORK_EDGE_KEEP)
    parts += _clutter(rng, middle, (-length / 2 + 0.1, length / 2 - 0.1), height, int(rng.integers(0, 5)))
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


ROUND_PLACE_SPACING = 0.65  # the least arc of a round table's edge each place takes (m)


def round_table(rng: np.random.Generator) -> Piece:
    """A round table (0.8-1.3 m across) on a pedestal or four legs, its places spread evenly round it, each
    labelled like a straight table's: 0.25 m outside the edge on the line to the centre, facing the centre,
    its chair (swivel or dining, one kind per table) in one of the CHAIR_STATES."""
    radius, height = rng.uniform(0.40, 0.65), rng.uniform(0.72, 0.76)
    color, top_t = _pick(rng, WOOD + LAMINATE[:2]), rng.uniform(0.025, 0.045)
    parts = disc(radius, height - top_t, height, color)
    if rng.random() < 0.6:  # a pedestal: a post on a foot plate
        post = rng.uniform(0.08, 0.14)
        parts.append(Box.span((-post / 2, -post / 2, 0.03), (post / 2, post / 2, height - top_t), color))
        parts += disc(rng.uniform(0.22, 0.32), 0.0, 0.03, _pick(rng, METAL), sides=8)
    else:
        half = radius * 0.55
        parts += _legs(rng, half, half, height - top_t, 0.05, color, inset=0.0)
    keep = (radius - WORK_EDGE_KEEP) / np.sqrt(2)  # things stay clear of every place's edge
    if keep > 0.05:
        parts += _clutter(rng, (-keep, keep), (-keep, keep), height, int(rng.integers(0, 3)))
    places = int(np.clip(2 * np.pi * radius // ROUND_PLACE_SPACING, 3, 6))
    chair_maker = office_chair if rng.random() < 0.5 else dining_chair
    edge = radius * np.cos(np.pi / 16)  # the top's apothem
    start = rng.uniform(0, 2 * np.pi)
    anchors = [
        _add_chair(rng, parts, edge, 0.0, chair_maker, start + 2 * np.pi * k / places) for k in range(places)
    ]
    chairs = sum(anchor.labelled for anchor in anchors)
    note = f"round table {2 * radius:.2f} m across, {height:.2f} m, {places} places, {chairs} chairs"
    return Piece("round-table", parts, anchors, note=note)


def _add_chair(
    rng,
    parts: list[Box],
    edge_x: float,
    along: float,
    chair_maker,
    turn: float = 0.0,
    tries: int = 10,
    torso_height: float | None = None,
) -> Anchor:
    """A place at the edge (turned by `turn` about the table's centre) and its chair, added to `parts`
    (whose first box is the top). A chair that hits something already there (the top, a leg, a pedestal, a
    neighbour) is drawn back until it fits, as a real one stops where its armrests meet the top; after
    `tries` draws in which it never fits, the place has no chair (and no label). Now and then the chair holds
    a bag or a laptop: the place stays labelled (a person would move it)."""
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
        chair += _things_on_chair(rng, chair[0])
        fully = push == np.inf
        push = _deepest_push(chair, parts[0].z_range[0]) if fully else push
        for depth in np.arange(push, -MAX_PULL - STEP_BACK, -STEP_BACK):
            centre = edge_x + seat_depth / 2 - depth
            # the chair at the unturned place (the anchor's support, turned with it), then turned
            at_place = [part.placed(centre, along, np.pi + swivel) for part in chair]
            placed = [part.placed(0, 0, turn) for part in at_place]
            if not any_overlap(placed, nearby):
                parts += placed
                note = _chair_note(state, float(depth), fully and depth == push)
                return _place_anchor(edge_x, along, turn, note, torso_height, at_place)
        state = "missing"
    # a place without a chair is no place to sit as the room stands (real rooms label their chairs; DESIGN
    # labels a pushed-in chair where it would be pulled out to); labelled, it taught that a bare table edge
    # is a seat
    return _place_anchor(edge_x, along, turn, _chair_note(state, push), torso_height)


def _rotated_anchor(anchor: Anchor, yaw: float) -> Anchor:
    turn = rot2(yaw)
    return replace(
        anchor,
        start=tuple(turn @ anchor.start),
        end=tuple(turn @ anchor.end),
        facing=anchor.facing + yaw,
        clearance=[box.placed(0, 0, yaw) for box in anchor.clearance],
        support=[box.placed(0, 0, yaw) for box in anchor.support],
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
    anchors = [] if cluttered else [_standing_edge(x1, length, height)]
    return Piece(
        "counter",
        parts,
        anchors,
        note=f"counter {height:.2f} m" + (", cluttered" if cluttered else ""),
        unlabelled_edges=[_edge_zone(x1, length)] if cluttered else [],
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
    anchors = [] if cluttered else [_standing_edge(depth / 2, length, height)]
    if both_sides and not cluttered:
        anchors.append(_rotated_anchor(_standing_edge(depth / 2, length, height), np.pi))
    edges = [_edge_zone(depth / 2, length)] + ([_edge_zone(-depth / 2, length)] if both_sides else [])
    return Piece(
        "workbench",
        parts,
        anchors,
        note=f"workbench {height:.2f} m" + (", cluttered" if cluttered else ""),
        unlabelled_edges=(edges if cluttered else [])
        + (_end_zones(-depth / 2, depth / 2, length) if both_sides else []),
    )


def high_table(rng: np.random.Generator) -> Piece:
    """A high lab table (standing height) on legs, worked at from its long sides."""
    length, depth, height = rng.uniform(0.9, 1.5), rng.uniform(0.6, 0.8), rng.uniform(0.90, 1.00)
    parts = table(rng, length, depth, height, _pick(rng, LAMINATE))
    return Piece(
        "high-table",
        parts,
        [
            _standing_edge(depth / 2, length, height),
            _rotated_anchor(_standing_edge(depth / 2, length, height), np.pi),
        ],
        note=f"high table {height:.2f} m",
        unlabelled_edges=_end_zones(-depth / 2, depth / 2, length),
    )


# ---------------------------------------------------------------- counter-height seating

# Seat below the top of a counter-height table: 0.21-0.27 m (people sit 0.25-0.30 m below a bar top; the
# sitting skeleton's hands lie 0.28 m above its seat, so a larger gap would put them inside the top).
BAR_GAP = (0.21, 0.27)
BAR_SEAT = (0.65, 0.80)  # bar stool and high chair seats
BAR_TOP = (0.90, 1.05)  # counter-height tables, kitchen islands, breakfast bars
# Things on a table keep this far from the edges people work at: their hands rest 0.1-0.2 m inside the edge
# (a person would push a cup aside, but the label's skeleton must fit as it is).
WORK_EDGE_KEEP = 0.30


def bar_seat_height(rng: np.random.Generator, top: float) -> float:
    """A seat for a counter-height top: BAR_GAP below it, within BAR_SEAT."""
    low, high = max(BAR_SEAT[0], top - BAR_GAP[1]), min(BAR_SEAT[1], top - BAR_GAP[0])
    return float(rng.uniform(low, high))


def bar_stool(rng: np.random.Generator, seat_h: float, back: bool = False) -> list[Box]:
    """A bar stool (or, with `back`, a high chair) with its seat top at `seat_h`: square seat, four legs, a
    footrest frame; facing +x, centred on the seat, seat first."""
    size, color, metal = rng.uniform(0.34, 0.40), _pick(rng, WOOD + FABRIC[:2]), _pick(rng, METAL)
    half, foot = size / 2, rng.uniform(0.26, 0.34)
    parts = [
        Box.span((-half, -half, seat_h - 0.05), (half, half, seat_h), color),
        *_legs(rng, half, half, seat_h - 0.05, 0.03, metal, inset=0.02),
    ]
    parts += [  # the footrest: a frame between the legs
        Box.span(
            (-half + 0.02, side * (half - 0.035) - 0.01, foot),
            (half - 0.02, side * (half - 0.035) + 0.01, foot + 0.02),
            metal,
        )
        for side in (-1, 1)
    ]
    if back:
        parts.append(
            Box.span(
                (-half, -half + 0.03, seat_h),
                (-half + 0.04, half - 0.03, seat_h + rng.uniform(0.30, 0.45)),
                color,
            )
        )
    return parts


def _bar_places(rng, parts: list[Box], edge_x: float, length: float, seat_h: float, turn: float = 0.0):
    """2-4 places (as many as fit 0.6 m apart) along a counter-height edge, each with a bar stool or a high
    chair in one of the CHAIR_STATES; labelled like any table place, torso at seat + TORSO_ABOVE_SEAT."""
    places = min(int(rng.integers(2, 5)), int((length - 0.2) // 0.6))
    back = bool(rng.random() < 0.5)
    maker = lambda r: bar_stool(r, seat_h, back)  # noqa: E731
    return [
        _add_chair(
            rng,
            parts,
            edge_x,
            -length / 2 + (k + 0.5) * length / places,
            maker,
            turn,
            torso_height=seat_h + TORSO_ABOVE_SEAT,
        )
        for k in range(places)
    ]


def kitchen_island(rng: np.random.Generator) -> Piece:
    """A free-standing kitchen island at counter height: a cabinet body, worked at standing from its kitchen
    side (-x); its top overhangs the other side by 0.45-0.55 m (room for knees and feet) over 2-4 bar stools
    or high chairs, whose places are labelled; that free edge is a standing edge too."""
    length, height = rng.uniform(1.4, 2.6), rng.uniform(*BAR_TOP)
    body_depth, overhang, top_t = rng.uniform(0.60, 0.90), rng.uniform(0.45, 0.55), rng.uniform(0.03, 0.045)
    edge, x0, y = (body_depth + overhang) / 2, -(body_depth + overhang) / 2, length / 2
    body = _pick(rng, LAMINATE + WOOD)
    parts = [
        Box.span((x0, -y, height - top_t), (edge, y, height), _pick(rng, LAMINATE)),
        Box.span((x0 + 0.03, -y, 0.10), (edge - overhang, y, height - top_t), body),
        Box.span((x0 + 0.09, -y, 0.0), (edge - overhang, y, 0.10), METAL[0]),  # plinth, recessed for toes
    ]
    parts += _clutter(
        rng,
        (x0 + WORK_EDGE_KEEP, edge - WORK_EDGE_KEEP),
        (-y + 0.05, y - 0.05),
        height,
        int(rng.integers(0, 4)),
    )
    seat_h = bar_seat_height(rng, height)
    anchors = _bar_places(rng, parts, edge, length, seat_h)
    anchors += [
        _standing_edge(edge, length, height),
        _rotated_anchor(_standing_edge(-x0, length, height), np.pi),
    ]
    note = f"kitchen island {height:.2f} m, {len(anchors) - 2} stools at {seat_h:.2f} m"
    return Piece("kitchen-island", parts, anchors, note=note, unlabelled_edges=_end_zones(x0, edge, length))


def bar_table(rng: np.random.Generator, both_sides: bool = True) -> Piece:
    """A counter-height table on legs with bar stools or high chairs: free-standing with places on both long
    sides, or (`both_sides` False) a breakfast bar against a wall (-x) with places on its front. Every free
    long edge is a standing edge as well."""
    length, height = rng.uniform(1.0, 2.2), rng.uniform(*BAR_TOP)
    depth = rng.uniform(0.85, 1.05) if both_sides else rng.uniform(0.50, 0.65)
    parts = table(rng, length, depth, height, _pick(rng, WOOD + LAMINATE))
    back_x = -depth / 2 + (WORK_EDGE_KEEP if both_sides else 0.05)
    parts += _clutter(
        rng,
        (back_x, depth / 2 - WORK_EDGE_KEEP),
        (-length / 2 + 0.1, length / 2 - 0.1),
        height,
        int(rng.integers(0, 3)),
    )
    seat_h = bar_seat_height(rng, height)
    anchors = _bar_places(rng, parts, depth / 2, length, seat_h) + [_standing_edge(depth / 2, length, height)]
    if both_sides:
        anchors += _bar_places(rng, parts, depth / 2, length, seat_h, np.pi)
        anchors.append(_rotated_anchor(_standing_edge(depth / 2, length, height), np.pi))
    stools = sum(anchor.role == DESK_SEAT for anchor in anchors)
    name = "bar table" if both_sides else "breakfast bar"
    note = f"{name} {height:.2f} m, {stools} places at {seat_h:.2f} m"
    ends = _end_zones(-depth / 2, depth / 2, length) if both_sides else []
    return Piece(name.replace(" ", "-"), parts, anchors, note=note, unlabelled_edges=ends)


def _standing_edge(edge_x: float, length: float, height: float) -> Anchor:
    """The standing place along a top's edge at x = edge_x, `height` up (the top on the -x side). Its support
    is the strip of the top a person's hands work on, WORK_EDGE_KEEP deep."""
    reach = max(0.0, length / 2 - STANDING_INSET)
    x = edge_x + STANDING_OFFSET
    half_width = 0.30  # a person's shoulders and elbows reach this far either side of the label
    room = _free_space(edge_x + 0.02, edge_x + 0.65, -reach - half_width, reach + half_width, 1.9)
    strip = Box.span((edge_x - WORK_EDGE_KEEP, -reach - 0.15, height - 0.04), (edge_x, reach + 0.15, height))
    return Anchor(
        STANDING_EDGE, (x, -reach), (x, reach), np.pi, [room], "free edge of a work surface", support=[strip]
    )


def _edge_zone(edge_x: float, length: float) -> tuple[tuple[float, float], tuple[float, float]]:
    """Where a person stands to work at the edge along y at `edge_x` (facing it from outside, +x or -x)."""
    outside = STANDING_REACH if edge_x >= 0 else -STANDING_REACH
    (x0, x1) = sorted((edge_x, edge_x + outside))
    return ((x0, -length / 2), (x1, length / 2))


def _end_zones(x0: float, x1: float, length: float) -> list[tuple[tuple[float, float], tuple[float, float]]]:
    """Where a person stands at either narrow end (y = +-length / 2) of a free-standing top spanning x0..x1,
    its corners included: one can work there, but the generator labels the long edges only."""
    across = (x0 - STANDING_REACH, x1 + STANDING_REACH)
    return [
        ((across[0], length / 2), (across[1], length / 2 + STANDING_REACH)),
        ((across[0], -length / 2 - STANDING_REACH), (across[1], -length / 2)),
    ]


# ---------------------------------------------------------------- context and distractors


def coffee_table(rng: np.random.Generator) -> Piece:
    return Piece(
        "coffee-table",
        table(rng, rng.uniform(0.8, 1.3), rng.uniform(0.45, 0.70), rng.uniform(0.35, 0.45)),
        note="coffee table (seat height, not a seat)",
    )


def ottoman(rng: np.random.Generator) -> Piece:
    """An upholstered block in front of a sofa where a coffee table would stand: seat height, nothing to lean
    on (a seat no label describes)."""
    size, height = rng.uniform(0.45, 0.90, 2), rng.uniform(0.38, 0.46)
    block = Box.span((-size[0] / 2, -size[1] / 2, 0), (size[0] / 2, size[1] / 2, height), _pick(rng, FABRIC))
    return _seat_everywhere(Piece("ottoman", [block], note=f"ottoman {height:.2f} m"))


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
