"""Ground-truth labels (DESIGN.md, "Ground-truth labels: affordance-labels/1"): file I/O, per-pose ground
truth on the pose grid, place-level matching, and a top-view plot.

A label is where a person's torso is while using an affordance: a segment ``from`` -> ``to`` (a sofa's seat
line, a counter's working edge) or a point ``at`` (one chair), with ``facing`` the theta of the person. A pose
is positive when its (x, y) is within ``XY_TOLERANCE`` of a label of its affordance (distance to the segment,
end caps included, or to the point) and its theta within ``THETA_TOLERANCE`` of the label's facing, angles
compared modulo 2 pi, at the torso levels within ``Z_TOLERANCE`` (one voxel) of the label's torso height: its
optional ``z`` (a bar stool's place sits higher than a dining chair's), else the skeleton's own. DESIGN.md
says "every z level counts" of a grid of three levels one voxel apart, which this is; a grid with levels
above them (high seats, `torso_reach_above`) would otherwise call a skeleton floating 0.3 m over an ordinary
chair a place. Poses whose (x, y) is inside an unlabelled region are excluded
from training and scoring, whatever their theta. Both bounds are inclusive (with 1e-9 of slack, so a pose
exactly on the tolerance of a round-number label is positive whatever the floating-point rounding).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from .geometry.grid import PoseGrid
from .jsonfile import read_json

FORMAT = "affordance-labels/1"
XY_TOLERANCE = 0.15  # m, DESIGN.md
THETA_TOLERANCE = 0.4  # rad, DESIGN.md
LOOSE_TOLERANCES = {"xy_tolerance": 0.3, "theta_tolerance": 0.5}  # DESIGN.md's loose variant
Z_TOLERANCE = 0.1  # m: the torso levels one voxel either side of the label's height count
_SLACK = 1e-9
MOVED_TILT_LIMIT = 10.0  # deg: labels move with a cloud levelled by at most this much (LabelSet.moved)

Point = tuple[float, float]


class LabelError(ValueError):
    """A label file that cannot be used; the message names the file and the field."""


@dataclass(frozen=True)
class Label:
    """One labelled place: either ``at`` (a point) or ``start`` -> ``end`` (the file's "from" / "to")."""

    affordance: str
    facing: float
    at: Point | None = None
    start: Point | None = None
    end: Point | None = None
    note: str | None = None
    z: float | None = None  # the torso's height above the floor (m); None: the affordance skeleton's own

    def __post_init__(self) -> None:
        for name in ("at", "start", "end"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, tuple(float(v) for v in value))
        object.__setattr__(self, "facing", float(self.facing))
        if (self.at is None) == (self.start is None) or (self.start is None) != (self.end is None):
            raise ValueError("a label is either a point 'at' or a segment 'from' -> 'to'")

    def distance(self, xy: np.ndarray) -> np.ndarray:
        """Distance in plan from points (..., 2) to the label (to the nearest end beyond a segment's ends)."""
        xy = np.asarray(xy, dtype=np.float64)
        if self.at is not None:
            return np.hypot(*np.moveaxis(xy - self.at, -1, 0))
        a, d = np.array(self.start), np.subtract(self.end, self.start)
        t = np.clip((xy - a) @ d / max(d @ d, 1e-300), 0.0, 1.0)
        return np.hypot(*np.moveaxis(xy - a - t[..., None] * d, -1, 0))


@dataclass(frozen=True)
class UnlabelledRegion:
    polygon: tuple[Point, ...]
    note: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "polygon", tuple(tuple(float(v) for v in p) for p in self.polygon))

    def contains(self, xy: np.ndarray) -> np.ndarray:
        return polygon_contains(np.array(self.polygon), xy)


