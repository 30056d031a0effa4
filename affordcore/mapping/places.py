"""Places a robot can trust: each candidate place of a skeleton map gets a calibrated probability that a
person can use it, from place-level evidence rather than a raw score cut.

Why: a pose score is a ranking. Its scale moves with the scan (a five-frame Kinect capture, a mesh, a laser
scan each shift every score of a room together), so one absolute cut learned on some rooms throws away the
places of rooms scanned otherwise, and a cut relative to the room cannot say "nothing here". A place's
evidence is more than its peak: how far the peak stands above the rest of the room, how many poses and
orientations around it agree, and how much of its surroundings was scanned at all.

* candidates: greedy non-maximum suppression over the confidence map (each (x, y) cell's best score), best
  first, among every pose the model scored, `CANDIDATE_SPACING` apart (closer than places are: a place's best
  spot is the one whose evidence is best, not always the peak of its score); at most `PLACE_CANDIDATES` per
  room;
* evidence (`EVIDENCE`): one row per candidate, computed for all of them at once from the grid of scores;
* `PlaceModel`: logistic regression over the standardised evidence, fitted on the candidates of validation
  rooms (found a label or not); logistic regression is Platt's calibration with more inputs, so its output
  is a probability (benchmarks/accuracy.py draws its reliability diagram per scan style and on real rooms).

The skeleton map keeps, likeliest first, the candidates whose probability reaches the place model's `cut`
(or `map.place_probability` when set), each suppressing the others within `map.nms_radius` of it
(`choose_places`). The cut is chosen on the validation rooms (`learn.thresholds.place_cut`): a calibrated 0.5
when that keeps few enough false places, lower where a lower one still does, so the map reaches more places
of a kind whose evidence is weak without filling rooms with phantoms.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.grid import PoseGrid

RULED_OUT = np.finfo(np.float32).min  # the score of a pose that is not a candidate (maps.RULED_OUT)
PLACE_CANDIDATES = 80  # per room: far more than any room's places, few enough to stay cheap
# m between candidates: on the generated validation rooms, 0.25 m put a candidate on 130 of 149 labelled
# places against 117 at the skeleton map's 0.45 m (docs/maps.md)
CANDIDATE_SPACING = 0.25
SUPPORT_RADIUS = 0.3  # m: poses this near a peak count as its support (DESIGN's loose place tolerance)
SURROUNDINGS_RADIUS = 1.0  # m: a person's reach around the place, for how much of it was scanned
CENTRE_RADIUS = 0.2  # m: a place stands at the weighted centre of its strong poses this near its peak ...
CENTRE_MARGIN = 2.0  # ... those above the pose threshold and within this of the peak's score (`centred`)
EVIDENCE = (
    "score",  # the peak's own score
    "over_median",  # above the median score of the room's candidate poses
    "below_best",  # below the room's best score (0 for the best place)
    "rank",  # log(1 + the peak's rank among the room's candidates)
    "support",  # log(1 + poses within SUPPORT_RADIUS scoring above the model's pose threshold)
    "near_peak",  # log(1 + poses within SUPPORT_RADIUS scoring within 1 of the peak)
    "turns",  # share of orientations with a pose above the pose threshold within SUPPORT_RADIUS
    "scanned",  # share of the cells within SURROUNDINGS_RADIUS near scanned floor
)


@dataclass
class Candidates:
    """A room's candidate places, best first."""

    cells: np.ndarray  # (k, 2) grid cell (i, j)
    rows: np.ndarray  # (k, 5) x, y, z, theta, score of the cell's best pose
    evidence: np.ndarray  # (k, len(EVIDENCE))


def room_reference(scores: np.ndarray) -> float:
    """The median score of a room's candidate poses (0 when it has none): what a relative place threshold
    is counted from. A scan unlike the training rooms (fewer viewpoints, other noise) moves a room's scores
    together, the places with the rest; a threshold above this median moves with them."""
    live = scores[scores > RULED_OUT]
    return float(np.median(live)) if len(live) else 0.0


