"""Thresholds chosen on held-out rooms, as `afford map` will use them: every pose of every validation room is
scored by the model's full path (`pipeline.score_model`: the cascade included, only cells near scanned floor),
then

* the pose threshold is the one with the best pose F1 over all those rooms' scored poses, and
* the place threshold is the one with the best place F1 of the skeleton maps: a labelled place is found when
  a skeleton above the threshold matches it (labels.match_places), a skeleton is false when it matches none.

Greedy non-maximum suppression keeps, among the cells above any threshold t, exactly the places it keeps
among all cells that score above t (a place is only ever suppressed by a better one). So one skeleton map per
room at the lowest score gives every threshold's skeletons at once: the place threshold is exact, one sort.

Training samples its negatives, so a learner's own threshold was fitted to the sample's class ratio, not the
room's: this step puts every learner's threshold back on the real distribution.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..geometry.fields import scanned_cells
from ..geometry.grid import PoseGrid
from ..labels import LabelSet, ground_truth, place_matches
from ..mapping.maps import RULED_OUT, build_map
from ..mapping.pipeline import score_model
from ..mapping.places import (
    CANDIDATE_SPACING,
    PlaceModel,
    above_threshold,
    choose_places,
    fit_place_model,
    place_candidates,
    room_reference,
)
from ..settings import Settings
from .baselines import tune_threshold
from .examples import Room


@dataclass
class RoomScores:
    """One room's scored poses (as the map scores them) against the ground truth, and its candidate places:
    every skeleton of the map at the lowest threshold with the label it matches."""

    room: str
    scores: np.ndarray  # scored poses only (not in an unlabelled region)
    labels: np.ndarray  # +1 / -1 per scored pose
    place_scores: np.ndarray  # (k,) the candidate skeletons' scores
    place_false: np.ndarray  # (k,) bool: matches no label (ignored ones are left out)
    label_best: np.ndarray  # (n_labels,) the best score of a skeleton matching each label (RULED_OUT: none)
    reference: float  # places.room_reference of the room's scores
    # what the place model's candidates need: the whole grid of scores, the cells the sensor saw, the labels
    grid: PoseGrid | None = None
    grid_scores: np.ndarray | None = None
    scanned: np.ndarray | None = None
    label_set: LabelSet | None = None
    affordance: str = ""
    tolerances: dict = field(default_factory=dict)

    def places(self, cut: float) -> tuple[int, int, int]:
        """(labelled places found, skeletons kept, false skeletons) when places must beat `cut`."""
        kept = self.place_scores > cut
        return int(np.sum(self.label_best > cut)), int(kept.sum()), int(np.sum(self.place_false & kept))

    def candidates(self, threshold: float, spacing: float = CANDIDATE_SPACING) -> PlaceCandidates:
        """The room's candidate places `spacing` apart as a map with pose threshold `threshold` finds them,
        matched to its labels."""
        found = place_candidates(self.grid_scores, self.grid, threshold, spacing, self.scanned)
        matches, ignored = place_matches(
            self.label_set, self.affordance, found.rows[:, [0, 1, 3]], **self.tolerances
        )
        eligible = above_threshold(found.rows, threshold)
        return PlaceCandidates(
            found.evidence, matches, ignored, found.rows[:, :2], eligible, found.rows[:, 4]
        )

    def model_candidates(self, model) -> PlaceCandidates:
        """The candidates as a map of `model` (one with a place model) takes them: its spacing, and those its
        place model lets be places (`PlaceModel.eligible`)."""
        places = model.places
        found = self.candidates(model.threshold, places.candidate_spacing)
        return found.eligible_from(model.threshold - places.eligible_margin)


@dataclass
class PlaceCandidates:
    evidence: np.ndarray  # (k, len(places.EVIDENCE))
    matches: np.ndarray  # (n_labels, k) bool: which candidate matches which label
    ignored: np.ndarray  # (k,) bool: in an unlabelled region (neither a place nor a false one)
    xy: np.ndarray  # (k, 2) where they stand
    eligible: np.ndarray | None = None  # (k,) bool: can be a place (its peak is a positive pose); None: all
    peaks: np.ndarray | None = None  # (k,) their peak scores (what `eligible` was decided from)

    def eligible_from(self, score: float) -> PlaceCandidates:
        """The same candidates, those whose peak scores above `score` eligible."""
        return replace(self, eligible=self.peaks > score)

    def places(self, probabilities: np.ndarray, cut: float, radius: float) -> tuple[int, int, int]:
        """(labelled places found, skeletons kept, false skeletons) of the skeleton map that keeps the places
        of probability `cut`, one within `radius` (`places.choose_places`)."""
        kept = np.zeros(len(probabilities), bool)
        kept[choose_places(self.xy, probabilities, cut, radius, self.eligible)] = True
        false = kept & ~self.matches.any(axis=0) & ~self.ignored
        return int(self.matches[:, kept].any(axis=1).sum()), int(kept.sum()), int(false.sum())

    def within_reach(self) -> int:
        """Labelled places some place decision could find: those matched by a candidate that may be a place.
        Any labelled place beyond that was lost by the pose scores (no eligible candidate on it), not by the
        place model or its cut."""
        eligible = np.ones(self.matches.shape[1], bool) if self.eligible is None else self.eligible
        return int((self.matches & eligible[None]).any(axis=1).sum())

    @property
    def used(self) -> np.ndarray:
        """(k,) bool of the candidates that count: a person can use the place (it matches a label)."""
        return self.matches.any(axis=0)


def fit_places(
    rooms: list[RoomScores],
    threshold: float,
    false_budget: float | None = None,
    nms_radius: float = 0.45,
    real: list[RoomScores] = (),
    real_share: float = 0.5,
) -> PlaceModel | None:
    """The place model fitted on the rooms' candidates (None when they hold no place, or only places), with
    its eligible margin and cut chosen under `false_budget` false places per room for maps of places
    `nms_radius` apart (`place_decision`; None: 0 and 0.5). `real` rooms (scanned rooms with labels, never
    trained on) join the generated ones, together weighing `real_share` of all (`room_weights`), and the
    cut must keep both kinds of room within the budget."""
    candidates = [room.candidates(threshold) for room in [*rooms, *real]]
    is_real = np.arange(len(candidates)) >= len(rooms)
    model = _fit_on(candidates, is_real, real_share)
    if model is not None:
        model.trained_on["rooms"] = len(rooms)
        if len(real):
            model.trained_on.update(real_rooms=len(real), real_share=real_share)
        if false_budget is not None:
            model.eligible_margin, model.cut = place_decision(
                candidates, threshold, false_budget, nms_radius, is_real=is_real, real_share=real_share
            )
    return model


def room_weights(is_real: np.ndarray, real_share: float) -> np.ndarray:
    """A weight per room: 1 for a generated room, and for a real one what makes the real rooms together
    `real_share` of the total. Few real rooms against many generated ones would otherwise barely move a
    model fitted on all their candidates; weighed so, the probabilities answer to both kinds of scan, while
    the generated rooms' many kinds of place keep a handful of real rooms from deciding alone."""
    n_real = int(np.sum(is_real))
    n_generated = len(is_real) - n_real
    if n_real == 0 or n_generated == 0:
        return np.ones(len(is_real))
    return np.where(is_real, real_share / (1 - real_share) * n_generated / n_real, 1.0)