def polygon_contains(polygon: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Even-odd point-in-polygon test for points (..., 2)."""
    xy = np.asarray(xy, dtype=np.float64)
    x, y = xy[..., 0], xy[..., 1]
    inside = np.zeros(x.shape, dtype=bool)
    for (x0, y0), (x1, y1) in zip(polygon, np.roll(polygon, -1, axis=0)):
        crosses = (y0 > y) != (y1 > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            inside ^= crosses & (x < x0 + (y - y0) * (x1 - x0) / (y1 - y0))
    return inside


@dataclass(frozen=True)
class LabelSet:
    scene: str
    cloud: str
    frame: str
    labels: tuple[Label, ...] = ()
    unlabelled_regions: tuple[UnlabelledRegion, ...] = ()
    format: str = FORMAT

    def __post_init__(self) -> None:
        object.__setattr__(self, "labels", tuple(self.labels))
        object.__setattr__(self, "unlabelled_regions", tuple(self.unlabelled_regions))

    @property
    def affordances(self) -> list[str]:
        return sorted({label.affordance for label in self.labels})

    def of(self, affordance: str) -> list[Label]:
        return [label for label in self.labels if label.affordance == affordance]

    def unlabelled(self, xy: np.ndarray) -> np.ndarray:
        """Whether points (..., 2) lie inside any unlabelled region."""
        xy = np.asarray(xy, dtype=np.float64)
        inside = np.zeros(xy.shape[:-1], dtype=bool)
        for region in self.unlabelled_regions:
            inside |= region.contains(xy)
        return inside

    def moved(self, world_from_input: np.ndarray) -> LabelSet:
        """The labels of a cloud given in its own frame, moved with it into the world frame
        (`world_from_input`, 4 x 4, what gravity alignment did to the cloud). Labels are places on a floor
        plan, so the cloud's own frame must already be about z-up (levelling a slight tilt, moving the floor
        to z = 0); a cloud turned further than `MOVED_TILT_LIMIT` has no plan its labels could be on, and is
        refused."""
        rotation, shift = np.asarray(world_from_input, np.float64)[:3, :3], world_from_input[:3, 3]
        tilt = math.degrees(math.acos(float(np.clip(rotation[2, 2], -1.0, 1.0))))
        if tilt > MOVED_TILT_LIMIT:
            raise LabelError(
                f"{self.scene}: labels are places on the plan of a z-up cloud, and gravity alignment "
                f"turned this cloud {tilt:.0f} deg; level it first (afford align CLOUD --out LEVEL.ply) "
                "and label that"
            )

        def plan(point) -> tuple[float, float]:
            return tuple((rotation @ (*point, 0.0) + shift)[:2])

        def facing(theta: float) -> float:
            x, y, _ = rotation @ (math.cos(theta), math.sin(theta), 0.0)
            return math.atan2(y, x) % (2 * math.pi)

        ends = ("at", "start", "end")
        labels = [
            replace(
                label,
                facing=facing(label.facing),
                **{k: plan(getattr(label, k)) for k in ends if getattr(label, k) is not None},
            )
            for label in self.labels
        ]
        regions = [replace(r, polygon=tuple(plan(p) for p in r.polygon)) for r in self.unlabelled_regions]
        return replace(self, labels=tuple(labels), unlabelled_regions=tuple(regions))


# ---------------------------------------------------------------------------------------------- file I/O


def load_labels(path: str | Path) -> LabelSet:
    """Read and validate a label file; every error is a `LabelError` naming the file and the field."""
    path = Path(path)
    return _parse(read_json(path, LabelError), str(path))


def save_labels(path: str | Path, labels: LabelSet) -> Path:
    """Write a label file (validated first, so whatever is saved loads back equal)."""
    path = Path(path)
    document: dict[str, Any] = {
        "format": labels.format,
        "scene": labels.scene,
        "cloud": labels.cloud,
        "frame": labels.frame,
        "labels": [],
        "unlabelled_regions": [],
    }
    for label in labels.labels:
        entry: dict[str, Any] = {"affordance": label.affordance}
        entry.update(
            {"at": list(label.at)}
            if label.at is not None
            else {"from": list(label.start), "to": list(label.end)}
        )
        entry["facing"] = label.facing
        if label.z is not None:
            entry["z"] = label.z
        if label.note is not None:
            entry["note"] = label.note
        document["labels"].append(entry)
    for region in labels.unlabelled_regions:
        polygon = [list(vertex) for vertex in region.polygon]
        document["unlabelled_regions"].append({"polygon": polygon, "note": region.note})
    _parse(document, str(path))
    path.write_text(json.dumps(document, indent=1, ensure_ascii=False, allow_nan=False) + "\n")
    return path


def _parse(document: Any, name: str) -> LabelSet:
    def fail(where: str, problem: str) -> LabelError:
        return LabelError(f"{name}: {where} {problem}")

    def check_keys(obj: dict, where: str, required: set[str], optional: set[str]) -> None:
        for key in sorted(required - set(obj)):
            raise fail(f"{where}.{key}" if where else key, "is missing")
        for key in sorted(set(obj) - required - optional):
            raise fail(f"{where}.{key}" if where else key, f"is not a field of {FORMAT}")

    def text(obj: dict, key: str, where: str, non_empty: bool = False) -> str:
        value = obj[key]
        if not isinstance(value, str) or (non_empty and not value.strip()):
            raise fail(where, "must be a non-empty string" if non_empty else "must be a string")
        return value

    def number(value: Any, where: str) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise fail(where, f"must be a number, got {value!r}")
        if not math.isfinite(value):
            raise fail(where, f"must be finite, got {value!r}")
        return float(value)

    def point(value: Any, where: str) -> Point:
        if not isinstance(value, list) or len(value) != 2:
            raise fail(where, f"must be 2 numbers [x, y], got {value!r}")
        return (number(value[0], f"{where}[0]"), number(value[1], f"{where}[1]"))

    def items(value: Any, where: str) -> list:
        if not isinstance(value, list):
            raise fail(where, f"must be a list, got {type(value).__name__}")
        return value

    if not isinstance(document, dict):
        raise LabelError(f"{name}: the top level must be a JSON object")
    if document.get("format") != FORMAT:
        raise fail("format", f"must be {FORMAT!r}, got {document.get('format')!r}")
    check_keys(document, "", {"format", "scene", "cloud", "frame", "labels"}, {"unlabelled_regions"})
    labels = []
    for i, entry in enumerate(items(document["labels"], "labels")):
        where = f"labels[{i}]"
        if not isinstance(entry, dict):
            raise fail(where, "must be an object")
        has_at, has_segment = "at" in entry, "from" in entry or "to" in entry
        if has_at == has_segment:
            raise fail(
                where,
                "must have either 'at' (a point) or 'from' and 'to' (a segment)"
                + (", not both" if has_at else ""),
            )
        check_keys(
            entry, where, {"affordance", "facing"} | ({"at"} if has_at else {"from", "to"}), {"note", "z"}
        )
        labels.append(
            Label(
                affordance=text(entry, "affordance", f"{where}.affordance", non_empty=True),
                facing=number(entry["facing"], f"{where}.facing"),
                at=point(entry["at"], f"{where}.at") if has_at else None,
                start=None if has_at else point(entry["from"], f"{where}.from"),
                end=None if has_at else point(entry["to"], f"{where}.to"),
                note=text(entry, "note", f"{where}.note") if "note" in entry else None,
                z=number(entry["z"], f"{where}.z") if "z" in entry else None,
            )
        )
    regions = []
    for j, entry in enumerate(items(document.get("unlabelled_regions", []), "unlabelled_regions")):
        where = f"unlabelled_regions[{j}]"
        if not isinstance(entry, dict):
            raise fail(where, "must be an object")
        check_keys(entry, where, {"polygon"}, {"note"})
        polygon = items(entry["polygon"], f"{where}.polygon")
        if len(polygon) < 3:
            raise fail(f"{where}.polygon", f"must have at least 3 vertices, has {len(polygon)}")
        regions.append(
            UnlabelledRegion(
                tuple(point(p, f"{where}.polygon[{k}]") for k, p in enumerate(polygon)),
                text(entry, "note", f"{where}.note") if "note" in entry else "",
            )
        )
    return LabelSet(
        scene=text(document, "scene", "scene"),
        cloud=text(document, "cloud", "cloud"),
        frame=text(document, "frame", "frame"),
        labels=tuple(labels),
        unlabelled_regions=tuple(regions),
    )


# ------------------------------------------------------------------------------------- ground truth


def angle_gap(a: np.ndarray | float, b: np.ndarray | float) -> np.ndarray:
    """|a - b| with the difference wrapped to [-pi, pi]."""
    return np.abs((np.asarray(a) - b + np.pi) % (2 * np.pi) - np.pi)


@dataclass(frozen=True)
class GroundTruth:
    """One affordance's ground truth on a pose grid: per (theta, x, y) and, where labels hold at some torso
    levels only, per level."""

    grid: PoseGrid
    positive: np.ndarray  # (n_theta, nx, ny) bool: positive at some level; False where excluded
    excluded: np.ndarray  # (nx, ny) bool: inside an unlabelled region, every theta and z left out
    by_level: np.ndarray | None = None  # (nz, n_theta, nx, ny) bool; None: every level repeats `positive`

    def pose_mask(self) -> np.ndarray:
        """(nz, n_theta, nx, ny) positives; ``.ravel()`` follows the grid's pose numbering."""
        return self.by_level if self.by_level is not None else np.broadcast_to(self.positive, self.grid.shape)

    def scored_mask(self) -> np.ndarray:
        """(nz, n_theta, nx, ny): the poses used in training and scoring (not in an unlabelled region)."""
        return np.broadcast_to(~self.excluded, self.grid.shape)

    def counts(self) -> tuple[int, int]:
        """(positives, negatives) over every pose of the grid, excluded poses left out."""
        nz, n_theta = self.grid.shape[:2]
        positives = int(self.pose_mask().sum())
        return positives, int((~self.excluded).sum()) * n_theta * nz - positives