def best_slabs(scores: np.ndarray, grid: PoseGrid) -> tuple[np.ndarray, np.ndarray]:
    """(the confidence map: each (x, y) cell's best score over theta and z, (nx, ny); the (z, theta) slab that
    reached it, as a flat index z * n_theta + theta) of scores shaped like the grid."""
    nz, nt, nx, ny = grid.shape
    flat = scores.reshape(nz * nt, nx, ny)
    best = flat.argmax(axis=0)
    return np.take_along_axis(flat, best[None], axis=0)[0], best


def peak_cells(confidence: np.ndarray, grid: PoseGrid, floor: float, radius: float, limit: int) -> np.ndarray:
    """(k, 2) cells of the confidence map above `floor` kept by greedy non-maximum suppression, best first:
    the best cell is kept and every cell within `radius` of it suppressed, whatever its theta; at most
    `limit` (None: all). The loop is over places, each step one vectorised distance test."""
    cells = np.argwhere(confidence > floor)
    cells = cells[np.argsort(-confidence[cells[:, 0], cells[:, 1]], kind="stable")]
    xy = np.column_stack([grid.x[cells[:, 0]], grid.y[cells[:, 1]]])
    return cells[suppress(xy, radius, limit)].reshape(-1, 2)


def suppress(xy: np.ndarray, radius: float, limit: int | None = None) -> np.ndarray:
    """Greedy non-maximum suppression of points (k, 2) sorted best first: indices of the kept ones, each
    suppressing the later ones within `radius` of it; at most `limit` (None: all)."""
    chosen, alive = [], np.ones(len(xy), dtype=bool)
    while alive.any() and (limit is None or len(chosen) < limit):
        first = int(np.argmax(alive))
        chosen.append(first)
        alive &= np.hypot(*(xy - xy[first]).T) > radius
    return np.array(chosen, dtype=np.int64)


