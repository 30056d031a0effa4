"""Affordance maps from pose scores: the predicted positives, the confidence map and the skeleton map.

* positives: every pose scoring above the model's threshold;
* confidence map: over the floor plan, each (x, y) cell's best score over theta and z, and the theta and z
  that reached it;
* skeleton map: one skeleton per place. Greedy non-maximum suppression over the confidence map's cells above
  the place threshold (the model's, or its cut for this room): the best cell becomes a skeleton (at its best
  theta and z, with placed joints), and every cell within `nms_radius` of it is suppressed, whatever its
  theta. Places are the loop, not poses: each step is one vectorised distance test over the remaining cells.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .grid import PoseGrid
from .skeleton import Skeleton, place_joints

FORMAT = "affordance-map/1"
RULED_OUT = np.finfo(np.float32).min  # the score of a pose that is not a candidate at all


def room_reference(scores: np.ndarray) -> float:
    """The median score of a room's candidate poses (0 when it has none): what a relative place threshold
    is counted from. A scan unlike the training rooms (fewer viewpoints, other noise) moves a room's scores
    together, the places with the rest; a threshold above this median moves with them."""
    live = scores[scores > RULED_OUT]
    return float(np.median(live)) if len(live) else 0.0


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
    skeletons: np.ndarray  # (k, 5): x, y, z, theta, score, best first
    joints: np.ndarray  # (k, 15, 3) placed joints of the skeletons
    place_threshold: float  # what a place of the skeleton map scored above (the room's cut)

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
) -> dict:
    """The affordance-map/1 JSON document (what `afford map` writes and `afford watch` saves)."""

    def rows(values: np.ndarray) -> list[dict]:
        keys = ("x", "y", "z", "theta", "score")
        return [dict(zip(keys, (round(float(v), 4) for v in row))) for row in values]

    placed = rows(skeletons)
    for skeleton, skeleton_joints in zip(placed, joints):
        skeleton["joints"] = np.round(skeleton_joints, 4).tolist()
    return {
        "format": FORMAT,
        "affordance": affordance,
        "model": model_id,
        "threshold": float(threshold),
        "place_threshold": float(place_threshold),
        "frame": "world: gravity-aligned, z up, floor at z = 0, metres",
        "world_from_input": np.asarray(world_from_input, dtype=float).round(9).tolist(),
        "grid": grid,
        "skeletons": placed,
        "positives": rows(positives),
    }


def build_map(
    affordance: str,
    scores: np.ndarray,
    grid: PoseGrid,
    skeleton: Skeleton,
    threshold: float,
    nms_radius: float = 0.45,
    allowed: np.ndarray | None = None,
    place_threshold: float | None = None,
) -> AffordanceMap:
    """The three outputs from the scores of every pose (shaped like the grid: z, theta, x, y); cells where
    `allowed` (nx, ny) is False hold no positive and no skeleton (their confidence is float32's lowest).
    Places of the skeleton map must score above `place_threshold` (default: `threshold`)."""
    if allowed is not None:
        scores = np.where(allowed[None, None], scores, RULED_OUT).astype(np.float32)
    nz, nt, nx, ny = grid.shape
    flat = scores.reshape(nz * nt, nx, ny)
    best = flat.argmax(axis=0)  # per (x, y): the best (z, theta) slab
    confidence = np.take_along_axis(flat, best[None], axis=0)[0]
    best_z, best_theta = grid.z[best // nt], grid.theta[best % nt]

    above = np.flatnonzero(scores.ravel() > threshold)
    above = above[np.argsort(-scores.ravel()[above], kind="stable")]
    positives = (
        np.column_stack([grid.poses(above), scores.ravel()[above]]) if len(above) else np.empty((0, 5))
    )

    place_threshold = threshold if place_threshold is None else place_threshold
    cells = np.argwhere(confidence > place_threshold)
    cells = cells[np.argsort(-confidence[cells[:, 0], cells[:, 1]], kind="stable")]
    xy = np.column_stack([grid.x[cells[:, 0]], grid.y[cells[:, 1]]])
    chosen, alive = [], np.ones(len(cells), dtype=bool)
    while alive.any():
        first = int(np.argmax(alive))  # cells are sorted best first
        chosen.append(first)
        alive &= np.hypot(*(xy - xy[first]).T) > nms_radius
    picked = cells[chosen]
    i, j = picked[:, 0], picked[:, 1]
    skeletons = (
        np.column_stack([grid.x[i], grid.y[j], best_z[i, j], best_theta[i, j], confidence[i, j]])
        if len(picked)
        else np.empty((0, 5))
    )
    joints = (
        place_joints(skeleton.joints, skeletons[:, :4])
        if len(picked)
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
    )
