"""Procedural rooms: a shell (walls with doors and windows, floor, ceiling) furnished by kind, with labels
that come from the furniture's own semantics.

Kinds: ``living`` (sofas, corner sofas, armchairs, coffee tables, TV units, shelves), ``office`` (desks with
office chairs in varied states, desks without chairs, meeting tables, cabinets), ``workshop`` (kitchen
counters, workbenches, high tables, stools, counter-height shelves with things on top) and ``mixed``. Every
kind also gets distractors: things at seat or counter height that afford nothing (benches without a backrest,
boxes, lone chairs, cluttered benches, low shelves, coffee tables).

Placement is rejection sampling: a piece is kept only where it lies inside the room, touches no wall, no
other piece, no door's swing, and where the free space each of its labels needs (feet in front of a sofa,
a pulled-out chair, a person at a counter) is free of everything else.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..labels import polygon_contains
from . import furniture as F
from .shapes import Anchor, Box, Piece, any_overlap, rot2

KINDS = ("living", "office", "workshop", "mixed")
# What rooms are furnished from: "base", or "extended", which adds shapes the real validation rooms have and
# base lacks (round tables ringed by chairs, low reclined loveseats, ottomans) and draws every base room
# differently
FURNITURE = ("base", "extended")
ROLES_FILE = Path(__file__).resolve().parents[1] / "data" / "furniture_roles.json"
WALL = 0.10
WALL_COLOR = (0.86, 0.85, 0.80)
FLOOR_COLOR = (0.55, 0.47, 0.38)


def role_affordances() -> dict[str, str]:
    """Furniture role -> affordance name (data, so the code lists no affordance types)."""
    return json.loads(ROLES_FILE.read_text())["roles"]


@dataclass
class Opening:
    edge: int
    start: float  # along the edge from its first vertex (m)
    width: float
    bottom: float
    top: float
    kind: str  # "door" or "window"


@dataclass
class Room:
    name: str
    kind: str
    polygon: np.ndarray  # (n, 2) floor outline, counter-clockwise
    height: float
    openings: list[Opening] = field(default_factory=list)
    pieces: list[Piece] = field(default_factory=list)
    walls: list[Box] = field(default_factory=list)
    keep_free: list[Box] = field(default_factory=list)  # door swings

    def shell_boxes(self) -> list[Box]:
        low, high = self.polygon.min(axis=0), self.polygon.max(axis=0)
        floor = [
            Box.span((a[0], a[1], -0.05), (b[0], b[1], 0.0), FLOOR_COLOR)
            for a, b in _floor_rectangles(self.polygon)
        ]
        ceiling = Box.span(
            (low[0] - WALL, low[1] - WALL, self.height),
            (high[0] + WALL, high[1] + WALL, self.height + 0.05),
            (0.93, 0.93, 0.92),
        )
        return floor + self.walls + [ceiling]

    def furniture_boxes(self) -> list[Box]:
        return [part for piece in self.pieces for part in piece.world_parts()]

    def labels(self, points: np.ndarray | None = None) -> dict:
        """The room's ground truth in the `affordance-labels/1` format (DESIGN.md).

        Seats that carry no label (benches, boxes, lone chairs, a sofa's corner) get unlabelled regions. Given
        the scanned `points`, a labelled piece the scan barely saw loses its labels to a "not scanned" region,
        and so does a place whose support (its chair, the strip of top at a standing edge) it barely saw: a
        label on furniture that is not in the cloud would teach that empty space is a place, and a table place
        whose chair the scan missed looks like one without a chair, which carries no label."""
        roles = role_affordances()
        unseen = self.unseen_pieces(points) if points is not None else []
        labels, regions = [], []
        for piece in self.pieces:
            if any(piece is p for p in unseen):
                region = self._region(piece, _labelled_plan(piece), UNSEEN_MARGINS, skip=piece.anchors)
                if region is not None:
                    regions.append({"polygon": region, "note": f"not scanned: {piece.note}"})
                    continue
            for anchor in _labelled(piece, roles):
                if points is not None and support_seen_share(piece, anchor, points) < PLACE_SEEN_SHARE:
                    region = self._region(piece, _label_rectangle(anchor), UNSEEN_MARGINS, skip=[anchor])
                    if region is not None:
                        regions.append(
                            {"polygon": region, "note": f"not scanned: {piece.note}; {anchor.note}"}
                        )
                        continue
                labels.append(_label(piece, anchor, roles))
        for piece in self.pieces:
            for rectangles, margins, what in (
                (piece.unlabelled_seats, SEAT_MARGINS, "a seat"),
                (piece.unlabelled_edges, EDGE_MARGINS, "a work edge"),
            ):
                for rectangle in rectangles:
                    region = self._region(piece, np.array(rectangle), margins)
                    if region is not None:
                        regions.append({"polygon": region, "note": f"{what} with no label: {piece.note}"})
        return {
            "format": "affordance-labels/1",
            "scene": f"{self.name} (procedural {self.kind} room)",
            "cloud": f"{self.name}.ply",
            "frame": "z-up, metres, floor at z = 0",
            "labels": labels,
            "unlabelled_regions": regions,
        }

    def label_points(self, skip: Sequence[Anchor] = ()) -> np.ndarray:
        """(n, 2) points every 2 cm along every label (but those of the anchors in `skip`), in the world."""
        roles = role_affordances()
        points = [np.zeros((0, 2))]
        for piece in self.pieces:
            for anchor in _labelled(piece, roles):
                if any(anchor is other for other in skip):
                    continue
                start, end = piece.world_point(anchor.start), piece.world_point(anchor.end)
                steps = int(np.linalg.norm(end - start) / 0.02) + 2
                points.append(start + np.linspace(0, 1, steps)[:, None] * (end - start))
        return np.vstack(points)

    def _region(self, piece: Piece, rectangle: np.ndarray, margins, skip: Sequence[Anchor] = ()):
        """The piece's plan rectangle ((x0, y0), (x1, y1) in its frame) grown by the first of `margins` that
        keeps it LABEL_GAP clear of every label but those of `skip`, as a world polygon; None if none does."""
        avoid = self.label_points(skip)
        for margin in margins:
            grown = rectangle + np.array([[-1.0], [1.0]]) * (margin + LABEL_GAP)
            if not inside_polygon(_rectangle_polygon(piece, grown), avoid).any():
                return [
                    _rounded(p)
                    for p in _rectangle_polygon(piece, rectangle + np.array([[-1.0], [1.0]]) * margin)
                ]
        return None

    def unseen_pieces(self, points: np.ndarray) -> list[Piece]:
        """Labelled pieces of whose plan less than UNSEEN_SHARE shows any scanned point above 0.1 m."""
        above = points[points[:, 2] > 0.1, :2]
        roles = role_affordances()
        return [
            piece
            for piece in self.pieces
            if _labelled(piece, roles) and plan_seen_share(piece, above) < UNSEEN_SHARE
        ]


# A person's torso can be this far outside a seat they sit on: 0.12 m, how far the sitting skeletons' torso
# lies behind their hips (hips on the seat, leaning back), plus 0.15 m, DESIGN's place tolerance (a skeleton
# that close to a seat is sitting on it), rounded up; smaller ones are tried in turn until the region keeps
# clear of every label.
SEAT_MARGINS = (0.30, 0.25, 0.20, 0.15, 0.10, 0.05, 0.0)
# around where a person stands at an unlabelled work edge (furniture.STANDING_REACH already reaches as far
# as a standing skeleton can be): a grid step's half, shrunk like SEAT_MARGINS until clear of every label,
# and on to the band 0.15-0.30 m from the edge where a standing torso is (another piece's label often runs
# past a table's end: the region shrinks away from it rather than go)
EDGE_MARGINS = (0.05, 0.0, -0.05, -0.10, -0.15)
# around an unseen piece and its labels: DESIGN's place tolerance, never less than a grid step's half (the
# labels must lie inside, not on the edge)
UNSEEN_MARGINS = (0.15, 0.10, 0.05)
LABEL_GAP = 0.05  # regions keep at least this far from any label
UNSEEN_SHARE = 0.2  # a labelled piece with less of its plan seen than this is "not scanned"
# a place with less than this share of its support's 5 cm cells holding a scanned point is "not scanned": a
# chair pushed in behind a table seen from across it shows the top of its backrest and little else
PLACE_SEEN_SHARE = 0.15


def _labelled(piece: Piece, roles: dict[str, str]) -> list:
    """The piece's anchors that carry a label: of a role standing for an affordance, usable as it stands."""
    return [anchor for anchor in piece.anchors if anchor.role in roles and anchor.labelled]


def _label(piece: Piece, anchor, roles: dict[str, str]) -> dict:
    start, end = piece.world_point(anchor.start), piece.world_point(anchor.end)
    facing = float(np.angle(np.exp(1j * (anchor.facing + piece.yaw))))
    label = {"affordance": roles[anchor.role]}
    if anchor.is_point:
        label["at"] = _rounded((start + end) / 2)
    else:
        label["from"], label["to"] = _rounded(start), _rounded(end)
    label["facing"] = round(facing, 4)
    if anchor.torso_height is not None:  # a place at its own height (a bar stool's), not the skeleton's
        label["z"] = round(float(anchor.torso_height), 3)
    label["note"] = f"{piece.note}; {anchor.note}"
    return label


def _label_rectangle(anchor: Anchor) -> np.ndarray:
    """The plan rectangle ((x0, y0), (x1, y1) in the piece's frame) the anchor's label spans."""
    ends = np.array([anchor.start, anchor.end])
    return np.array([ends.min(axis=0), ends.max(axis=0)])


def _labelled_plan(piece: Piece) -> np.ndarray:
    """The piece's plan rectangle in its frame, stretched over its labels' ends."""
    lo, hi = piece.local_bounds()
    ends = np.array([end for anchor in piece.anchors for end in (anchor.start, anchor.end)])
    return np.array([np.minimum(lo, ends.min(axis=0)), np.maximum(hi, ends.max(axis=0))])


def _rectangle_polygon(piece: Piece, rectangle: np.ndarray) -> np.ndarray:
    (x0, y0), (x1, y1) = rectangle
    return np.array([piece.world_point(p) for p in ((x0, y0), (x1, y0), (x1, y1), (x0, y1))])


def plan_seen_share(piece: Piece, points_xy: np.ndarray, cell: float = 0.05) -> float:
    """Of the `cell` m cells of the piece's plan that its parts cover, the share holding one of the points."""
    lo, hi = piece.local_bounds()
    shape = np.maximum(np.ceil((hi - lo) / cell).astype(int), 1)
    centres = lo + (np.stack(np.indices(shape), axis=-1).reshape(-1, 2) + 0.5) * cell
    covered = np.zeros(len(centres), bool)
    for part in piece.parts:
        covered |= part.contains_xy(centres)
    local = (points_xy - (piece.x, piece.y)) @ rot2(piece.yaw)
    index = np.floor((local - lo) / cell).astype(int)
    inside = np.all((index >= 0) & (index < shape), axis=1)
    seen = np.zeros(shape, bool)
    seen[index[inside, 0], index[inside, 1]] = True
    return float(seen.reshape(-1)[covered].mean()) if covered.any() else 1.0


def support_seen_share(piece: Piece, anchor: Anchor, points: np.ndarray, cell: float = 0.05) -> float:
    """Of the ~`cell` m cells filling the anchor's support boxes, the share holding one of the scanned
    `points` (a point up to 2 cm outside a box, sensor noise, counts for its nearest cell); 1 for an anchor
    with no support of its own."""
    boxes = [box.placed(piece.x, piece.y, piece.yaw) for box in anchor.support]
    if not boxes:
        return 1.0
    corners = np.vstack([box.corners_xy() for box in boxes])
    centre = corners.mean(axis=0)
    points = points[
        np.linalg.norm(points[:, :2] - centre, axis=1)
        <= np.linalg.norm(corners - centre, axis=1).max() + 0.05
    ]
    seen = cells = 0
    for box in boxes:
        size = np.array(box.size)
        shape = np.maximum(np.round(size / cell).astype(int), 1)
        # the points in the box's own frame, from its low corner
        local = np.column_stack([(points[:, :2] - box.centre[:2]) @ rot2(box.yaw), points[:, 2]])
        local += np.array([*size[:2] / 2, -box.z_range[0]])
        near = np.all((local >= -0.02) & (local <= size + 0.02), axis=1)
        index = np.clip(np.floor(local[near] / (size / shape)).astype(int), 0, shape - 1)
        seen += len(np.unique(np.ravel_multi_index(index.T, shape)))
        cells += int(np.prod(shape))
    return seen / cells


def _rounded(point) -> list[float]:
    return [round(float(v), 4) for v in point]


def generate_room(kind: str, rng: np.random.Generator, name: str, furniture: str = "base") -> Room:
    if kind not in KINDS:
        raise ValueError(f"unknown room kind {kind!r}; choose from {', '.join(KINDS)}")
    if furniture not in FURNITURE:
        raise ValueError(f"unknown furniture {furniture!r}; choose from {', '.join(FURNITURE)}")
    room = _shell(kind, rng, name)
    previous = None  # the piece the last builder made, if it found a place
    for builder, mode in _program(kind, rng, furniture == "extended"):
        piece = builder(rng)
        reserve_body_space(piece)
        if mode == "in-front" and previous is None:
            continue  # a coffee table whose sofa found no place would stand in front of whatever came before
        previous = piece if _place(room, piece, mode, rng, previous if mode == "in-front" else None) else None
    return room


# ---------------------------------------------------------------- the shell


def _shell(kind: str, rng: np.random.Generator, name: str) -> Room:
    low, high = {"living": (3.0, 7.0), "office": (3.5, 10.0), "workshop": (3.0, 8.0), "mixed": (4.0, 10.0)}[
        kind
    ]
    width, depth = rng.uniform(low, high, 2)
    polygon = np.array([[0, 0], [width, 0], [width, depth], [0, depth]], float)
    if rng.random() < 0.3 and min(width, depth) > 4.0:  # an L: cut away one corner
        cut_w, cut_d = rng.uniform(0.25, 0.45) * width, rng.uniform(0.25, 0.45) * depth
        polygon = np.array(
            [
                [0, 0],
                [width, 0],
                [width, depth - cut_d],
                [width - cut_w, depth - cut_d],
                [width - cut_w, depth],
                [0, depth],
            ],
            float,
        )
    room = Room(name, kind, polygon, float(rng.uniform(2.4, 3.0)))
    room.openings = _openings(polygon, rng, room.height)
    room.walls = _walls(polygon, room.openings, room.height)
    room.keep_free = [_door_swing(polygon, door) for door in room.openings if door.kind == "door"]
    return room


def _edges(polygon: np.ndarray):
    for i, start in enumerate(polygon):
        end = polygon[(i + 1) % len(polygon)]
        length = float(np.linalg.norm(end - start))
        direction = (end - start) / length
        inward = np.array([-direction[1], direction[0]])  # counter-clockwise: the inside is on the left
        yield i, start, direction, inward, length


def _openings(polygon: np.ndarray, rng: np.random.Generator, height: float) -> list[Opening]:
    edges = [e for e in _edges(polygon) if e[4] >= 1.6]
    openings = []
    for k in range(int(rng.integers(1, 3)) + int(rng.integers(0, 4))):
        index, _, _, _, length = edges[int(rng.integers(len(edges)))]
        door = k < 1 or rng.random() < 0.2
        width = rng.uniform(0.8, 1.0) if door else rng.uniform(0.8, min(2.0, length - 0.6))
        start = rng.uniform(0.3, length - width - 0.3)
        candidate = Opening(
            index,
            start,
            width,
            0.0 if door else rng.uniform(0.8, 1.0),
            min(height - 0.2, 2.05) if door else min(height - 0.15, rng.uniform(2.0, 2.3)),
            "door" if door else "window",
        )
        if all(
            o.edge != index or start > o.start + o.width + 0.3 or start + width < o.start - 0.3
            for o in openings
        ):
            openings.append(candidate)
    return openings


def _walls(polygon: np.ndarray, openings: list[Opening], height: float) -> list[Box]:
    walls = []
    for index, start, direction, inward, length in _edges(polygon):
        yaw = float(np.arctan2(direction[1], direction[0]))
        pieces = []  # (from, to, bottom, top) along the edge, extended past its ends to close the corners
        cursor = -WALL
        for opening in sorted((o for o in openings if o.edge == index), key=lambda o: o.start):
            pieces.append((cursor, opening.start, 0.0, height))
            if opening.bottom > 0:
                pieces.append((opening.start, opening.start + opening.width, 0.0, opening.bottom))
            pieces.append((opening.start, opening.start + opening.width, opening.top, height))
            cursor = opening.start + opening.width
        pieces.append((cursor, length + WALL, 0.0, height))
        for a, b, bottom, top in pieces:
            middle = start + direction * (a + b) / 2 - inward * WALL / 2
            walls.append(
                Box(
                    (float(middle[0]), float(middle[1]), (bottom + top) / 2),
                    (b - a, WALL, top - bottom),
                    yaw,
                    WALL_COLOR,
                )
            )
            if bottom == 0.0:  # a skirting board along every stretch that reaches the floor
                board = start + direction * (max(a, 0.0) + min(b, length)) / 2 + inward * 0.0075
                walls.append(
                    Box(
                        (float(board[0]), float(board[1]), 0.04),
                        (min(b, length) - max(a, 0.0), 0.015, 0.08),
                        yaw,
                        (0.95, 0.95, 0.93),
                    )
                )
        for opening in (o for o in openings if o.edge == index):  # door and window frames stand proud
            for along in (opening.start - 0.035, opening.start + opening.width + 0.035):
                post = start + direction * along + inward * 0.01
                walls.append(
                    Box(
                        (float(post[0]), float(post[1]), (opening.bottom + opening.top) / 2),
                        (0.07, 0.02, opening.top - opening.bottom + 0.07),
                        yaw,
                        (0.95, 0.95, 0.93),
                    )
                )
            if opening.kind == "window":
                sill = start + direction * (opening.start + opening.width / 2) + inward * 0.08
                walls.append(
                    Box(
                        (float(sill[0]), float(sill[1]), opening.bottom - 0.015),
                        (opening.width + 0.14, 0.16, 0.03),
                        yaw,
                        (0.95, 0.95, 0.93),
                    )
                )
    return walls


def _door_swing(polygon: np.ndarray, door: Opening) -> Box:
    _, start, direction, inward, _ = list(_edges(polygon))[door.edge]
    centre = start + direction * (door.start + door.width / 2) + inward * 0.5
    return Box(
        (float(centre[0]), float(centre[1]), 1.0),
        (door.width + 0.1, 1.0, 2.0),
        float(np.arctan2(direction[1], direction[0])),
        (0, 0, 0),
    )


def _floor_rectangles(polygon: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The floor as axis-aligned rectangles (the outlines here are rectangles and L shapes)."""
    xs, ys = np.unique(polygon[:, 0]), np.unique(polygon[:, 1])
    cells = []
    for x0, x1 in zip(xs[:-1], xs[1:]):
        for y0, y1 in zip(ys[:-1], ys[1:]):
            if inside_polygon(polygon, np.array([[(x0 + x1) / 2, (y0 + y1) / 2]]))[0]:
                cells.append((np.array([x0, y0]), np.array([x1, y1])))
    return cells


def inside_polygon(polygon: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Even-odd rule, vectorised over points (boundary points count as inside within 1e-9)."""
    return polygon_contains(polygon, points) | _on_boundary(polygon, points)


def _on_boundary(polygon: np.ndarray, points: np.ndarray) -> np.ndarray:
    a, b = polygon, np.roll(polygon, -1, axis=0)
    ab = b - a
    t = np.clip(np.einsum("pij,ij->pi", points[:, None] - a, ab) / np.einsum("ij,ij->i", ab, ab), 0, 1)
    closest = a + t[..., None] * ab
    return (np.linalg.norm(points[:, None] - closest, axis=2) < 1e-9).any(axis=1)


# ---------------------------------------------------------------- what goes in a room


def _program(kind: str, rng: np.random.Generator, extended: bool = False) -> list[tuple]:
    """(builder, placement) pairs in placement order: the big pieces first, then context and distractors;
    `extended`: from the extended furniture (FURNITURE)."""
    n = lambda low, high: int(rng.integers(low, high + 1))  # noqa: E731
    maybe = lambda share, pieces: pieces if rng.random() < share else []  # noqa: E731
    pick = lambda shares: list(shares)[int(rng.choice(len(shares), p=list(shares.values())))]  # noqa: E731
    # base draws nothing for these, so its rooms stay as they were
    extend = lambda base, shares: pick({base: 1 - sum(shares.values()), **shares}) if extended else base  # noqa: E731
    # Every kind also gets, now and then, another kind's furniture, so that each affordance's model sees the
    # others' furniture as negatives in every kind of room (shares in docs/synthetic-rooms.md).
    lounge_corner = [(pick({F.sofa: 0.4, F.armchair: 0.35, F.lounge_chair: 0.25}), "wall")]
    lounge_corner.append((extend(F.coffee_table, {F.ottoman: 0.3}), "in-front"))
    living = (
        [
            (
                extend(pick({F.sofa: 0.55, F.corner_sofa: 0.25, F.chaise_sofa: 0.2}), {F.loveseat: 0.3}),
                "wall",
            ),
            (extend(F.coffee_table, {F.ottoman: 0.3}), "in-front"),
        ]
        # before the armchairs and shelves: a table ringed by places finds no room once they stand (an
        # island, ringed by stools and standing room, first of all)
        + maybe(0.35, [_counter_height_seating(rng)])  # a kitchen-dining flavour
        + maybe(0.5, [(extend(F.dining_table, {F.round_table: 0.4}), "free")])
        + maybe(0.3, [(F.desk, "wall")])  # an office corner
        + [
            (pick({F.armchair: 0.65, F.lounge_chair: 0.35}), "free" if rng.random() < 0.5 else "wall")
            for _ in range(n(0, 2))
        ]
        + [(F.tv_unit, "wall")] * n(0, 1)
        + [(F.shelf, "wall")] * n(0, 2)
    )
    office = (
        [(F.desk, "wall") for _ in range(n(1, 4))]
        + [(extend(F.meeting_table, {F.round_table: 0.4}), "free")] * n(0, 1)
        + [(F.cabinet, "wall")] * n(1, 3)
        + [(F.shelf, "wall")] * n(0, 2)
        + maybe(0.3, lounge_corner)
        + maybe(0.3, [(F.counter, "wall")])  # a kitchenette
        + maybe(0.15, [(lambda r: F.bar_table(r, both_sides=False), "wall")])  # its breakfast bar
    )
    workshop = (
        [(F.counter, "wall") for _ in range(n(1, 3))]
        + maybe(0.35, [_counter_height_seating(rng)])  # a kitchen with an island or a bar
        + [(lambda r: F.workbench(r, both_sides=True), "free")] * n(0, 2)
        + [(F.workbench, "wall")] * n(0, 1)
        + [(F.high_table, "free")] * n(0, 1)
        + [(F.cabinet, "wall")] * n(0, 2)
        + maybe(0.35, [(F.desk, "wall")])
        + maybe(0.25, [(F.sofa, "wall")])  # a break corner
    )
    distractors = (
        [(F.bench, "any")] * n(0, 1)
        + [(F.storage_box, "any")] * n(0, 2)
        + [(F.lone_chair, "any")] * n(0, 2)
        + [(lambda r: F.shelf(r, low=True), "wall")] * n(0, 1)
        + [(F.stool, "any")] * n(0, 2)
        + [(lambda r: F.counter(r, cluttered=True), "wall")] * n(0, 1)
        + [(lambda r: F.desk(r, place=False, cluttered=True), "wall")] * n(0, 1)
        + [(lambda r: F.workbench(r, cluttered=True), "any")] * n(0, 1)
        + [(F.coffee_table, "any")] * n(0, 1)
    )
    decor = (
        [(F.picture, "wall") for _ in range(n(2, 6))]
        + [(F.radiator, "wall")] * n(0, 2)
        + [(F.floor_clutter, "any") for _ in range(n(2, 6))]
    )
    if kind == "mixed":
        main = living[:2] + maybe(0.25, [_counter_height_seating(rng)]) + office[: n(1, 2)]
        main += workshop[: n(1, 2)] + [(F.armchair, "free")] * n(0, 1)
    else:
        main = {"living": living, "office": office, "workshop": workshop}[kind]
    chosen = [distractors[i] for i in sorted(rng.permutation(len(distractors))[: n(2, 5)])]
    return main + chosen + decor


def _counter_height_seating(rng: np.random.Generator) -> tuple:
    """A kitchen island (half the time), a free-standing bar table or a breakfast bar against a wall, each
    with bar stools or high chairs."""
    draw = rng.random()
    if draw < 0.5:
        return (F.kitchen_island, "free")
    if draw < 0.75:
        return (F.bar_table, "free")
    return (lambda r: F.bar_table(r, both_sides=False), "wall")


def _place(
    room: Room, piece: Piece, mode: str, rng: np.random.Generator, anchor_piece: Piece | None, tries: int = 80
) -> bool:
    edges = list(_edges(room.polygon))
    lengths = np.array([e[4] for e in edges])
    lo, hi = piece.local_bounds()
    for _ in range(tries):
        if mode == "in-front" and anchor_piece is not None:
            front = anchor_piece.local_bounds()[1][0]
            gap = rng.uniform(0.46, 0.65)
            piece.x, piece.y = anchor_piece.world_point((front + gap - lo[0], rng.uniform(-0.2, 0.2)))
            piece.yaw = anchor_piece.yaw
        elif mode == "wall" or (mode == "any" and rng.random() < 0.6):
            _, start, direction, inward, length = edges[
                int(rng.choice(len(edges), p=lengths / lengths.sum()))
            ]
            along = rng.uniform(0, length)
            piece.x, piece.y = start + direction * along + inward * (rng.uniform(0.02, 0.05) - lo[0])
            piece.yaw = float(np.arctan2(inward[1], inward[0]))
        else:
            low, high = room.polygon.min(axis=0), room.polygon.max(axis=0)
            piece.x, piece.y = rng.uniform(low, high)
            piece.yaw = (
                float(rng.integers(4) * np.pi / 2 + rng.normal(0, 0.1))
                if rng.random() < 0.7
                else float(rng.uniform(0, 2 * np.pi))
            )
        if fits(room, piece):
            room.pieces.append(piece)
            return True
    return False


def reserve_body_space(piece: Piece, margin: float = 0.05) -> None:
    """Add to each anchor's free space the box its affordance's skeleton fills along the whole label (from the
    floor to above the head), so nothing else is placed where that person's knees, feet or elbows would be."""
    from ..geometry.skeleton import get_skeleton, place_joints

    roles = role_affordances()
    for anchor in piece.anchors:
        skeleton = get_skeleton(roles[anchor.role])
        torso = skeleton.torso_height if anchor.torso_height is None else anchor.torso_height
        ends = np.array([[*anchor.start, torso, anchor.facing], [*anchor.end, torso, anchor.facing]])
        joints = place_joints(skeleton.joints, ends).reshape(-1, 3)
        low, high = joints.min(axis=0) - margin, joints.max(axis=0) + margin
        anchor.clearance.append(Box.span((low[0], low[1], 0.0), (high[0], high[1], high[2]), (0, 0, 0)))


def fits(room: Room, piece: Piece) -> bool:
    """Inside the room, clear of walls, door swings, other pieces, and every piece's free space."""
    parts, clearance = piece.world_parts(), piece.world_clearance()
    corners = np.vstack([box.corners_xy() for box in parts + clearance])
    if not inside_polygon(room.polygon, corners).all():
        return False
    others = [p for other in room.pieces for p in other.world_parts()]
    others_free = [c for other in room.pieces for c in other.world_clearance()]
    return not (
        any_overlap(parts, room.walls + room.keep_free + others + others_free)
        or any_overlap(clearance, room.walls + others)
    )


def world_anchor_boxes(piece: Piece) -> list[tuple]:
    """(anchor, its clearance boxes in the world) for every anchor of a placed piece."""
    return [
        (anchor, [box.placed(piece.x, piece.y, piece.yaw) for box in anchor.clearance])
        for anchor in piece.anchors
    ]


__all__ = [
    "KINDS",
    "Room",
    "generate_room",
    "fits",
    "inside_polygon",
    "role_affordances",
    "rot2",
]