def place_candidates(
    scores: np.ndarray,
    grid: PoseGrid,
    threshold: float,
    nms_radius: float,
    scanned: np.ndarray | None = None,
    limit: int = PLACE_CANDIDATES,
) -> Candidates:
    """The room's candidate places and their evidence. `scores` (z, theta, x, y) as mapped (RULED_OUT where
    not scored), `threshold` the model's pose threshold, `scanned` (nx, ny): the cells the sensor saw (None:
    every cell)."""
    confidence, best = best_slabs(scores, grid)
    nt = grid.shape[1]
    cells = peak_cells(confidence, grid, RULED_OUT, nms_radius, limit)
    i, j = cells[:, 0], cells[:, 1]
    rows = np.column_stack(
        [grid.x[i], grid.y[j], grid.z[best[i, j] // nt], grid.theta[best[i, j] % nt], confidence[i, j]]
    )
    evidence = _evidence(scores, confidence, cells, grid, threshold, scanned)
    return Candidates(cells, centred(scores, grid, cells, rows, threshold), evidence)


def centred(
    scores: np.ndarray, grid: PoseGrid, cells: np.ndarray, rows: np.ndarray, threshold: float
) -> np.ndarray:
    """The candidates' rows (x, y, z, theta, score) with x, y and theta moved to the score-weighted centre of
    the poses within `CENTRE_RADIUS` of each peak that score above the pose threshold and within
    `CENTRE_MARGIN` of the peak (theta by a weighted circular mean; z and the score stay the peak's). Why:
    a place's strong poses form a plateau whose argmax lands anywhere on it, often at its rim, 0.15-0.25 m or
    0.4-0.6 rad from where the person is, beyond a place's tolerance; the plateau's centre is nearer
    (measured in docs/maps.md). A peak with no such pose keeps its cell."""
    if not len(cells):
        return rows
    di, dj = _disc(grid.step, CENTRE_RADIUS)
    near = _window(scores, cells, grid.step, CENTRE_RADIUS).astype(np.float64)  # (z, theta, k, disc)
    floor = np.maximum(threshold, rows[:, 4] - CENTRE_MARGIN)
    weight = np.clip(near - floor[None, None, :, None], 0.0, None)
    over_cells, over_turns = weight.sum(axis=(0, 1)), weight.sum(axis=(0, 3))  # (k, disc), (theta, k)
    total = over_cells.sum(axis=1)
    moved = total > 0
    out = rows.copy()
    shift = (
        np.column_stack([over_cells @ di, over_cells @ dj]) * grid.step / np.maximum(total, 1e-300)[:, None]
    )
    out[moved, :2] += shift[moved]
    sine, cosine = np.sin(grid.theta) @ over_turns, np.cos(grid.theta) @ over_turns
    out[moved, 3] = np.mod(np.arctan2(sine, cosine), 2 * np.pi)[moved]
    return out


def _evidence(scores, confidence, cells, grid: PoseGrid, threshold: float, scanned) -> np.ndarray:
    peak = confidence[cells[:, 0], cells[:, 1]].astype(np.float64)
    median = room_reference(scores)
    best = float(peak.max()) if len(peak) else 0.0
    near = _window(scores, cells, grid.step, SUPPORT_RADIUS)  # (z, theta, k, disc)
    scanned_map = np.ones(confidence.shape, bool) if scanned is None else scanned
    surroundings = _window(scanned_map, cells, grid.step, SURROUNDINGS_RADIUS, fill=False)
    return np.column_stack(
        [
            peak,
            peak - median,
            peak - best,
            np.log1p(np.arange(len(cells))),
            np.log1p((near > threshold).sum(axis=(0, 1, 3))),
            np.log1p((near > peak[:, None] - 1.0).sum(axis=(0, 1, 3))),
            (near > threshold).any(axis=(0, 3)).mean(axis=0),
            surroundings.mean(axis=-1),
        ]
    ).reshape(-1, len(EVIDENCE))


def _disc(step: float, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """The cell offsets (di, dj) of a disc of `radius` on a grid of `step`."""
    reach = int(np.floor(radius / step + 1e-9))
    di, dj = np.mgrid[-reach : reach + 1, -reach : reach + 1].reshape(2, -1)
    inside = np.hypot(di, dj) * step <= radius + 1e-9
    return di[inside], dj[inside]


def _window(values: np.ndarray, cells: np.ndarray, step: float, radius: float, fill=RULED_OUT) -> np.ndarray:
    """values[..., i, j] over the disc of `radius` around each cell (k, 2), shaped (..., k, disc);
    cells off the grid hold `fill`. Every candidate's disc at once, by one fancy index."""
    di, dj = _disc(step, radius)
    ii, jj = cells[:, :1] + di, cells[:, 1:] + dj
    nx, ny = values.shape[-2:]
    inside = (ii >= 0) & (ii < nx) & (jj >= 0) & (jj < ny)
    gathered = values[..., np.clip(ii, 0, nx - 1), np.clip(jj, 0, ny - 1)]
    return np.where(inside, gathered, fill)


def choose_places(
    xy: np.ndarray, probabilities: np.ndarray, cut: float, radius: float, eligible: np.ndarray | None = None
) -> np.ndarray:
    """Indices of the places kept from candidates at `xy` (k, 2): those whose probability reaches `cut`,
    likeliest first, each suppressing the candidates within `radius` of it (one place per person's width).
    Only `eligible` candidates (None: all) can be places: a map keeps a place only where a pose scores above
    the pose threshold (`above_threshold`), so the place model's evidence can rank places but never raise one
    where the model sees no person (a sofa skeleton on a kitchen table at 0.23 did, before)."""
    order = np.flatnonzero((probabilities >= cut) & (True if eligible is None else eligible))
    order = order[np.argsort(-probabilities[order], kind="stable")]
    return order[suppress(xy[order], radius)]


def above_threshold(rows: np.ndarray, threshold: float) -> np.ndarray:
    """(k,) bool: the candidates (rows of x, y, z, theta, peak score) whose peak is a positive pose."""
    return rows[:, 4] > threshold


@dataclass
class PlaceModel:
    """P(a person can use the place | its evidence): logistic regression over the standardised evidence."""

    evidence: tuple[str, ...]
    mean: np.ndarray
    scale: np.ndarray
    coef: np.ndarray
    intercept: float
    trained_on: dict  # what it was fitted on: candidates, places, rooms
    candidate_spacing: float = CANDIDATE_SPACING  # the candidates it was fitted on were this far apart (m)
    cut: float = 0.5  # the probability a place must reach to be kept (learn.thresholds.place_cut)
    # a place's peak may score this far under the model's pose threshold (learn.thresholds.place_decision)
    eligible_margin: float = 0.0

    def eligible(self, rows: np.ndarray, threshold: float) -> np.ndarray:
        """(k,) bool: the candidates (rows of x, y, z, theta, peak score) that may be places."""
        return above_threshold(rows, threshold - self.eligible_margin)

    def probability(self, evidence: np.ndarray) -> np.ndarray:
        if tuple(self.evidence) != EVIDENCE:
            raise ValueError(f"a place model of evidence {self.evidence}; this code computes {EVIDENCE}")
        z = (np.asarray(evidence, np.float64) - self.mean) / self.scale @ self.coef + self.intercept
        return 1.0 / (1.0 + np.exp(-np.clip(z, -50, 50)))

    def to_dict(self) -> dict:
        return {
            "evidence": list(self.evidence),
            "mean": self.mean.round(9).tolist(),
            "scale": self.scale.round(9).tolist(),
            "coef": self.coef.round(9).tolist(),
            "intercept": round(float(self.intercept), 9),
            "trained_on": self.trained_on,
            "candidate_spacing": self.candidate_spacing,
            "cut": self.cut,
            **({"eligible_margin": self.eligible_margin} if self.eligible_margin else {}),
        }

    @classmethod
    def from_dict(cls, document: dict) -> PlaceModel:
        arrays = [np.asarray(document[k], np.float64) for k in ("mean", "scale", "coef")]
        if any(a.shape != (len(document["evidence"]),) for a in arrays):
            raise ValueError("a place model's mean, scale and coef must each hold one value per evidence")
        if not 0 <= float(document.get("eligible_margin", 0.0)) < np.inf:
            raise ValueError("a place model's eligible_margin must be a finite score margin >= 0")
        return cls(
            tuple(document["evidence"]),
            *arrays,
            float(document["intercept"]),
            document["trained_on"],
            float(document.get("candidate_spacing", CANDIDATE_SPACING)),
            float(document.get("cut", 0.5)),  # models before the cut was chosen kept places at 0.5
            float(document.get("eligible_margin", 0.0)),  # and before the margin, none
        )


def fit_place_model(
    evidence: np.ndarray, used: np.ndarray, regularisation: float = 1.0, weight: np.ndarray | None = None
) -> PlaceModel:
    """Logistic regression of `used` (k,) bool (the candidate matched a labelled place) on `evidence` (k, F).
    Not reweighted by class: the candidates' own base rate is what the probabilities must reproduce;
    `weight` (k,) weighs whole rooms against each other (`thresholds.room_weights`)."""
    from sklearn.linear_model import LogisticRegression

    if used.all() or not used.any():
        raise ValueError("a place model needs candidates that are places and candidates that are not")
    mean, scale = evidence.mean(axis=0), evidence.std(axis=0)
    scale = np.where(scale > 1e-9, scale, 1.0)
    fitted = LogisticRegression(C=regularisation, max_iter=1000).fit(
        (evidence - mean) / scale, used, sample_weight=weight
    )
    return PlaceModel(
        EVIDENCE,
        mean,
        scale,
        fitted.coef_[0].astype(np.float64),
        float(fitted.intercept_[0]),
        {"candidates": int(len(used)), "places": int(used.sum())},
    )
