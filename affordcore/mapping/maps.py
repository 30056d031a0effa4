"""Affordance maps from pose scores: the predicted positives, the confidence map and the skeleton map.

* positives: every pose scoring above the model's threshold;
* confidence map: over the floor plan, each (x, y) cell's best score over theta and z, and the theta and z
  that reached it;
* skeleton map: one skeleton per place, at its best theta and z, with placed joints. With a place model
  (affordcore/mapping/places.py) the peaks of the confidence map are candidates with a probability, and the
  map keeps the likeliest that reach `place_probability`, one within `nms_radius`; without one, greedy
  non-maximum suppression over the confidence map's cells above the place threshold (the model's, or its
  cut for this room): the best cell becomes a skeleton and every cell within `nms_radius` of it is
  suppressed, whatever its theta.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..geometry.grid import PoseGrid
from ..geometry.skeleton import Skeleton, place_joints
from .places import (
    RULED_OUT,
    PlaceModel,
    best_slabs,
    choose_places,
    peak_cells,
    place_candidates,
)

FORMAT = "affordance-map/1"
# a probability low enough that a map asked for it keeps nearly every place the scores see (docs/accuracy.md,
# the operating curve): the places it would add to a map are that map's unsure places
UNSURE_PROBABILITY = 0.1


@dataclass
class AffordanceMap:
    affordance: str
    grid: PoseGrid
    threshold: float
    scores: np.ndarray  # (z, theta, x, y) every pose's score as mapped (float32's lowest where not allowed)
    confidence: np.ndarray  # (nx, ny) best score over theta and z
    best_theta: np.ndarray  # (nx, ny) radians
    best_z: np.ndarray  # (nx, ny) metres
    positives: np.ndarray  # (n, 5): x, y, z, theta, score, best first
    skeletons: np.ndarray  # (k, 5): x, y, z, theta, score; the likeliest (else the best) first
    joints: np.ndarray  # (k, 15, 3) placed joints of the skeletons
    place_threshold: float  # the score cut places beat in this room (NaN: kept by probability)
    probabilities: np.ndarray  # (k,) that a person can use each place (NaN: no place model)
    place_probability: float  # what a place's probability reached to be kept (NaN: no place model)
    # places a map asked for UNSURE_PROBABILITY would keep besides these (0 without a place model): what
    # lowering `map.place_probability` would add, for the one who reads the map
    unsure_places: int = 0
    # (m, 6) x, y, z, theta, score, probability of every candidate place the place model may keep, kept
    # or not (none without a place model): what the map is unsure of
    candidates: np.ndarray = field(default_factory=lambda: np.empty((0, 6)))
    # where to look next to settle its candidates (`next_views`; with `next_views.count` and the sensor
    # positions)
    next_views: list = field(default_factory=list)

    def unsure_note(self) -> str:
        """How many more places a map at UNSURE_PROBABILITY would keep, and how to ask for them ("" when
        none): "2 more with AFFORD_MAP__PLACE_PROBABILITY=0.1"."""
        if not self.unsure_places:
            return ""
        return f"{self.unsure_places} more with AFFORD_MAP__PLACE_PROBABILITY={UNSURE_PROBABILITY:g}"

    def place_labels(self) -> list[str]:
        """What a person reads beside each place: its probability, or its score for a model without a place
        model."""
        return [
            f"p {p:.2f}" if np.isfinite(p) else f"{score:.2f}"
            for score, p in zip(self.skeletons[:, 4], self.probabilities)
        ]

    def to_json(self, model_id: str, world_from_input: np.ndarray) -> dict:
        return map_document(
            self.affordance,
            model_id,
            self.threshold,
            self.grid.as_dict(),
            self.skeletons,
            self.joints,
            self.positives,
            world_from_input,
            self.place_threshold,
            self.probabilities,
            self.place_probability,
            self.next_views,
        )


def map_document(
    affordance: str,
    model_id: str,
    threshold: float,
    grid: dict,
    skeletons: np.ndarray,
    joints: np.ndarray,
    positives: np.ndarray,
    world_from_input: np.ndarray,
    place_threshold: float,
    probabilities: np.ndarray,
    place_probability: float = float("nan"),
    next_views: list | None = None,
) -> dict:
    """The affordance-map/1 JSON document (what `afford map` writes and `afford watch` saves). A NaN (no place
    model) is written as null."""

    def rows(values: np.ndarray) -> list[dict]:
        keys = ("x", "y", "z", "theta", "score")
        return [dict(zip(keys, (round(float(v), 4) for v in row))) for row in values]

    placed = rows(skeletons)
    for skeleton, skeleton_joints, probability in zip(placed, joints, probabilities):
        skeleton["probability"] = _number(probability)
        skeleton["joints"] = np.round(skeleton_joints, 4).tolist()
    document = {
        "format": FORMAT,
        "affordance": affordance,
        "model": model_id,
        "threshold": float(threshold),
        "place_threshold": _number(place_threshold),
        "place_probability": _number(place_probability),
        "frame": "world: gravity-aligned, z up, floor at z = 0, metres",
        "world_from_input": np.asarray(world_from_input, dtype=float).round(9).tolist(),
        "grid": grid,
        "skeletons": placed,
        "positives": rows(positives),
    }
    if next_views:  # asked for (afford map --next-views): the views, best first
        document["next_views"] = [view.to_json() for view in next_views]
    return document


def _number(value: float) -> float | None:
    return None if not np.isfinite(value) else round(float(value), 4)


def build_map(
    affordance: str,
    scores: np.ndarray,
    grid: PoseGrid,
    skeleton: Skeleton,
    threshold: float,
    nms_radius: float = 0.45,
    allowed: np.ndarray | None = None,
    place_threshold: float | None = None,
    place_model: PlaceModel | None = None,
    place_probability: float | None = None,
    scanned: np.ndarray | None = None,
) -> AffordanceMap:
    """The three outputs from the scores of every pose (shaped like the grid: z, theta, x, y); cells where
    `allowed` (nx, ny) is False hold no positive and no skeleton (their confidence is float32's lowest).
    Places of the skeleton map must reach `place_probability` (default: the place model's own cut) under
    `place_model` (with `scanned`, (nx, ny): the cells the sensor saw), or without one score above
    `place_threshold` (default: `threshold`)."""
    if allowed is not None:
        scores = np.where(allowed[None, None], scores, RULED_OUT).astype(np.float32)
    confidence, best = best_slabs(scores, grid)
    nt = grid.shape[1]
    best_z, best_theta = grid.z[best // nt], grid.theta[best % nt]

    above = np.flatnonzero(scores.ravel() > threshold)
    above = above[np.argsort(-scores.ravel()[above], kind="stable")]
    positives = (
        np.column_stack([grid.poses(above), scores.ravel()[above]]) if len(above) else np.empty((0, 5))
    )

    if place_model is not None:
        candidates = place_candidates(scores, grid, threshold, place_model.candidate_spacing, scanned)
        probabilities = place_model.probability(candidates.evidence)
        place_probability = place_model.cut if place_probability is None else place_probability
        eligible = place_model.eligible(candidates.rows, threshold)
        xy = candidates.rows[:, :2]
        kept = choose_places(xy, probabilities, place_probability, nms_radius, eligible)
        lower = min(UNSURE_PROBABILITY, place_probability)
        unsure = len(choose_places(xy, probabilities, lower, nms_radius, eligible)) - len(kept)
        candidate_rows = np.column_stack([candidates.rows, probabilities])[eligible].reshape(-1, 6)
        skeletons, probabilities = candidates.rows[kept].reshape(-1, 5), probabilities[kept]
        place_threshold = float("nan")
    else:
        place_threshold = threshold if place_threshold is None else place_threshold
        i, j = peak_cells(confidence, grid, place_threshold, nms_radius, None).T
        skeletons = np.column_stack([grid.x[i], grid.y[j], best_z[i, j], best_theta[i, j], confidence[i, j]])
        probabilities, place_probability = np.full(len(skeletons), np.nan), float("nan")
        unsure, candidate_rows = 0, np.empty((0, 6))
    joints = (
        place_joints(skeleton.joints, skeletons[:, :4])
        if len(skeletons)
        else np.empty((0, len(skeleton.joints), 3))
    )
    return AffordanceMap(
        affordance,
        grid,
        float(threshold),
        scores,
        confidence,
        best_theta,
        best_z,
        positives,
        skeletons,
        joints,
        float(place_threshold),
        probabilities,
        float(place_probability),
        unsure,
        candidate_rows,
    )
