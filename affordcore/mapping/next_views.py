"""Where to look next: camera poses from which a robot still mapping a room would see most of what its maps
are unsure of.

A partial view misses places because their body space was never seen: a chair behind a table, a sofa's far
end. The fields' visibility states (`geometry.visibility`) say which voxels were never seen, and the place
model says how likely each candidate place is. A candidate whose probability is near 0.5 is the one a look
would settle, so each candidate weighs its binary entropy H(p) (1 bit at p = 0.5, none at 0 or 1), shared out
over the voxels of its body space (`VisibilitySettings.seen_radius`, `seen_low` ... `seen_high`); the
never-seen ones among them are the targets. A view's gain is the weight of the targets it would see, in
bits: a candidate whose whole body space is unknown, seen whole, gives H(p).

Views stand where the robot can: nothing occupied within the robot's footprint up to the camera, and most
of that space seen free (`_standable`; `NextViewSettings`), on a grid of `step`, each at `headings` headings.
A target is seen when it lies within the camera's range and field of view and no occupied voxel stands on the
line to it. Unknown voxels on the line count as clear: what hides behind them is what the view finds out.
Views are
chosen greedily, each counting only the targets the ones before it do not see.

What each position sees is one compiled pass over its (position, target) pairs (`sight_lines`): a line of
sight is marched only until its first occupied voxel, and a target's azimuth, kept per pair, says which
headings see it, so memory grows with positions x targets and never with the headings.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..geometry.fields import SceneFields, disc
from ..settings import NextViewSettings, Settings, VisibilitySettings

# a candidate's body space is sampled every this many voxels along each axis (20 cm on 10 cm voxels): what a
# camera sees of a body-sized space changes little within that, and the work falls eightfold
_TARGET_STRIDE = 2
_PLACES = 24  # the candidates a look would settle most (by their bits) are the ones targeted
_SEEN_FREE = 0.5  # of a column a robot may stand in, at least this share was seen free
_MIN_GAIN = 0.01  # bits: a view that would tell less is not worth the drive
_UNSEEN_STRIDE = 3  # the never-seen space no candidate stands in is sampled every 3 voxels (30 cm)
_UNSEEN_TARGETS = 1500  # ... and at most this many samples (a line-of-sight test each, from every position)
DRAWN_LOOKS = 3  # a view's places a plan draws a line to: the ones it settles most (more hide the plan)


@dataclass
class NextView:
    """A camera pose (its position, world frame, and heading about z) and what it would tell."""

    x: float
    y: float
    z: float
    heading: float  # radians, 0 along +x
    gain: float  # bits: the entropy of candidate places it would settle (`next_views`)
    places: list[int]  # the candidates it would look at (their indices), most gained first
    looks_at: np.ndarray  # (len(places), 3): their x, y and probability
    affordances: list[str] = field(default_factory=list)  # each place's affordance (`suggest_views`)

    def pose(self) -> np.ndarray:
        """world_from_view (4 x 4): at the camera, turned by the heading about z (x forward, z up)."""
        from ..geometry.skeleton import rotation_z

        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = rotation_z(self.heading), (self.x, self.y, self.z)
        return pose

    def to_json(self) -> dict:
        looks = [
            {"x": round(float(x), 3), "y": round(float(y), 3), "probability": round(float(p), 4)}
            for x, y, p in self.looks_at
        ]
        for look, affordance in zip(looks, self.affordances):
            look["affordance"] = affordance
        return {
            "x": round(self.x, 3),
            "y": round(self.y, 3),
            "z": round(self.z, 3),
            "heading": round(self.heading, 4),
            "gain": round(self.gain, 4),
            "looks_at": looks,
        }


def suggest_views(fields: SceneFields, maps, settings: Settings) -> list[NextView]:
    """Up to `settings.next_views.count` views, best first, for the candidate places of `maps` (affordance
    maps of these fields) together: one robot's views over every affordance, or one map's own. None when the
    count is 0 or the fields carry no visibility (no sensor positions). Each view names the affordance of
    each place it would look at."""
    wanted, maps = settings.next_views, [amap for amap in maps if len(amap.candidates)]
    if not wanted.count or fields.visibility is None or not (maps or wanted.unseen_prior):
        return []
    # no candidate yet: the views look where places may hide (the unseen prior's space)
    candidates = np.concatenate([amap.candidates for amap in maps]) if maps else np.zeros((0, 6))
    names = [amap.affordance for amap in maps for _ in range(len(amap.candidates))]
    views = next_views(fields, candidates[:, :2], candidates[:, 5], wanted.count, wanted, settings.visibility)
    for view in views:
        view.affordances = [names[index] for index in view.places]
    return views


def entropy_bits(p: np.ndarray) -> np.ndarray:
    """Binary entropy of probabilities, in bits (0 at 0 and 1)."""
    p = np.clip(np.asarray(p, dtype=np.float64), 1e-12, 1 - 1e-12)
    return -(p * np.log2(p) + (1 - p) * np.log2(1 - p))


def next_views(
    fields: SceneFields,
    candidates: np.ndarray,
    probabilities: np.ndarray,
    count: int,
    settings: NextViewSettings | None = None,
    body: VisibilitySettings | None = None,
    height: float | None = None,
) -> list[NextView]:
    """Up to `count` views, best first, for candidate places at (x, y) (`candidates`, (k, >= 2)) of the given
    probabilities (NaN, from a model without a place model: taken as 0.5). `height`: the camera's above the
    floor (default `settings.height`). ValueError when the fields carry no visibility (no sensor positions:
    nothing tells unknown space from free)."""
    settings, body = settings or NextViewSettings(), body or VisibilitySettings()
    if fields.visibility is None:
        raise ValueError("next views need the sensor positions: without them unknown space cannot be told")
    targets, owner, weight = view_targets(fields, candidates, probabilities, settings, body)
    eye_z = settings.height if height is None else height  # the fields are levelled: the floor at z = 0
    positions = _standable(fields, settings, eye_z)
    if not len(targets) or not len(positions) or count < 1:
        return []
    from .sight_lines import seen_from, view_gains

    eyes = np.column_stack([positions, np.full(len(positions), eye_z)])
    azimuths = _azimuths(fields, eyes, targets, settings)  # (positions, targets), NaN where unseen
    half_fov = np.radians(settings.fov_horizontal_deg) / 2
    gains = np.zeros((len(eyes), settings.headings))
    seen = np.zeros(len(targets), bool)
    remaining, views = weight.astype(np.float64), []
    for _ in range(count):
        view_gains(azimuths, remaining, settings.headings, half_fov, gains)
        p, h = np.unravel_index(int(np.argmax(gains)), gains.shape)
        if gains[p, h] < _MIN_GAIN:
            break
        seen_from(azimuths[p], h, settings.headings, half_fov, seen)
        seen &= remaining > 0
        of_place = seen & (owner >= 0)
        per_place = np.bincount(owner[of_place], weights=remaining[of_place], minlength=len(candidates))
        places = [int(i) for i in np.argsort(-per_place, kind="stable") if per_place[i] > 0]
        looks_at = np.column_stack([candidates[places, :2], probabilities[places]])
        heading = 2 * np.pi * h / settings.headings
        views.append(NextView(*map(float, eyes[p]), float(heading), float(gains[p, h]), places, looks_at))
        remaining[seen] = 0.0
    return views


def seen_by_view(
    fields: SceneFields, eye: np.ndarray, heading: int, targets: np.ndarray, settings: NextViewSettings
) -> np.ndarray:
    """(targets,) bool: which of the points the camera at `eye`, turned to heading number `heading` of
    `settings.headings`, would see, as the views count them."""
    from .sight_lines import seen_from

    azimuths = _azimuths(fields, np.asarray(eye, np.float64)[None], targets, settings)
    seen = np.zeros(len(targets), bool)
    seen_from(azimuths[0], heading, settings.headings, np.radians(settings.fov_horizontal_deg) / 2, seen)
    return seen


def compile_sight_lines() -> None:
    """Compile the views' kernels now (or read them from numba's cache) with the argument types
    `next_views` passes, so that a service's first views do not wait."""
    from ..geometry.visibility import OCCUPIED
    from .sight_lines import seen_from, sight_azimuths, view_gains

    eyes, targets = np.zeros((1, 3)), np.ones((1, 3))
    azimuths = np.empty((1, 1), np.float32)
    ranges, elevations = np.array([0.0, 5.0]), np.array([-1.0, 1.0])
    sight_azimuths(
        eyes, targets, np.zeros((2, 2, 2), np.uint8), np.zeros(3), 0.1, OCCUPIED, ranges, elevations, azimuths
    )
    view_gains(azimuths, np.ones(1), 4, 0.5, np.zeros((1, 4)))
    seen_from(azimuths[0], 0, 4, 0.5, np.zeros(1, bool))