def _fit_on(
    candidates: list[PlaceCandidates], is_real: np.ndarray | None = None, real_share: float = 0.5
) -> PlaceModel | None:
    rooms = room_weights(np.zeros(len(candidates), bool) if is_real is None else is_real, real_share)
    evidence = np.concatenate([c.evidence[~c.ignored] for c in candidates])
    used = np.concatenate([c.used[~c.ignored] for c in candidates])
    weight = np.concatenate([np.full(int((~c.ignored).sum()), w) for c, w in zip(candidates, rooms)])
    if used.all() or not used.any():
        return None
    return fit_place_model(evidence, used, weight=None if np.all(weight == 1) else weight)


PLACE_CUTS = np.round(np.arange(0.5, 0.199, -0.05), 2)  # 0.5 down to 0.2: the cuts place_cut walks


# score margins under the pose threshold a place's peak may have (`place_decision`): the pose threshold is
# the best for pose F1, and a place is judged by its evidence, so a place whose best pose scores a little
# under it (a chair pushed in, a seat seen from one side) may still be one
ELIGIBLE_MARGINS = (0.0, 0.25, 0.5, 0.75, 1.0)


def place_decision(
    candidates: list[PlaceCandidates],
    threshold: float,
    false_budget: float,
    radius: float,
    folds: int = 5,
    is_real: np.ndarray | None = None,
    real_share: float = 0.5,
) -> tuple[float, float]:
    """(eligible margin, cut): of `ELIGIBLE_MARGINS`, the one whose `place_cut` finds the most labelled places
    within the false budget (the smaller on a tie), judged as `place_cut` judges, on probabilities of place
    models fitted without each room."""
    is_real = np.zeros(len(candidates), bool) if is_real is None else np.asarray(is_real, bool)
    dealt = _dealt(candidates, folds, is_real, real_share)
    if dealt is None:
        return 0.0, 0.5
    best = (-1.0, 0.0, 0.5)
    for margin in ELIGIBLE_MARGINS:
        eligible = [c.eligible_from(threshold - margin) for c in candidates]
        cut, found = _walk(eligible, dealt, false_budget, radius, is_real)
        if found > best[0]:
            best = (found, margin, cut)
    return best[1], best[2]