def ground_truth(
    labels: LabelSet,
    affordance: str,
    grid: PoseGrid,
    xy_tolerance: float = XY_TOLERANCE,
    theta_tolerance: float = THETA_TOLERANCE,
    torso_height: float | None = None,
) -> GroundTruth:
    """Which poses of ``grid`` are positive for ``affordance`` (see the module docstring); `torso_height` is
    the skeleton's, for labels without a height of their own (None: every level counts for them)."""
    xy = np.stack(np.meshgrid(grid.x, grid.y, indexing="ij"), axis=-1)  # (nx, ny, 2)
    by_level = np.zeros(grid.shape, dtype=bool)
    every_level = True
    for label in labels.of(affordance):
        near = label.distance(xy) <= xy_tolerance + _SLACK
        facing = angle_gap(grid.theta, label.facing) <= theta_tolerance + _SLACK
        height = label.z if label.z is not None else torso_height
        levels = (
            np.abs(grid.z - height) <= Z_TOLERANCE + 1e-6
            if height is not None
            else np.ones(len(grid.z), bool)
        )
        every_level &= bool(levels.all())
        by_level[levels] |= facing[:, None, None] & near[None]
    excluded = labels.unlabelled(xy)
    by_level &= ~excluded
    return GroundTruth(grid, by_level.any(axis=0), excluded, None if every_level else by_level)