def _floor_layer(fields: SceneFields) -> int:
    """The voxel layer of the floor: the world frame's z = 0 (a few points of noise below it are no floor)."""
    lattice = fields.lattice
    return int(np.clip(np.rint(-lattice.origin[2] / lattice.resolution), 0, lattice.shape[2] - 1))


def _body_band(fields: SceneFields, body: VisibilitySettings) -> np.ndarray:
    """The voxel layers of a body's space above the floor (`seen_low` ... `seen_high`)."""
    lattice = fields.lattice
    layers = np.arange(lattice.shape[2])
    heights = (layers - _floor_layer(fields)) * lattice.resolution
    return layers[(heights >= body.seen_low - 1e-9) & (heights <= body.seen_high + 1e-9)]


def view_targets(
    fields: SceneFields,
    candidates: np.ndarray,
    probabilities: np.ndarray,
    settings: NextViewSettings,
    body: VisibilitySettings,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What views would look at: (never-seen voxel centres (t, 3), the candidate each belongs to (-1: the
    unseen prior's), its weight in bits) of the `_PLACES` weightiest candidates at (x, y) of the given
    probabilities (NaN taken as 0.5), and of the never-seen body space no candidate stands in."""
    candidates = np.atleast_2d(np.asarray(candidates, dtype=np.float64))
    probabilities = np.where(np.isfinite(probabilities), probabilities, 0.5)
    bits = entropy_bits(probabilities)
    bits[np.argsort(-bits, kind="stable")[_PLACES:]] = 0.0
    targets, owner, weight = _targets(fields, candidates[:, :2], bits, body)
    if settings.unseen_prior > 0:  # the never-seen body space no candidate stands in: where places may hide
        unseen, unseen_weight = _unseen_targets(fields, body, settings.unseen_prior, targets)
        targets = np.concatenate([targets, unseen])
        owner = np.concatenate([owner, np.full(len(unseen), -1)])
        weight = np.concatenate([weight, unseen_weight])
    return targets, owner, weight


def _targets(
    fields: SceneFields, xy: np.ndarray, bits: np.ndarray, body: VisibilitySettings
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(the never-seen voxel centres of the candidates' body space (n, 3), each one's candidate, its weight:
    the candidate's bits over its body space's voxel count), on the body space's `_TARGET_STRIDE` lattice;
    candidates of no bits have none."""
    from ..geometry.visibility import UNKNOWN

    lattice, state = fields.lattice, fields.visibility
    res = lattice.resolution
    band = _body_band(fields, body)[::_TARGET_STRIDE]
    reach = int(round(body.seen_radius / res))
    di, dj = np.nonzero(disc(reach))
    di, dj = di - reach, dj - reach
    on_stride = (di % _TARGET_STRIDE == 0) & (dj % _TARGET_STRIDE == 0)
    di, dj = di[on_stride], dj[on_stride]
    xy = xy[bits > 0]
    bits, kept = bits[bits > 0], np.flatnonzero(bits > 0)
    centre = np.rint((xy - lattice.origin[:2]) / res).astype(int)  # (k, 2)
    ci = centre[:, :1] + di[None]  # (k, disc)
    cj = centre[:, 1:] + dj[None]
    inside = (ci >= 0) & (ci < lattice.shape[0]) & (cj >= 0) & (cj < lattice.shape[1])
    owner_col = np.broadcast_to(np.arange(len(xy))[:, None], ci.shape)[inside]
    ci, cj = ci[inside], cj[inside]
    voxels_per_place = np.bincount(owner_col, minlength=len(xy)) * len(band)
    unknown = state[ci[:, None], cj[:, None], band[None]] == UNKNOWN  # (columns, band)
    column, layer = np.nonzero(unknown)
    index = np.column_stack([ci[column], cj[column], band[layer]])
    owner = owner_col[column]
    weight = bits[owner] / np.maximum(voxels_per_place[owner], 1)
    return lattice.centres(index), kept[owner], weight


def _unseen_targets(
    fields: SceneFields, body: VisibilitySettings, prior: float, taken: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(never-seen voxel centres of the body band over the whole floor, each one's weight): a body space no
    candidate stands in holds a place with probability `prior`, so a body-sized volume of it seen whole is
    worth H(prior) bits. On a coarser lattice than the candidates' (`_UNSEEN_STRIDE`), at most
    `_UNSEEN_TARGETS` of them (spread evenly, their weights scaled to keep the total), so the views stay
    within a second; the candidates' own targets (`taken`) are not counted twice."""
    from scipy import ndimage

    from ..geometry.visibility import UNKNOWN

    lattice, state, res = fields.lattice, fields.visibility, fields.lattice.resolution
    band = _body_band(fields, body)[::_UNSEEN_STRIDE]
    grid = state[::_UNSEEN_STRIDE, ::_UNSEEN_STRIDE][:, :, band] == UNKNOWN
    index = np.argwhere(grid) * np.array([_UNSEEN_STRIDE, _UNSEEN_STRIDE, 1])
    index[:, 2] = band[index[:, 2]]
    if len(taken):  # a column within half a sample of a candidate's target is weighed by the candidate
        claimed = np.zeros(lattice.shape[:2], bool)
        column = np.rint((taken[:, :2] - lattice.origin[:2]) / res).astype(int)
        claimed[column[:, 0], column[:, 1]] = True
        reach = _UNSEEN_STRIDE // 2  # voxels: the sample's half-width, rounded down
        claimed = ndimage.binary_dilation(claimed, np.ones((2 * reach + 1,) * 2, bool))
        index = index[~claimed[index[:, 0], index[:, 1]]]
    centres = lattice.centres(index)
    # a body space: a disc of seen_radius on the band, in this lattice's samples
    per_body = max(1.0, np.pi * (body.seen_radius / (res * _UNSEEN_STRIDE)) ** 2 * len(band))
    weight = np.full(len(centres), float(entropy_bits(prior)) / per_body)
    if len(centres) > _UNSEEN_TARGETS:
        keep = np.linspace(0, len(centres) - 1, _UNSEEN_TARGETS).astype(int)
        weight = weight[keep] * (len(centres) / _UNSEEN_TARGETS)
        centres = centres[keep]
    return centres, weight


def _standable(fields: SceneFields, settings: NextViewSettings, eye_z: float) -> np.ndarray:
    """(n, 2) positions on the `step` grid where the robot can stand: nothing occupied from 15 cm above the
    floor up to the camera within `footprint` in plan, and most of the position's own column (`_SEEN_FREE`)
    seen free. Not all of it: a camera looking level never sees the space at its feet, nor the floor under
    its next stop, and a column looked through above the knee seldom hides anything below it."""
    from scipy import ndimage

    from ..geometry.visibility import FREE, OCCUPIED

    lattice, state = fields.lattice, fields.visibility
    res = lattice.resolution
    floor = _floor_layer(fields)
    top = min(int(np.ceil((eye_z - lattice.origin[2]) / res)), lattice.shape[2] - 1)
    # from two layers up: the floor's own points spill into the layer above it (noise, a rug, a threshold),
    # which a robot crosses
    column = state[:, :, floor + 2 : top + 1]
    obstacle = (column == OCCUPIED).any(axis=2)
    reach = int(np.ceil(settings.footprint / res))
    if reach:  # obstacles grown by the robot's radius, as a planner's costmap inflates them
        obstacle = ndimage.binary_dilation(obstacle, disc(reach))
    clear = ~obstacle & ((column == FREE).mean(axis=2) >= _SEEN_FREE)
    stride = max(1, int(round(settings.step / res)))
    keep = np.zeros_like(clear)
    keep[::stride, ::stride] = True
    i, j = np.nonzero(clear & keep)
    return lattice.origin[:2] + np.column_stack([i, j]) * res


def _azimuths(
    fields: SceneFields, eyes: np.ndarray, targets: np.ndarray, settings: NextViewSettings
) -> np.ndarray:
    """(positions, targets) float32: the azimuth of each target from each eye where the camera there could
    see it (within range and the vertical field of view, no occupied voxel on the line), else NaN; which
    headings see it is the horizontal field's business (`sight_lines.heading_span`)."""
    from ..geometry.visibility import OCCUPIED
    from .sight_lines import sight_azimuths

    lattice = fields.lattice
    half = settings.fov_vertical_deg / 2
    elevations = np.radians([settings.pitch_deg - half, settings.pitch_deg + half])
    out = np.empty((len(eyes), len(targets)), np.float32)
    sight_azimuths(
        np.ascontiguousarray(eyes, np.float64),
        np.ascontiguousarray(targets, np.float64),
        fields.visibility,
        np.asarray(lattice.origin, np.float64),
        float(lattice.resolution),
        OCCUPIED,
        np.array([settings.min_range, settings.max_range]),
        elevations,
        out,
    )
    return out
