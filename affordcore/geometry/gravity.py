"""Gravity alignment: bring a cloud into the world frame of DESIGN.md (metres, z up, floor at z = 0).

Automatic alignment does not know which way the input frame is up. It tries each candidate axis
(by default +z for z-up scans, +y for y-up scans, -y for camera frames with y down) and, for each, looks for
a floor: a plane among the lowest points, leaning at most ``max_tilt_deg`` from that axis, found by RANSAC.
A candidate's floor is *valid* when it covers at least ``min_floor_area`` and almost nothing lies under it
(walls fail here: doors, windows and scan noise put points behind them). Where the cloud knows where its
sensor stood (`origins`), a floor must also lie under the sensor at a height a sensor is carried at
(`sensor_heights`): a wall a few frames saw from across the room does not. Among valid floors the one with the
strongest floor evidence wins (`_judge_floor`: furniture tops above it, the plane's own extent, and
nothing behind it). No valid floor is an error (`NoFloorError`) that says, per candidate, why it failed: a
wrong frame is worse than no frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..settings import GravitySettings
from .scene import voxel_thin

_BELOW_MARGIN = 0.05  # a point this far under a floor plane is "below the floor"
_AREA_CELL = 0.10  # floor area is counted in cells of this size
_HORIZONTAL_COS = 0.9  # a surface whose normal is within ~25 deg of up counts as horizontal
# two candidate floors whose normals are this close to opposite and whose planes are at least this far apart
# (m) are a floor and the ceiling over it (nearer, the upper one is something's top: a workbench seen from a
# walk, whose floor is what stands under it)
_OPPOSITE_COS = 0.9
_ROOM_HEIGHT = 1.8
_FURNITURE_BOTTOM = 0.15  # horizontal surfaces from this height ... (m)
_FURNITURE_TOP = 1.3  # ... up to this one count as furniture tops for a floor's evidence (m)
# How the evidence weighs the plane's own points and the points under it against furniture tops: fitted (a
# pairwise logistic regression, rounded) to which candidate is the floor in generated rooms of every scan
# style, each in three frames (docs/geometry.md; benchmarks/studies/does_gravity_alignment_find_up.py
# measures the choice)
_ON_PLANE_WEIGHT = 0.4
_BELOW_WEIGHT = 25.0
_REFITS = 10  # least-squares refits of the RANSAC plane, at most
_JUDGES = 20_000  # points that rank RANSAC hypotheses, and that the floor evidence is taken over
_DESCENTS = 3  # at most this many times a floor is looked for under a plane with points below it
_LEVEL_SLAB = 0.25  # check_levelled looks for the floor among points this close to z = 0 (m)
# check_levelled lets a floor be half as big and have twice as much under it as the search that levels a
# cloud does: its own sample of the same map falls either side of those limits when the leveller's was close
_CHECK_SLACK = 2.0
_PATCH_INTERIOR = 0.05  # a floor patch has at least this much inside it (m^2; `_interior_area`)

AXES = {
    "+x": (1, 0, 0),
    "-x": (-1, 0, 0),
    "+y": (0, 1, 0),
    "-y": (0, -1, 0),
    "+z": (0, 0, 1),
    "-z": (0, 0, -1),
}


class NoFloorError(ValueError):
    """No floor plane that could define the world frame."""


@dataclass
class FloorCandidate:
    axis: str
    valid: bool
    reason: str
    normal: np.ndarray | None = None
    offset: float = 0.0
    tilt_deg: float = float("nan")
    area: float = 0.0
    below_fraction: float = float("nan")
    score: float = float("nan")  # `_judge_floor`'s floor evidence; scored only when several floors are valid
    tops: float = float("nan")  # `_judge_floor`'s share of points on furniture tops above it (likewise)
    patch: bool = False  # not valid for its area alone, and at least `min_patch_area`: a less sure floor


@dataclass
class Alignment:
    """What was done to a cloud: the transform and the evidence for it."""

    world_from_input: np.ndarray
    method: str  # "auto", "gravity", "none"
    up_axis: str  # the input axis taken as up, or "given" for a gravity vector
    tilt_deg: float  # angle between the floor's normal and that axis
    floor_offset: float  # where the floor was along the up direction in the input frame (m)
    floor_area: float = 0.0
    candidates: list[FloorCandidate] = field(default_factory=list)
    floor_note: str = ""  # why the floor is less sure than a search's usual floor ("": it is not)

    def describe(self) -> str:
        if self.method == "none":
            return "no gravity alignment (the cloud is taken as z-up with the floor at z = 0)"
        how = f"up = input {self.up_axis}" if self.method == "auto" else "up = against the given gravity"
        return (
            f"gravity alignment ({self.method}): {how}{self._runners_up()}, floor tilted "
            f"{self.tilt_deg:.2f} deg from it, floor at {self.floor_offset:+.3f} m moved to z = 0, "
            f"floor area {self.floor_area:.2f} m^2" + (f" ({self.floor_note})" if self.floor_note else "")
        )

    def _runners_up(self) -> str:
        """What else passed for a floor, and by how much the chosen one won (its evidence, then each other
        valid candidate's), when any did: a close call on a partial scan is worth knowing (a wall can pass
        for a floor; --gravity settles it)."""
        chosen = [c for c in self.candidates if c.valid and c.axis == self.up_axis]
        others = [c for c in self.candidates if c.valid and c.axis != self.up_axis]
        if self.method != "auto" or not chosen or not others:
            return ""
        over = ", ".join(f"{c.axis}'s {c.score:.2f}" for c in sorted(others, key=lambda c: -c.score))
        return f" (floor evidence {chosen[0].score:.2f}, over {over})"

    def as_dict(self) -> dict:
        return {
            "method": self.method,
            "up_axis": self.up_axis,
            "tilt_deg": round(self.tilt_deg, 4),
            "floor_offset": round(self.floor_offset, 4),
            "floor_area": round(self.floor_area, 2),
            "floor_note": self.floor_note,
            "world_from_input": self.world_from_input.round(9).tolist(),
        }


def align_to_gravity(
    points: np.ndarray,
    gravity: str | np.ndarray | None = "auto",
    settings: GravitySettings | None = None,
    origins: np.ndarray | None = None,
) -> Alignment:
    """Find the transform to the z-up, floor-at-zero world frame.

    ``gravity``: "auto" (search the candidate axes), "none" or None (the cloud is already aligned), or a
    3-vector pointing down in the input frame (the floor height is still found from the cloud). ``origins``
    (M, 3): where the sensor stood, in the points' frame, if known; the search keeps only floors under it.
    """
    settings = settings or GravitySettings()
    if gravity is None or (isinstance(gravity, str) and gravity == "none"):
        return Alignment(np.eye(4), "none", "+z", 0.0, 0.0)
    sample = voxel_thin(points, settings.sample_voxel)[0]
    if isinstance(gravity, str):
        if gravity != "auto":
            raise ValueError(f"gravity must be 'auto', 'none' or a vector, not {gravity!r}")
        return _auto(sample, settings, origins)
    down = np.asarray(gravity, dtype=np.float64).reshape(3)
    if not np.isfinite(down).all() or np.linalg.norm(down) < 1e-9:
        raise ValueError(f"gravity vector {down.tolist()} has no direction")
    up = -down / np.linalg.norm(down)
    # Trust the given direction; only the floor's height comes from the cloud.
    strict = settings.model_copy(update={"max_tilt_deg": min(settings.max_tilt_deg, 10.0)})
    candidate = _find_floor(sample, up, "given", strict, descend=True)
    if origins is not None and len(origins) and (candidate.valid or candidate.patch):
        _check_sensor_height(candidate, origins, settings)
    if not (candidate.valid or candidate.patch):
        raise NoFloorError(
            f"no floor found under the given gravity {down.round(4).tolist()}: {candidate.reason}. "
            + _what_to_pass(settings)
        )
    on_floor = np.abs(sample @ candidate.normal - candidate.offset) < settings.ransac_threshold
    offset = float(np.median(sample[on_floor] @ up))
    return Alignment(
        _world_from(up, offset),
        "gravity",
        "given",
        candidate.tilt_deg,
        offset,
        candidate.area,
        [candidate],
        _patch_note(candidate, settings),
    )


def _patch_note(candidate: FloorCandidate, settings: GravitySettings) -> str:
    """What a floor taken from a patch says of itself ("" for a floor of the usual area)."""
    if candidate.valid:
        return ""
    return (
        f"less sure: the lowest plane, {candidate.area:.2f} m^2 with almost nothing under it, under "
        f"{settings.min_floor_area:g} m^2 of floor"
    )


def _what_to_pass(settings: GravitySettings) -> str:
    return (
        "A cloud already levelled (z up, floor at z = 0) maps with --gravity none; otherwise scan more of "
        f"the floor (at least {settings.min_patch_area:g} m^2 of it in one plane)"
    )


def check_levelled(
    points: np.ndarray,
    settings: GravitySettings | None = None,
    tolerance: float = 0.05,
    max_tilt: float = 15.0,
) -> float:
    """A cloud said to be in the world frame has its floor at z = 0: a plane among the points near z = 0,
    within `max_tilt` degrees of level, whose points lie within `tolerance` m of z = 0 at their median, that
    covers a floor's area and has almost nothing under it (the floor search's limits, with slack). Returns its
    area; raises `NoFloorError` saying what is wrong (a cloud with its floor elsewhere would be scored
    against air and come back as empty maps, which looks like an answer).

    It tests that one hypothesis rather than searching for the floor afresh: a map levelled from a drifting
    walk has its floor smeared over decimetres, and a new search (which descends through planes with points
    under them) can settle on a different patch of it than the search that levelled the map did (the
    assembler's own maps were refused one time in three). The slab is wide enough for a floor tilted a few
    degrees across a room (an IMU-levelled map can show 5 deg) and too thin for seats (0.4 m)."""
    settings = settings or GravitySettings()
    strict = settings.model_copy(update={"max_tilt_deg": max_tilt})
    sample = voxel_thin(points, settings.sample_voxel)[0]
    up = np.array([0.0, 0.0, 1.0])
    slab = sample[np.abs(sample[:, 2]) < _LEVEL_SLAB]
    plane = _ransac_plane(slab, up, strict, np.random.default_rng(settings.seed))
    if plane is None:
        problem = f"no plane within {max_tilt:g} deg of level lies within {_LEVEL_SLAB:g} m of z = 0"
    else:
        normal, inliers = plane
        height = float(np.median(slab[inliers, 2]))
        area = _area(slab[inliers], normal)
        below = float(np.mean(sample @ normal - np.median(slab[inliers] @ normal) < -_BELOW_MARGIN))
        problem = ""
        if abs(height) > tolerance:
            problem = (
                f"its largest level plane near z = 0 is at z = {height:+.2f} m (at most {tolerance:g} m)"
            )
        elif area < settings.min_floor_area / _CHECK_SLACK:
            problem = f"the level plane at z = {height:+.2f} m covers only {area:.2f} m^2"
        elif below > settings.max_below_fraction * _CHECK_SLACK:
            problem = f"{below:.1%} of the points lie under the level plane at z = {height:+.2f} m"
        if not problem:
            return area
    raise NoFloorError(
        f"a 'world' cloud has its floor at z = 0, but {_where_the_floor_is(sample, settings)} ({problem}). "
        "Send it in its own frame (any frame_id but 'world') and it is levelled for you"
    )


def _where_the_floor_is(sample: np.ndarray, settings: GravitySettings) -> str:
    """What a floor search under gravity -z makes of a cloud, for an error message."""
    floor = _find_floor(sample, np.array([0.0, 0.0, 1.0]), "+z", settings, descend=True)
    if not floor.valid:
        return f"no floor found under gravity -z ({floor.reason})"
    return f"its floor is at z = {floor.offset:+.2f} m, tilted {floor.tilt_deg:.1f} deg"


def _auto(sample: np.ndarray, settings: GravitySettings, origins: np.ndarray | None = None) -> Alignment:
    candidates = []
    # where the sensor stood tells a wall from a floor, so a candidate may descend under the tops it sees
    known = origins is not None and len(origins) > 0
    for axis in settings.up_candidates:
        if axis not in AXES:
            raise ValueError(f"unknown up candidate {axis!r}; use one of {', '.join(AXES)}")
        candidates.append(_find_floor(sample, np.array(AXES[axis], float), axis, settings, descend=known))
        if known:
            _check_sensor_height(candidates[-1], origins, settings)
    valid = [c for c in candidates if c.valid]
    if not valid and known:  # a patch under where the sensor stood: less sure, but a single frame's floor
        valid = [c for c in candidates if c.patch]
    if not valid:
        reasons = "; ".join(f"{c.axis}: {c.reason}" for c in candidates)
        raise NoFloorError(
            f"no floor found ({reasons}). Give the gravity direction explicitly if the floor is not in view."
        )
    if len(valid) > 1:  # the evidence only chooses between valid floors: normals only then
        _judge_floors(sample, valid, settings)
    best = max(valid, key=lambda c: c.score)
    # A floor and the ceiling over it are both wide planes with nothing beyond them, and the ceiling, which no
    # furniture hides, is often the wider (a third of a laser scan's points): between the two, the floor is
    # the one furniture stands on (docs/geometry.md)
    best = max([best, *_ends_of_a_room(best, valid)], key=lambda c: c.tops)
    return Alignment(
        _world_from(best.normal, best.offset),
        "auto",
        best.axis,
        best.tilt_deg,
        best.offset,
        best.area,
        candidates,
        _patch_note(best, settings),
    )


def _check_sensor_height(candidate: FloorCandidate, origins: np.ndarray, settings: GravitySettings) -> None:
    """Rule out a valid candidate the sensor does not stand over at a height it can be carried at (the median
    of its positions' heights above the plane: a walk's few low or high frames do not decide)."""
    if not (candidate.valid or candidate.patch):
        return
    height = float(np.median(origins @ candidate.normal - candidate.offset))
    low, high = settings.sensor_heights
    if not low <= height <= high:
        candidate.valid = candidate.patch = False
        candidate.reason = (
            f"the sensor would stand {height:+.2f} m over it (a floor lies {low:g}-{high:g} m under it)"
        )


def _ends_of_a_room(floor: FloorCandidate, candidates: list[FloorCandidate]) -> list[FloorCandidate]:
    """The candidates facing the other way at least a room's height from `floor`: the other end of its room,
    if `floor` is a floor or a ceiling."""
    return [
        c
        for c in candidates
        if c.normal @ floor.normal < -_OPPOSITE_COS and abs(c.offset + floor.offset) >= _ROOM_HEIGHT
    ]


def _find_floor(
    sample: np.ndarray,
    up: np.ndarray,
    axis: str,
    settings: GravitySettings,
    descend: bool = False,
) -> FloorCandidate:
    heights = sample @ up
    band = sample[heights <= np.quantile(heights, settings.lowest_fraction)]
    rng = np.random.default_rng(settings.seed)
    plane = _ransac_plane(band, up, settings, rng)
    if plane is None:
        return FloorCandidate(
            axis, False, f"no plane within {settings.max_tilt_deg:g} deg of {axis} among the lowest points"
        )
    normal, inliers = plane
    offset = float(np.median(band[inliers] @ normal))
    for _ in range(_DESCENTS if descend else 0):
        # A room seen by a few frames can show more seat and table tops than floor: when the biggest plane
        # has points under it, look for the lowest plane among those. Only under a known gravity or a known
        # sensor position: otherwise, on a wrong candidate axis, the points under a wall are what tells it is
        # a wall (the sensor stands further from a wall than from a floor: `_check_sensor_height`).
        lower = band[band @ normal - offset < -_BELOW_MARGIN]
        if (
            np.mean(sample @ normal - offset < -_BELOW_MARGIN) <= settings.max_below_fraction
            or len(lower) < 100
        ):
            break
        plane = _ransac_plane(lower, up, settings, rng)
        if plane is None:
            break
        band = lower
        normal, inliers = plane
        offset = float(np.median(band[inliers] @ normal))
    tilt = float(np.degrees(np.arccos(np.clip(normal @ up, -1, 1))))
    area = _area(band[inliers], normal)
    height = sample @ normal - offset
    below = float(np.mean(height < -_BELOW_MARGIN))
    candidate = FloorCandidate(axis, True, "ok", normal, offset, tilt, area, below)
    if area < settings.min_floor_area:
        candidate.valid, candidate.reason = False, f"lowest plane covers only {area:.2f} m^2"
        candidate.patch = (
            area >= settings.min_patch_area
            and below <= settings.max_below_fraction
            and _interior_area(band[inliers], normal) >= _PATCH_INTERIOR
        )
    elif below > settings.max_below_fraction:
        candidate.valid, candidate.reason = (
            False,
            f"{below:.1%} of the points lie under the lowest plane (a wall?)",
        )
    return candidate


def _judge_floors(sample: np.ndarray, candidates: list[FloorCandidate], settings: GravitySettings) -> None:
    """Each candidate floor's tops and floor evidence (`_judge_floor`), their surface shares taken over
    `_JUDGES` random points of a coarser copy of the sample (normals from all of its points): a share of
    points, which that many estimate to within +-0.011 (3 sigma), and normal estimation, most of an auto
    alignment when it runs, costs a sixth of what it costs at every point (0.5 s of CPU on a 10 m room's
    131,000 coarse points)."""
    coarse = voxel_thin(sample, 2 * settings.sample_voxel)[0]
    rng = np.random.default_rng(settings.seed)
    judges = np.sort(rng.choice(len(coarse), _JUDGES, replace=False)) if len(coarse) > _JUDGES else None
    normals = _estimate_normals(coarse, radius=4 * settings.sample_voxel, at=judges)
    points = coarse if judges is None else coarse[judges]
    for candidate in candidates:
        _judge_floor(candidate, points, normals)


def _judge_floor(candidate: FloorCandidate, points: np.ndarray, point_normals: np.ndarray) -> None:
    """Set a valid candidate's `tops`, the share of points on surfaces parallel to it at furniture height
    above it (seats, tables, counters), and its `score`, how much it looks like the floor: those tops, plus a
    lesser share for the plane itself, less a heavy one for the points under it. A wall seen by a few frames
    can show more of itself, and more surfaces parallel to it (cabinet fronts, a sofa's back), than the floor
    does, and by horizontal surface alone it often won (docs/geometry.md has how often). What gives it away
    is what lies behind it (a door, a window, a room beyond), counted at its candidate's `below_fraction`."""
    parallel = np.abs(point_normals @ candidate.normal) > _HORIZONTAL_COS
    level = points @ candidate.normal - candidate.offset
    candidate.tops = float(np.mean(parallel & (level > _FURNITURE_BOTTOM) & (level < _FURNITURE_TOP)))
    plane = np.mean(parallel & (np.abs(level) < _BELOW_MARGIN))
    candidate.score = float(
        candidate.tops + _ON_PLANE_WEIGHT * plane - _BELOW_WEIGHT * candidate.below_fraction
    )


def _ransac_plane(
    points: np.ndarray, up: np.ndarray, settings: GravitySettings, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray] | None:
    """The plane with the most inliers among those leaning at most max_tilt from `up`, refined by least
    squares."""
    if len(points) < 3:
        return None
    min_cos = np.cos(np.radians(settings.max_tilt_deg))
    picks = rng.integers(0, len(points), size=(settings.ransac_iterations, 3))
    a, b, c = points[picks[:, 0]], points[picks[:, 1]], points[picks[:, 2]]
    normals = np.cross(b - a, c - a)
    lengths = np.linalg.norm(normals, axis=1)
    ok = lengths > 1e-9
    normals[ok] /= lengths[ok, None]
    normals *= np.sign(normals @ up)[:, None]
    ok &= normals @ up >= min_cos
    if not ok.any():
        return None
    normals, offsets = normals[ok], np.einsum("ij,ij->i", normals[ok], a[ok])
    # Hypotheses are counted on a random subset (the refits below use every point): 20,000 points rank
    # planes as well as 200,000 and the count was most of an alignment's time.
    judges = points if len(points) <= _JUDGES else points[rng.choice(len(points), _JUDGES, replace=False)]
    best_count, best = -1, 0
    # 64 planes x all judges at a time bounds memory; the distances are worked out in place in one buffer
    # (the arithmetic of a fresh array per step, without its allocation and page faults)
    distance = np.empty((len(judges), 64))
    inside = np.empty((len(judges), 64), dtype=bool)
    for start in range(0, len(normals), 64):
        n = min(64, len(normals) - start)
        block, near = distance[:, :n], inside[:, :n]
        np.matmul(judges, normals[start : start + n].T, out=block)
        np.subtract(block, offsets[start : start + n], out=block)
        np.less(np.abs(block, out=block), settings.ransac_threshold, out=near)
        counts = np.count_nonzero(near, axis=0)
        if counts.max() > best_count:
            best_count, best = int(counts.max()), start + int(counts.argmax())
    normal, offset = normals[best], offsets[best]
    # Refit until the inliers settle: one refit stays near whichever rough plane RANSAC drew, which on a
    # thick (noisy) floor moves the result by centimetres with the sampling order.
    for _ in range(_REFITS):
        inliers = np.abs(points @ normal - offset) < settings.ransac_threshold
        normal = _fit_normal(points[inliers], up)
        new_offset = float(np.median(points[inliers] @ normal))
        if abs(new_offset - offset) < 1e-4:
            break
        offset = new_offset
    inliers = np.abs(points @ normal - offset) < settings.ransac_threshold
    if normal @ up < min_cos:
        return None
    return normal, inliers


def _fit_normal(points: np.ndarray, up: np.ndarray) -> np.ndarray:
    centred = points - points.mean(axis=0)
    normal = np.linalg.svd(centred, full_matrices=False)[2][-1]
    return normal * np.sign(normal @ up)


def _plane_cells(points: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """(n, 2) indices of the `_AREA_CELL` cells of a plane its points fall in, counted from 0 in the plane."""
    flat = (points @ rotation_between(normal, np.array([0.0, 0.0, 1.0])).T)[:, :2]
    cells = np.floor(flat / _AREA_CELL).astype(np.int64)
    return cells - cells.min(axis=0) if len(cells) else cells


def _area(points: np.ndarray, normal: np.ndarray) -> float:
    cells = _plane_cells(points, normal)
    if len(cells) == 0:
        return 0.0
    # one key per cell: a 1-D unique, 5x faster than unique rows
    return len(np.unique(cells[:, 0] * (cells[:, 1].max() + 1) + cells[:, 1])) * _AREA_CELL**2


def _interior_area(points: np.ndarray, normal: np.ndarray) -> float:
    """The area of a plane's 10 cm cells whose eight neighbours hold its points too (m^2): a patch of floor
    has an inside; the strip or ring where walls meet a plane below the view has none."""
    from scipy.ndimage import binary_erosion

    cells = _plane_cells(points, normal)
    if len(cells) == 0:
        return 0.0
    grid = np.zeros(cells.max(axis=0) + 1, dtype=bool)
    grid[cells[:, 0], cells[:, 1]] = True
    return float(binary_erosion(grid, np.ones((3, 3), bool)).sum()) * _AREA_CELL**2


def _estimate_normals(points: np.ndarray, radius: float = 0.1, at: np.ndarray | None = None) -> np.ndarray:
    from .normals import pca_normals

    return pca_normals(points, radius, 30, at)


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking vector a onto vector b (half a turn when they are opposite)."""
    from scipy.spatial.transform import Rotation

    a = np.asarray(a, dtype=np.float64) / np.linalg.norm(a)
    b = np.asarray(b, dtype=np.float64) / np.linalg.norm(b)
    rotation, _ = Rotation.align_vectors([b], [a])  # one pair: the shortest rotation
    return rotation.as_matrix()


def _world_from(up: np.ndarray, floor_offset: float) -> np.ndarray:
    transform = np.eye(4)
    transform[:3, :3] = rotation_between(up, np.array([0.0, 0.0, 1.0]))
    transform[2, 3] = -floor_offset
    return transform
