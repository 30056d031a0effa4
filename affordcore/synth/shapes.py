"""Boxes turned about z: the one solid the room generator builds furniture, walls and floors from.

A `Box` is a centre, a size and a yaw. Furniture pieces are lists of boxes in their own frame (x forward:
the side a person uses, y left, z up, origin on the floor under the piece's centre), placed in a room by a
yaw and a translation. Overlap tests use the separating-axis theorem in plan and interval overlap in height.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# outward-facing, vertices ordered bottom (0-3) then top (4-7), counter-clockwise from (-x, -y)
_TRIANGLES = np.array(
    [
        [0, 2, 1],
        [0, 3, 2],
        [4, 5, 6],
        [4, 6, 7],
        [0, 1, 5],
        [0, 5, 4],
        [1, 2, 6],
        [1, 6, 5],
        [2, 3, 7],
        [2, 7, 6],
        [3, 0, 4],
        [3, 4, 7],
    ]
)


def rot2(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s], [s, c]])


@dataclass(frozen=True)
class Box:
    centre: tuple[float, float, float]
    size: tuple[float, float, float]
    yaw: float = 0.0
    color: tuple[float, float, float] = (0.6, 0.6, 0.6)

    @classmethod
    def span(cls, low, high, color=(0.6, 0.6, 0.6), yaw: float = 0.0) -> Box:
        """An axis-aligned box (in its own frame) from its low and high corners."""
        low, high = np.asarray(low, float), np.asarray(high, float)
        return cls(tuple((low + high) / 2), tuple(high - low), yaw, tuple(color))

    def placed(self, x: float, y: float, yaw: float) -> Box:
        """This box moved by a rotation `yaw` about the origin, then a translation (x, y)."""
        cx, cy = rot2(yaw) @ np.array(self.centre[:2]) + (x, y)
        return Box((float(cx), float(cy), self.centre[2]), self.size, self.yaw + yaw, self.color)

    def contains_xy(self, xy: np.ndarray) -> np.ndarray:
        """Whether plan points (..., 2) lie inside the box's footprint."""
        local = (np.asarray(xy, float) - self.centre[:2]) @ rot2(self.yaw)
        return np.all(np.abs(local) <= np.array(self.size[:2]) / 2, axis=-1)

    def corners_xy(self) -> np.ndarray:
        half = np.array(self.size[:2]) / 2
        square = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * half
        return square @ rot2(self.yaw).T + self.centre[:2]

    @property
    def z_range(self) -> tuple[float, float]:
        return self.centre[2] - self.size[2] / 2, self.centre[2] + self.size[2] / 2

    def mesh_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(8, 3) vertices and (12, 3) triangles."""
        low, high = self.z_range
        ring = self.corners_xy()
        vertices = np.vstack(
            [np.column_stack([ring, np.full(4, low)]), np.column_stack([ring, np.full(4, high)])]
        )
        return vertices, _TRIANGLES.copy()


def disc(radius: float, z0: float, z1: float, color, sides: int = 16) -> list[Box]:
    """A regular `sides`-gon inscribed in a circle of `radius`, from z0 to z1, as sides / 2 boxes: each
    spans two opposite faces (half-length the polygon's apothem, half-width half a face) and the wedges from
    the centre to them, so together they fill the polygon exactly; 16 sides stay within 2 % of the radius
    from the circle."""
    half_turn = np.pi / sides
    length, width = 2 * radius * np.cos(half_turn), 2 * radius * np.sin(half_turn)
    z = (z0 + z1) / 2
    return [
        Box((0.0, 0.0, z), (length, width, z1 - z0), 2 * half_turn * k, tuple(color))
        for k in range(sides // 2)
    ]


def boxes_overlap(a: Box, b: Box, tolerance: float = 1e-3) -> bool:
    """True when the two solids share volume deeper than `tolerance` (touching is allowed)."""
    a_low, a_high = a.z_range
    b_low, b_high = b.z_range
    if min(a_high, b_high) - max(a_low, b_low) <= tolerance:
        return False
    return rectangles_overlap(a.corners_xy(), b.corners_xy(), tolerance)


def rectangles_overlap(a: np.ndarray, b: np.ndarray, tolerance: float = 1e-3) -> bool:
    """Separating-axis test for two convex quadrilaterals given as (4, 2) corners."""
    for polygon in (a, b):
        edges = np.roll(polygon, -1, axis=0) - polygon
        normals = np.column_stack([-edges[:, 1], edges[:, 0]])
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        pa, pb = a @ normals.T, b @ normals.T
        gap = np.maximum(pa.min(axis=0) - pb.max(axis=0), pb.min(axis=0) - pa.max(axis=0))
        if np.any(gap >= -tolerance):
            return False
    return True


@dataclass
class Anchor:
    """Where a person uses a piece, in the piece's frame: a segment (or a point) of torso positions, a facing,
    and the space that must stay free for them (boxes in the piece's frame)."""

    role: str
    start: tuple[float, float]
    end: tuple[float, float]
    facing: float
    clearance: list[Box] = field(default_factory=list)
    note: str = ""
    # The torso's height above the floor when this place is used, where the seat is not at the usual height
    # (a bar stool, a lounge chair); None: the skeleton's own torso height.
    torso_height: float | None = None
    # False for a place nobody can use as the room stands (a table place whose chair is missing): its space
    # is kept free like any place's, but it carries no label
    labelled: bool = True
    # What a scan must show for the place to be known (boxes in the piece's frame): a table place's chair,
    # the strip of top a standing person works on. Empty: the piece as a whole (a sofa's seats are the sofa).
    support: list[Box] = field(default_factory=list)

    @property
    def is_point(self) -> bool:
        return bool(np.allclose(self.start, self.end, atol=0.05))


@dataclass
class Piece:
    """One furniture item (or a group such as a desk with its chair) in its own frame, then placed."""

    kind: str
    parts: list[Box]
    anchors: list[Anchor] = field(default_factory=list)
    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0
    note: str = ""
    # Plan rectangles ((x0, y0), (x1, y1)) in the piece's frame where a person could sit although no label
    # says so (a bench, a box, a lone chair, a sofa's corner): the room turns them into unlabelled regions.
    unlabelled_seats: list[tuple[tuple[float, float], tuple[float, float]]] = field(default_factory=list)
    # Plan rectangles in the piece's frame where a person could stand and work at it although no label says
    # so (the narrow ends of a free-standing table, the edge of a cluttered top): unlabelled regions too.
    unlabelled_edges: list[tuple[tuple[float, float], tuple[float, float]]] = field(default_factory=list)

    def world_parts(self) -> list[Box]:
        return [part.placed(self.x, self.y, self.yaw) for part in self.parts]

    def world_clearance(self) -> list[Box]:
        return [box.placed(self.x, self.y, self.yaw) for anchor in self.anchors for box in anchor.clearance]

    def world_point(self, local_xy) -> np.ndarray:
        return rot2(self.yaw) @ np.asarray(local_xy, float) + (self.x, self.y)

    @property
    def depth(self) -> float:
        """Extent along the piece's own x (front to back)."""
        corners = np.vstack([part.corners_xy() for part in self.parts])
        return float(np.ptp(corners[:, 0]))

    def local_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        corners = np.vstack([part.corners_xy() for part in self.parts])
        return corners.min(axis=0), corners.max(axis=0)


def any_overlap(boxes: list[Box], others: list[Box], tolerance: float = 1e-3) -> bool:
    """Do any of `boxes` overlap any of `others`? Axis-aligned bounds first (vectorised), then exact tests."""
    return any(
        boxes_overlap(boxes[i], others[j], tolerance) for i, j in _candidate_pairs(boxes, others, tolerance)
    )


def overlaps_any(boxes: list[Box], others: list[Box], tolerance: float = 1e-3) -> np.ndarray:
    """(len(boxes),) whether each of `boxes` overlaps any of `others`."""
    hit = np.zeros(len(boxes), bool)
    for i, j in _candidate_pairs(boxes, others, tolerance):
        hit[i] = hit[i] or boxes_overlap(boxes[i], others[j], tolerance)
    return hit


def _candidate_pairs(boxes: list[Box], others: list[Box], tolerance: float) -> np.ndarray:
    """(i, j) pairs whose axis-aligned bounds overlap by more than `tolerance`."""
    if not boxes or not others:
        return np.zeros((0, 2), int)
    a, b = _bounds(boxes), _bounds(others)
    return np.argwhere(
        np.all(
            (a[:, None, :3] < b[None, :, 3:] - tolerance) & (b[None, :, :3] < a[:, None, 3:] - tolerance),
            axis=2,
        )
    )


def _bounds(boxes: list[Box]) -> np.ndarray:
    """(n, 6) axis-aligned bounds: x, y, z minima then maxima."""
    centre, size = np.array([box.centre for box in boxes]), np.array([box.size for box in boxes])
    cos, sin = np.abs(np.cos([box.yaw for box in boxes])), np.abs(np.sin([box.yaw for box in boxes]))
    half = (
        np.column_stack(
            [cos * size[:, 0] + sin * size[:, 1], sin * size[:, 0] + cos * size[:, 1], size[:, 2]]
        )
        / 2
    )
    return np.hstack([centre - half, centre + half])