def place_cut(
    candidates: list[PlaceCandidates],
    false_budget: float,
    radius: float,
    folds: int = 5,
    is_real: np.ndarray | None = None,
    real_share: float = 0.5,
) -> float:
    """The probability a place must reach: walking down from a calibrated 0.5, the lowest of `PLACE_CUTS`
    before the rooms' false places per room exceed `false_budget` (the generated rooms' and, apart, the real
    ones' of `is_real`). Each room's probabilities come from a place model fitted on the other folds of rooms,
    so the cut is judged on rooms its model did not see, as a map's rooms will be, and over `DEALS` deals of
    the rooms into folds, so that it does not hang on one deal. Why lower
    than 0.5 at all: where a kind of place has weak evidence (a chair pushed under a table scores low), the
    true places gather at 0.2-0.5 and a map at 0.5 misses most of them. Why not below 0.2: a place shown to a
    robot should be one in five likely or better."""
    is_real = np.zeros(len(candidates), bool) if is_real is None else np.asarray(is_real, bool)
    dealt = _dealt(candidates, folds, is_real, real_share)
    return 0.5 if dealt is None else _walk(candidates, dealt, false_budget, radius, is_real)[0]


# The rooms are dealt into folds this many ways (the first in turn, the rest seeded at random) and a cut is
# judged on all of them, so that it does not hang on how the rooms happened to be dealt (docs/maps.md,
# "Real rooms in the calibration", measures how much one deal moves it)
DEALS = 8


def _dealt(
    candidates: list[PlaceCandidates], folds: int, is_real: np.ndarray, real_share: float
) -> list[list[np.ndarray]] | None:
    """`_held_out` under each of `DEALS` deals of the rooms into folds; None as `_held_out`."""
    dealt, n = [], len(candidates)
    for deal in range(DEALS):
        order = np.arange(n) if deal == 0 else np.random.default_rng(deal).permutation(n)
        held_out = _held_out(candidates, folds, is_real, real_share, order)
        if held_out is None:
            return None
        dealt.append(held_out)
    return dealt


def _held_out(
    candidates: list[PlaceCandidates],
    folds: int,
    is_real: np.ndarray,
    real_share: float,
    order: np.ndarray,
) -> list[np.ndarray] | None:
    """Each room's candidate probabilities from a place model fitted on the other folds of rooms, the rooms
    dealt to folds in turn in `order` (a permutation of them); None when a fold lacks either kind of
    candidate (nothing to judge a lower cut on)."""
    n = len(candidates)
    position = np.empty(n, np.int64)
    position[order] = np.arange(n)
    fold_of = position % folds
    held_out = [None] * n
    for fold in range(min(folds, n)):
        inside = np.flatnonzero(fold_of != fold)
        model = _fit_on([candidates[k] for k in inside], is_real[inside], real_share) if len(inside) else None
        if model is None:
            return None
        for k in np.flatnonzero(fold_of == fold):
            held_out[k] = model.probability(candidates[k].evidence)
    return held_out


def _walk(
    candidates: list[PlaceCandidates],
    dealt: list[list[np.ndarray]],
    false_budget: float,
    radius: float,
    is_real: np.ndarray,
) -> tuple[float, float]:
    """(the lowest cut of `PLACE_CUTS` within the budget on each kind of room, the places found there), the
    false places and the places found counted over every deal of `dealt` (each room's held-out
    probabilities, deal by deal), the places as a mean per deal."""

    budget = false_budget * len(dealt)
    chosen, found = 0.5, None
    for cut in PLACE_CUTS:  # from 0.5 down
        at_cut = np.array(
            [[c.places(p, cut, radius) for c, p in zip(candidates, held_out)] for held_out in dealt]
        ).reshape(len(dealt), -1, 3)
        places = float(at_cut[..., 0].sum() / len(dealt))
        false = at_cut[..., 2].sum(axis=0)
        if any(false[kind].sum() > budget * kind.sum() for kind in (~is_real, is_real) if kind.any()):
            if found is None:  # even 0.5 breaks the budget: 0.5 all the same, with what it finds
                found = places
            break
        chosen, found = float(cut), places
    return chosen, found