class ClassCount(NamedTuple):
    positives: int
    negatives: int
    ratio: str  # "1:N" as in the paper's table (N = negatives // positives)

    @classmethod
    def of(cls, positives: int, negatives: int) -> ClassCount:
        return cls(positives, negatives, f"1:{negatives // positives:,}" if positives else "no positives")


def class_counts(
    labels: LabelSet,
    grids: dict[str, PoseGrid],
    torso_heights: dict[str, float] | None = None,
    **tolerances: float,
) -> dict[str, ClassCount]:
    """Per affordance with a grid: positives, negatives and their ratio (sum the first two over rooms and
    call `ClassCount.of` for a data set's table); `torso_heights`: each affordance skeleton's."""
    heights = torso_heights or {}
    return {
        name: ClassCount.of(
            *ground_truth(labels, name, grid, torso_height=heights.get(name), **tolerances).counts()
        )
        for name, grid in sorted(grids.items())
    }


# ---------------------------------------------------------------------------------- place-level match


@dataclass(frozen=True)
class PlaceMatch:
    labels: list[Label]  # the labels of the affordance, in file order
    found: np.ndarray  # (n_labels,) bool: some counted skeleton within the tolerances
    false: np.ndarray  # (n_skeletons,) bool: matches no label (and is not in an unlabelled region)
    ignored: np.ndarray  # (n_skeletons,) bool: inside an unlabelled region, neither finds nor is false

    @property
    def recall(self) -> float:
        return float(self.found.mean()) if len(self.found) else float("nan")


def match_places(
    labels: LabelSet,
    affordance: str,
    skeletons: np.ndarray,
    xy_tolerance: float = XY_TOLERANCE,
    theta_tolerance: float = THETA_TOLERANCE,
) -> PlaceMatch:
    """Place-level matching (DESIGN.md, "Metrics") of predicted skeletons, (n, 3) rows of (x, y, theta)."""
    matches, ignored = place_matches(labels, affordance, skeletons, xy_tolerance, theta_tolerance)
    return PlaceMatch(labels.of(affordance), matches.any(axis=1), ~matches.any(axis=0) & ~ignored, ignored)


def place_matches(
    labels: LabelSet,
    affordance: str,
    skeletons: np.ndarray,
    xy_tolerance: float = XY_TOLERANCE,
    theta_tolerance: float = THETA_TOLERANCE,
) -> tuple[np.ndarray, np.ndarray]:
    """(n_labels, n_skeletons) bool: which skeleton (x, y, theta) matches which label of the affordance, and
    (n_skeletons,) bool: which skeletons lie in an unlabelled region (they match nothing)."""
    skeletons = np.asarray(skeletons, dtype=np.float64).reshape(-1, 3)
    ignored = labels.unlabelled(skeletons[:, :2])
    chosen = labels.of(affordance)
    matches = np.zeros((len(chosen), len(skeletons)), dtype=bool)
    for i, label in enumerate(chosen):
        matches[i] = (
            (label.distance(skeletons[:, :2]) <= xy_tolerance + _SLACK)
            & (angle_gap(skeletons[:, 2], label.facing) <= theta_tolerance + _SLACK)
            & ~ignored
        )
    return matches, ignored


# ---------------------------------------------------------------------------------------------- plot


def affordance_colours(names: list[str] | set[str]) -> dict[str, tuple]:
    """A colour per affordance from the sorted names (tab10, then tab20 beyond ten)."""
    import matplotlib

    ordered = sorted(names)
    cmap = matplotlib.colormaps["tab10" if len(ordered) <= 10 else "tab20"]
    return {name: cmap(i % cmap.N) for i, name in enumerate(ordered)}