def room_scores(
    model, room: Room, layout, settings: Settings, grid_and_scores: tuple | None = None, **tolerances: float
) -> RoomScores:
    """The room scored by `model` as `afford map` scores it (or `grid_and_scores` when the caller has
    them); `tolerances` (xy_tolerance, theta_tolerance) loosen the ground truth and the place matching
    alike."""
    fields = room.fields  # once: a cached room reads its fields each time
    grid, scores = grid_and_scores or score_model(model, fields, layout, settings)
    truth = ground_truth(
        room.labels, model.affordance, grid, torso_height=model.as_skeleton().torso_height, **tolerances
    )
    scored = truth.scored_mask().ravel()
    y = np.where(truth.pose_mask().ravel()[scored], 1, -1).astype(np.int8)
    live = scores[scores > RULED_OUT]
    lowest = np.nextafter(np.float32(live.min()), RULED_OUT) if len(live) else RULED_OUT
    # every candidate place: the skeleton map at the lowest threshold
    skeletons = build_map(
        model.affordance, scores, grid, model.as_skeleton(), lowest, settings.map.nms_radius
    ).skeletons
    matches, ignored = place_matches(room.labels, model.affordance, skeletons[:, [0, 1, 3]], **tolerances)
    score = skeletons[:, 4]
    label_best = np.max(np.where(matches, score, RULED_OUT), axis=1, initial=RULED_OUT)
    counted = ~ignored
    return RoomScores(
        room.name,
        scores.ravel()[scored],
        y,
        score[counted],
        ~matches.any(axis=0)[counted],
        label_best,
        room_reference(scores),
        grid,
        scores,
        scanned_cells(fields, grid.x, grid.y),
        room.labels,
        model.affordance,
        tolerances,
    )


def pose_threshold(rooms: list[RoomScores]) -> float:
    """The threshold with the best pose F1 over every scored pose of the rooms; ruled-out poses never count
    as positive."""
    scores = np.concatenate([r.scores for r in rooms])
    labels = np.concatenate([r.labels for r in rooms])
    live = scores > RULED_OUT
    if not (labels[live] > 0).any():
        return 0.0
    return tune_threshold(scores[live], labels[live])[0]


def place_threshold(rooms: list[RoomScores], relative: bool = False) -> tuple[float, dict]:
    """(threshold, what it gives) with the best place F1 over the rooms: recall = labelled places found /
    labelled places, precision = true skeletons / skeletons. `relative`: the threshold counts from each
    room's reference (`places.room_reference`), as a model with place_reference "room-median" applies it."""
    shift = [r.reference if relative else 0.0 for r in rooms]
    candidates = np.unique(np.concatenate([r.place_scores - s for r, s in zip(rooms, shift)] + [[RULED_OUT]]))
    return _best_cut(rooms, candidates, lambda t: [t + s for s in shift])


def place_floor(rooms: list[RoomScores], relative_threshold: float) -> tuple[float | None, dict]:
    """(floor, what it gives): the absolute score a place must also beat under a relative threshold (each
    room's cut is the larger of `relative_threshold` + its reference and the floor), with the best place F1
    over the rooms; None when no floor does better than none. A room whose scores run high keeps its places,
    a room whose best scores are low (few such places, or none) gets no phantom ones."""
    relative = [relative_threshold + r.reference for r in rooms]
    candidates = np.unique(np.concatenate([r.place_scores for r in rooms] + [[RULED_OUT]]))
    floor, stats = _best_cut(rooms, candidates, lambda f: [max(c, f) for c in relative])
    return (None if floor == RULED_OUT else floor), stats


def _best_cut(rooms: list[RoomScores], candidates: np.ndarray, cuts_of) -> tuple[float, dict]:
    """The candidate (ascending) whose per-room cuts `cuts_of(candidate)` give the best place F1; ties go to
    the fewer false skeletons, then to the lower candidate."""
    labels = sum(len(r.label_best) for r in rooms)
    best = None
    for t in candidates:  # distinct skeleton scores: a few hundred, not poses
        found, kept, false = np.sum([r.places(c) for r, c in zip(rooms, cuts_of(t))], axis=0)
        recall = found / labels if labels else 0.0
        precision = (kept - false) / kept if kept else 0.0
        f1 = 2 * recall * precision / (recall + precision) if recall + precision else 0.0
        # ties (rooms with no such place at all: F1 0 everywhere) go to the fewer false skeletons
        key = (f1, -false)
        if best is None or key > best[0]:
            stats = {"place_f1": f1, "place_recall": recall, "false_per_room": false / max(1, len(rooms))}
            best = (key, float(t), stats)
    return best[1], best[2]
