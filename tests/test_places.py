"""Places with a probability: the candidates and their evidence against brute-force counts, the place model's
calibration, and the probability carried through the map, its JSON, the model file and the wire."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import skeleton_document

from affordcore.geometry.features import FeatureLayout
from affordcore.geometry.grid import PoseGrid
from affordcore.geometry.skeleton import get_skeleton
from affordcore.learn.model import AffordanceModel, load_model
from affordcore.mapping.maps import build_map
from affordcore.mapping.outputs import summary_line
from affordcore.mapping.places import (
    CANDIDATE_SPACING,
    EVIDENCE,
    SUPPORT_RADIUS,
    PlaceModel,
    choose_places,
    fit_place_model,
    place_candidates,
)
from affordcore.mapping.plots import place_summary


def _grid() -> PoseGrid:
    return PoseGrid(
        np.arange(30) * 0.1 + 0.05, np.arange(20) * 0.1 + 0.05, np.array([0.5, 0.6]), np.arange(8) * np.pi / 4
    )


def _scores(grid: PoseGrid) -> np.ndarray:
    """A broad bump at (0.85, 0.85) over four orientations, a narrow spike at (2.25, 1.45) in one slab, noise
    below -3 elsewhere."""
    rng = np.random.default_rng(3)
    xx, yy = np.meshgrid(grid.x, grid.y, indexing="ij")
    scores = rng.uniform(-5, -3, grid.shape)
    for it in range(4):
        scores[:, it] = np.maximum(scores[:, it], 2.0 - np.hypot(xx - 0.85, yy - 0.85) / 0.1)
    scores[1, 6, 22, 14] = 2.5
    return scores.astype(np.float32)


def test_candidates_are_peaks_best_first_with_evidence_counted_pose_by_pose():
    grid = _grid()
    scores = _scores(grid)
    threshold = 0.0
    candidates = place_candidates(scores, grid, threshold, nms_radius=0.45)
    # the spike (2.5) before the bump (2.0), then noise peaks; no two within 0.45 m
    np.testing.assert_allclose(candidates.rows[0], [2.25, 1.45, 0.6, 6 * np.pi / 4, 2.5], atol=1e-6)
    np.testing.assert_allclose(candidates.rows[1, [0, 1, 4]], [0.85, 0.85, 2.0], atol=1e-6)
    xy = candidates.rows[:, :2]
    assert np.all(np.diff(candidates.rows[:, 4]) <= 0)
    assert (np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1)) + np.eye(len(xy)) > 0.45).all()
    # an independent oracle: walk every pose of the grid
    poses = grid.poses(np.arange(grid.size))
    flat = scores.ravel()
    evidence = dict(zip(EVIDENCE, candidates.evidence.T))
    for k, (x, y, _, _, peak) in enumerate(candidates.rows[:2]):
        near = np.hypot(poses[:, 0] - x, poses[:, 1] - y) <= SUPPORT_RADIUS + 1e-9
        assert evidence["support"][k] == pytest.approx(np.log1p(np.sum(near & (flat > threshold))))
        assert evidence["near_peak"][k] == pytest.approx(np.log1p(np.sum(near & (flat > peak - 1))))
        turns = len(np.unique(poses[near & (flat > threshold), 3]))
        assert evidence["turns"][k] == pytest.approx(turns / len(grid.theta))
    assert evidence["turns"][1] == pytest.approx(0.5) and evidence["turns"][0] == pytest.approx(1 / 8)
    assert evidence["below_best"][0] == 0 and evidence["below_best"][1] == pytest.approx(-0.5)
    assert evidence["over_median"][0] == pytest.approx(2.5 - np.median(flat))


def test_scanned_share_counts_the_cells_the_sensor_saw():
    grid = _grid()
    scanned = np.zeros((30, 20), bool)
    scanned[:15] = True  # the half x < 1.5 m was seen
    candidates = place_candidates(_scores(grid), grid, 0.0, 0.45, scanned)
    share = candidates.evidence[:, EVIDENCE.index("scanned")]
    xx, yy = np.meshgrid(grid.x, grid.y, indexing="ij")
    for (x, y), got in zip(candidates.rows[:, :2], share):
        # cells off the grid are outside the scanned footprint: they count as unseen
        disc = int(np.sum(np.hypot(*np.mgrid[-10:11, -10:11]) <= 10 + 1e-9))
        within = np.hypot(xx - x, yy - y) <= 1.0 + 1e-9
        assert got == pytest.approx(np.sum(within & scanned) / disc)
    assert share[0] < 0.1 < 0.5 < share[1]  # the spike stands in the unseen half, the bump in the seen one


def _synthetic_places(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Evidence rows whose true place probability is a known logistic function of two columns."""
    rng = np.random.default_rng(seed)
    evidence = rng.normal(size=(n, len(EVIDENCE)))
    truth = 1 / (1 + np.exp(-(2.0 * evidence[:, 0] + 1.0 * evidence[:, 4] - 2.5)))
    return evidence, rng.random(n) < truth


def test_the_place_model_is_calibrated_on_rooms_it_never_saw():
    evidence, used = _synthetic_places(6000, 0)
    model = fit_place_model(evidence, used)
    held, held_used = _synthetic_places(6000, 1)
    p = model.probability(held)
    for low, high in ((0.0, 0.2), (0.2, 0.5), (0.5, 0.8), (0.8, 1.0)):
        inside = (p >= low) & (p < high)
        assert inside.sum() > 100
        assert abs(p[inside].mean() - held_used[inside].mean()) < 0.05, (low, high)
    # it ranks by the evidence that matters, not the noise columns
    assert model.coef[0] > 1.0 and abs(model.coef[2]) < 0.2
    again = PlaceModel.from_dict(json.loads(json.dumps(model.to_dict())))
    np.testing.assert_allclose(again.probability(held), p, atol=1e-7)


def test_a_place_model_of_other_evidence_is_refused():
    model = fit_place_model(*_synthetic_places(500, 0))
    model.evidence = (*EVIDENCE[:-1], "something-else")
    with pytest.raises(ValueError, match="evidence"):
        model.probability(np.zeros((1, len(EVIDENCE))))
    with pytest.raises(ValueError, match="places and candidates that are not"):
        fit_place_model(np.zeros((5, len(EVIDENCE))), np.zeros(5, bool))


def _place_model_on_score(weight: float, intercept: float) -> PlaceModel:
    """P = sigmoid(weight * (score - 0) + intercept): a place model that looks at the peak score only."""
    coef = np.zeros(len(EVIDENCE))
    coef[0] = weight
    return PlaceModel(EVIDENCE, np.zeros(len(EVIDENCE)), np.ones(len(EVIDENCE)), coef, intercept, {})


def test_the_map_keeps_the_places_that_reach_the_probability_likeliest_first():
    grid, skeleton = _grid(), get_skeleton("sitting-working")
    scores = _scores(grid)
    model = _place_model_on_score(4.0, -8.5)  # p(2.5) = 0.82, p(2.0) = 0.38, p(noise) ~ 0
    kept = build_map("a", scores, grid, skeleton, 0.0, place_model=model, place_probability=0.5)
    assert len(kept.skeletons) == 1 and kept.probabilities[0] == pytest.approx(1 / (1 + np.exp(-1.5)))
    # the place at 0.38 is not kept, and the summary says how to ask for it
    assert kept.unsure_places == 1
    assert summary_line(kept).endswith("1 more with AFFORD_MAP__PLACE_PROBABILITY=0.1")
    assert place_summary(kept) == "1 place (probability >= 0.50; +1 at >= 0.1)"  # the PNG's title
    assert kept.unsure_note() == "1 more with AFFORD_MAP__PLACE_PROBABILITY=0.1"  # the recording's note
    both = build_map("a", scores, grid, skeleton, 0.0, place_model=model, place_probability=0.3)
    assert len(both.skeletons) == 2 and np.all(np.diff(both.probabilities) <= 0)
    assert both.unsure_places == 0 and "more with" not in summary_line(both)
    assert place_summary(both) == "2 places (probability >= 0.30)"
    assert both.joints.shape == (2, 15, 3) and np.isnan(both.place_threshold)
    document = both.to_json("m", np.eye(4))
    assert [s["probability"] for s in document["skeletons"]] == pytest.approx(both.probabilities, abs=1e-4)
    assert document["place_probability"] == 0.3 and document["place_threshold"] is None
    assert both.place_labels()[0] == f"p {both.probabilities[0]:.2f}"
    # without a place model: the score cut, and no probability
    plain = build_map("a", scores, grid, skeleton, 0.0)
    assert place_summary(plain) == f"{len(plain.skeletons)} places" and plain.unsure_places == 0
    assert (
        np.isnan(plain.probabilities).all()
        and plain.to_json("m", np.eye(4))["skeletons"][0]["probability"] is None
    )


def test_the_model_file_carries_its_place_model(tmp_path):
    layout = FeatureLayout(cell_size=0.25)
    place = fit_place_model(*_synthetic_places(800, 0))
    model = AffordanceModel(
        "leaning",
        layout.describe(),
        layout.fingerprint,
        np.ones(layout.n_features),
        0.0,
        0.1,
        "ssvm",
        skeleton=skeleton_document(),
    )
    without = model.id
    model.place_model = place.to_dict()
    loaded = load_model(model.save(tmp_path / "m.json"), layout)
    assert loaded.id == model.id != without
    evidence = _synthetic_places(10, 5)[0]
    np.testing.assert_allclose(loaded.places.probability(evidence), place.probability(evidence), atol=1e-7)
    document = json.loads((tmp_path / "m.json").read_text())
    document["place_model"]["coef"] = [1.0]
    (tmp_path / "bad.json").write_text(json.dumps(document))
    with pytest.raises(ValueError, match="one value per evidence"):
        load_model(tmp_path / "bad.json")


def test_probabilities_cross_the_wire_and_none_stays_none():
    from affordwire.messages import map_arrays, map_document_of, map_message
    from affordwire.proto.maps_pb2 import SceneFields as SceneFieldsMessage

    grid, skeleton = _grid(), get_skeleton("sitting-working")
    scores = _scores(grid)
    fields = SceneFieldsMessage()
    with_model = build_map(
        "a", scores, grid, skeleton, 0.0, place_model=_place_model_on_score(4.0, -8.5), place_probability=0.3
    )
    arrays = map_arrays(map_message(with_model, "m", fields))
    np.testing.assert_allclose(arrays["probabilities"], with_model.probabilities)
    document = map_document_of(map_message(with_model, "m", fields))
    assert document["place_probability"] == 0.3
    plain = build_map("a", scores, grid, skeleton, 0.0)
    message = map_message(plain, "m", fields)
    assert not message.HasField("place_probability") and not message.skeletons[0].HasField("probability")
    assert np.isnan(map_arrays(message)["probabilities"]).all()


def test_places_are_chosen_likeliest_first_one_per_persons_width():
    xy = np.array([[0.0, 0.0], [0.25, 0.0], [0.5, 0.0], [2.0, 0.0], [3.0, 0.0]])
    p = np.array([0.6, 0.9, 0.7, 0.4, 0.55])
    # 0.9 at 0.25 m suppresses its neighbours within 0.45 m (0.6 and 0.7); 0.4 is below the cut
    np.testing.assert_array_equal(choose_places(xy, p, 0.5, 0.45), [1, 4])
    np.testing.assert_array_equal(choose_places(xy, p, 0.5, 0.2), [1, 2, 0, 4])
    assert len(choose_places(xy, p, 0.95, 0.45)) == 0


def test_candidates_are_denser_than_places_and_the_spacing_travels_with_the_model():
    grid = _grid()
    dense = place_candidates(_scores(grid), grid, 0.0, CANDIDATE_SPACING)
    sparse = place_candidates(_scores(grid), grid, 0.0, 0.45)
    assert len(dense.rows) > len(sparse.rows)
    model = fit_place_model(*_synthetic_places(500, 0))
    assert PlaceModel.from_dict(model.to_dict()).candidate_spacing == CANDIDATE_SPACING


def _rooms_of_candidates(rooms: int, seed: int, overlap: float, column: int = 0) -> list:
    """Rooms of candidate places 1 m apart (no two suppress each other): two true places and twenty false
    ones each, the true ones `overlap` sigmas above the false ones in evidence `column` (the peak score)."""
    from affordcore.learn.thresholds import PlaceCandidates

    rng = np.random.default_rng(seed)
    found = []
    for _ in range(rooms):
        used = np.r_[np.ones(2, bool), np.zeros(20, bool)]
        evidence = rng.normal(size=(len(used), len(EVIDENCE)))
        evidence[:, column] += overlap * used
        matches = np.zeros((2, len(used)), bool)
        matches[[0, 1], [0, 1]] = True
        xy = np.column_stack([np.arange(len(used), dtype=float), np.zeros(len(used))])
        found.append(PlaceCandidates(evidence, matches, np.zeros(len(used), bool), xy))
    return found


def test_the_place_cut_is_the_lowest_that_keeps_false_places_within_the_budget_on_unseen_rooms():
    from affordcore.learn.thresholds import PLACE_CUTS, _fit_on, place_cut

    rooms = _rooms_of_candidates(60, 0, overlap=2.0)
    cuts = {budget: place_cut(rooms, budget, 0.45) for budget in (0.0, 0.3, 1.0, 3.0, 50.0)}
    assert set(cuts.values()) <= {float(c) for c in PLACE_CUTS}
    # a larger budget never raises the cut; none keeps the calibrated 0.5; a vast one walks to the floor
    assert list(cuts.values()) == sorted(cuts.values(), reverse=True)
    assert cuts[0.0] == 0.5 and cuts[50.0] == 0.2 and 0.2 < cuts[1.0] < 0.5
    # the budget holds, within what 60 rooms can tell, on 300 rooms nobody fitted or judged on, and the walk
    # stopped where the next lower cut would have broken it there as well
    model, fresh = _fit_on(rooms), _rooms_of_candidates(300, 9, overlap=2.0)
    false = {
        cut: np.mean([c.places(model.probability(c.evidence), cut, 0.45)[2] for c in fresh])
        for cut in (cuts[1.0], cuts[1.0] - 0.05)
    }
    assert false[cuts[1.0]] <= 1.3 and false[cuts[1.0] - 0.05] > 1.0, false
    # places that stand apart keep nothing false at any cut, so the walk goes to the floor; in rooms of pure
    # noise every probability sits near the base rate (2 in 22), so however low the cut walks, no phantom
    assert place_cut(_rooms_of_candidates(20, 1, overlap=8.0), 1.0, 0.45) == 0.2
    noise = _rooms_of_candidates(20, 2, overlap=0.0)
    cut, model = place_cut(noise, 0.3, 0.45), _fit_on(noise)
    assert sum(c.places(model.probability(c.evidence), cut, 0.45)[1] for c in noise) <= 0.3 * len(noise)


def test_real_rooms_weigh_their_share_of_the_place_model_and_hold_its_cut_to_the_budget():
    """Generated rooms whose places stand out by their score, real ones whose places stand out by another
    evidence (a scan that shifts scores): fitted with the real rooms at half the weight, the model finds the
    places of fresh real rooms it would miss without them; and a cut must keep the real rooms within the
    budget too."""
    from affordcore.learn.thresholds import _fit_on, place_cut, room_weights

    is_real = np.r_[np.zeros(40, bool), np.ones(5, bool)]
    weights = room_weights(is_real, 0.5)
    assert weights[is_real].sum() == pytest.approx(weights[~is_real].sum())
    assert np.all(weights[~is_real] == 1) and np.all(room_weights(is_real, 0.2)[is_real] == 2.0)
    assert np.all(room_weights(np.zeros(3, bool), 0.5) == 1)

    generated = _rooms_of_candidates(40, 3, overlap=3.0, column=0)
    real = _rooms_of_candidates(5, 4, overlap=3.0, column=1)
    fresh_real = _rooms_of_candidates(100, 5, overlap=3.0, column=1)
    fresh_generated = _rooms_of_candidates(100, 6, overlap=3.0, column=0)

    def found(model, rooms, cut=0.3):
        return np.sum([c.places(model.probability(c.evidence), cut, 0.45) for c in rooms], axis=0)

    alone, both = _fit_on(generated), _fit_on([*generated, *real], is_real, 0.5)
    lightly = _fit_on([*generated, *real], is_real, 0.1)
    # the real rooms' places, all but lost without them, and found more the more the real rooms weigh
    assert found(alone, fresh_real)[0] < 20 < 2 * found(lightly, fresh_real)[0] < found(both, fresh_real)[0]
    # at the price of some of the generated ones, where the two kinds of room disagree this much
    assert (
        found(alone, fresh_generated)[0]
        > found(both, fresh_generated)[0]
        > 0.5 * found(alone, fresh_generated)[0]
    )
    # real rooms full of phantoms (places no better than noise) stop the walk where generated ones would not
    noisy_real = _rooms_of_candidates(5, 7, overlap=0.0, column=1)
    # (the budget judged on the real rooms apart: pooled with the generated ones they would pass lower)
    apart = place_cut([*generated, *noisy_real], 1.0, 0.45, is_real=is_real, real_share=0.5)
    assert place_cut(generated, 1.0, 0.45) == 0.2 < place_cut([*generated, *noisy_real], 1.0, 0.45) < apart


def test_the_map_keeps_the_places_at_the_place_models_own_cut_unless_told_otherwise():
    grid, skeleton = _grid(), get_skeleton("sitting-working")
    scores = _scores(grid)
    model = _place_model_on_score(4.0, -8.5)  # p(2.5) = 0.82, p(2.0) = 0.38
    model.cut = 0.3
    own = build_map("a", scores, grid, skeleton, 0.0, place_model=model)
    assert len(own.skeletons) == 2 and own.to_json("m", np.eye(4))["place_probability"] == 0.3
    told = build_map("a", scores, grid, skeleton, 0.0, place_model=model, place_probability=0.5)
    assert len(told.skeletons) == 1 and told.place_probability == 0.5
    # a candidate whose peak is no positive pose is never a place, however likely its evidence says it is
    above = build_map("a", scores, grid, skeleton, 2.2, place_model=model)
    assert len(above.skeletons) == 1 and above.skeletons[0, 4] == pytest.approx(2.5)
    # the cut travels with the place model; a model file from before the cut keeps places at 0.5
    assert PlaceModel.from_dict(model.to_dict()).cut == 0.3
    older = {k: v for k, v in model.to_dict().items() if k != "cut"}
    assert PlaceModel.from_dict(older).cut == 0.5
    # a place model with an eligible margin lets a peak that far under the pose threshold be a place
    model.eligible_margin = 0.4
    below = build_map("a", scores, grid, skeleton, 2.2, place_model=model)
    assert len(below.skeletons) == 2
    assert PlaceModel.from_dict(model.to_dict()).eligible_margin == 0.4
    assert "eligible_margin" not in older and PlaceModel.from_dict(older).eligible_margin == 0.0
    for hostile in (-0.1, float("inf"), float("nan")):
        with pytest.raises(ValueError, match="eligible_margin"):
            PlaceModel.from_dict({**model.to_dict(), "eligible_margin": hostile})


def test_a_false_budget_met_exactly_lets_the_cut_walk_on():
    """Two rooms, a budget of 0.5 false places a room: one false place in all is within it, two are not. The
    walk goes on past the cut that meets the budget exactly and stops before the one that breaks it."""
    from affordcore.learn.thresholds import PlaceCandidates, _walk

    def room(false_probability: float):
        evidence = np.zeros((2, len(EVIDENCE)))
        matches = np.array([[True, False]])
        xy = np.array([[0.0, 0.0], [5.0, 0.0]])  # too far apart to suppress each other
        return PlaceCandidates(evidence, matches, np.zeros(2, bool), xy), np.array([0.9, false_probability])

    (a, pa), (b, pb) = room(0.42), room(0.27)
    cut, found = _walk([a, b], [[pa, pb]], 0.5, 0.45, np.zeros(2, bool))
    assert (cut, found) == (0.3, 2)  # 0.4 and 0.3 keep one false place (the budget); 0.25 keeps two
    assert _walk([a, b], [[pa, pb]], 0.49, 0.45, np.zeros(2, bool))[0] == 0.45  # under it: before 0.4


def test_places_whose_peaks_fall_just_under_the_pose_threshold_are_let_in_when_that_finds_more():
    """Candidates whose true places stand out by their evidence but whose peaks score under the pose
    threshold: the decision lets them in by the margin that finds them, within the false budget; where the
    candidates under the threshold are all false, it keeps the margin at 0."""
    from affordcore.learn.thresholds import ELIGIBLE_MARGINS, place_decision

    threshold = 1.0

    def rooms(seed: int, true_peak: float, false_low: float) -> list:
        found = _rooms_of_candidates(40, seed, overlap=4.0, column=1)
        rng = np.random.default_rng(seed)
        for c in found:
            c.peaks = np.where(c.used, true_peak, rng.uniform(false_low, 2.0, len(c.used)))
            c.eligible = c.peaks > threshold
        return found

    margin, cut = place_decision(rooms(1, true_peak=0.6, false_low=1.1), threshold, 0.4, 0.45)
    assert margin == min(m for m in ELIGIBLE_MARGINS if m > 0.4) and 0.2 <= cut <= 0.5
    # the places above the threshold already: a margin would let in false candidates only
    assert place_decision(rooms(2, true_peak=1.5, false_low=-1.0), threshold, 0.4, 0.45)[0] == 0.0


def test_place_probability_setting_overrides_or_defers(monkeypatch):
    from affordcore.settings import Settings

    assert Settings().map.place_probability is None
    monkeypatch.setenv("AFFORD_MAP__PLACE_PROBABILITY", "0.7")
    assert Settings().map.place_probability == 0.7
    monkeypatch.setenv("AFFORD_MAP__PLACE_PROBABILITY", "none")
    assert Settings().map.place_probability is None


def test_a_place_stands_at_the_centre_of_its_strong_poses_not_at_the_rim_of_their_plateau():
    """A plateau of strong poses centred at (1.45, 0.95) facing theta = 0, whose single best pose sits on its
    rim (1.55, 0.95): the place moves most of the way to the plateau's centre, and its theta is
    the circular mean of the plateau's orientations (7 pi / 4 and pi / 4 average to 0, not to pi)."""
    from affordcore.mapping.places import CENTRE_MARGIN, centred

    grid = _grid()
    scores = np.full(grid.shape, -5.0, np.float32)
    xx, yy = np.meshgrid(grid.x, grid.y, indexing="ij")
    plateau = np.hypot(xx - 1.45, yy - 0.95) <= 0.15
    for it in (7, 0, 1):  # -pi/4, 0, +pi/4
        scores[:, it][:, plateau] = 2.0
    scores[0, 0, 15, 9] = 2.4  # the argmax: on the rim, 0.1 m off
    candidates = place_candidates(scores, grid, threshold=0.0, nms_radius=0.45)
    x, y, z, theta, peak = candidates.rows[0]
    assert peak == pytest.approx(2.4) and z == grid.z[0]  # the peak's own score and height stay
    # most of the way in: the centre of what lies within CENTRE_RADIUS of the peak, not the whole plateau's
    assert 1.45 <= x < 1.49 and abs(y - 0.95) < 0.01
    assert min(theta, 2 * np.pi - theta) < 0.05
    # a pose below the pose threshold, or more than CENTRE_MARGIN under the peak, does not pull
    lone = np.full(grid.shape, -5.0, np.float32)
    lone[1, 2, 10, 10] = 1.0
    lone[1, 2, 11, 10] = 1.0 - CENTRE_MARGIN - 0.1
    rows = np.array([[grid.x[10], grid.y[10], grid.z[1], grid.theta[2], 1.0]])
    np.testing.assert_allclose(centred(lone, grid, np.array([[10, 10]]), rows, 0.0), rows)
    np.testing.assert_allclose(centred(lone, grid, np.array([[10, 10]]), rows, 2.0), rows)  # none above it


def test_within_reach_counts_the_labels_an_eligible_candidate_stands_on():
    from affordcore.learn.thresholds import PlaceCandidates

    # three labels: the first under an eligible candidate, the second only under one whose peak is no
    # positive pose, the third under none
    matches = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 0]], bool)
    xy = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    evidence = np.zeros((3, len(EVIDENCE)))
    ignored = np.zeros(3, bool)
    assert PlaceCandidates(evidence, matches, ignored, xy, np.array([True, False, True])).within_reach() == 1
    assert PlaceCandidates(evidence, matches, ignored, xy).within_reach() == 2  # no eligibility: every one
    # however low the cut, the map finds no more than is within reach
    some = PlaceCandidates(evidence, matches, ignored, xy, np.array([True, False, True]))
    assert some.places(np.ones(3), 0.0, 0.45)[0] == some.within_reach()


class _Counted:
    """A room's candidates reduced to what the cut's walk reads: (found, labels, false) at each cut."""

    def __init__(self, false_below: float | None, found_below: float):
        self.false_below, self.found_below = false_below, found_below

    def places(self, probabilities, cut: float, radius: float) -> tuple[int, int, int]:
        false = int(self.false_below is not None and cut <= self.false_below + 1e-9)
        return int(cut <= self.found_below + 1e-9), 1, false


def test_a_cut_whose_false_places_meet_the_budget_exactly_is_taken_and_the_walk_goes_on():
    """Five rooms at a budget of 0.4 a room allow 2 false places: the cuts that give exactly 2 are within it,
    the first that gives 3 is not."""
    from affordcore.learn.thresholds import _walk

    rooms = [
        _Counted(0.3, 0.5),
        _Counted(0.3, 0.4),
        _Counted(0.2, 0.25),
        _Counted(None, 0.2),
        _Counted(None, 0.5),
    ]
    held_out = [np.zeros(1)] * len(rooms)
    # 0 false down to 0.35, 2 at 0.3 and 0.25 (the budget met exactly), 3 at 0.2
    assert _walk(rooms, [held_out], 0.4, 0.45, np.zeros(len(rooms), bool)) == (0.25, 4)
    # a budget a hair smaller stops before the first false place
    assert _walk(rooms, [held_out], 0.39, 0.45, np.zeros(len(rooms), bool)) == (0.35, 3)
    # the real rooms are held to the budget apart: the same false places in two real rooms of the five
    is_real = np.array([True, True, False, False, False])
    assert _walk(rooms, [held_out], 0.4, 0.45, is_real)[0] == 0.35


def test_the_cut_hangs_less_on_how_the_rooms_are_listed_when_judged_over_several_deals(monkeypatch):
    """The same rooms listed in other orders deal into other folds: judged on one deal the cut moves with the
    order; judged over `DEALS` deals it moves less."""
    import affordcore.learn.thresholds as thresholds

    rooms = _rooms_of_candidates(20, 5, overlap=1.5)
    orders = [np.random.default_rng(seed).permutation(len(rooms)) for seed in range(8)]

    def cuts() -> list[float]:
        return [thresholds.place_cut([rooms[k] for k in order], 0.5, 0.45) for order in orders]

    several = cuts()
    monkeypatch.setattr(thresholds, "DEALS", 1)
    one = cuts()
    assert len(set(one)) == 3 and len(set(several)) == 1, (one, several)  # 0.4-0.5 on one deal; 0.45
    assert min(one) < several[0] < max(one)


def _room_scores(place_scores, place_false, label_best, room: str = "r"):
    from affordcore.learn.thresholds import RoomScores

    return RoomScores(
        room=room,
        scores=np.zeros(1),
        labels=np.ones(1),
        place_scores=np.asarray(place_scores, float),
        place_false=np.asarray(place_false, bool),
        label_best=np.asarray(label_best, float),
        reference=0.0,
    )


def test_a_place_must_beat_the_cut_a_score_at_it_is_no_place():
    """Kept skeletons and found labels answer the same rule: above the cut, not at it; and a candidate whose
    peak is at a score is not eligible from it."""
    from affordcore.learn.thresholds import PlaceCandidates

    room = _room_scores([0.5, 0.7, 0.9], [False, True, False], [0.5, 0.9])
    assert room.places(0.5) == (1, 2, 1)  # the label whose best skeleton scores 0.5 is not found at 0.5
    assert room.places(0.49) == (2, 3, 1)
    candidates = PlaceCandidates(
        np.zeros((3, len(EVIDENCE))),
        np.zeros((1, 3), bool),
        np.zeros(3, bool),
        np.zeros((3, 2)),
        peaks=np.array([1.0, 0.5, 0.2]),
    )
    np.testing.assert_array_equal(candidates.eligible_from(0.5).eligible, [True, False, False])


def test_each_labelled_place_a_kept_candidate_stands_on_counts_once():
    """Three labels, two of them under kept candidates (one candidate on two labels), the third under a
    candidate too unlikely to keep: two places found, two kept, none false; an unmatched kept candidate is
    false unless it lies in an unlabelled region."""
    from affordcore.learn.thresholds import PlaceCandidates

    matches = np.array(
        [[True, False, False, False], [True, False, False, False], [False, True, False, False]]
    )
    xy = np.array([[0.0, 0.0], [5.0, 0.0], [10.0, 0.0], [15.0, 0.0]])
    ignored = np.array([False, False, False, True])
    candidates = PlaceCandidates(np.zeros((4, len(EVIDENCE))), matches, ignored, xy)
    assert candidates.places(np.array([0.9, 0.1, 0.8, 0.8]), 0.5, 0.45) == (2, 3, 1)
    matches[2, 1] = False
    assert candidates.places(np.array([0.9, 0.9, 0.1, 0.1]), 0.5, 0.45) == (2, 2, 1)


def test_one_generated_room_beside_the_real_ones_still_gives_the_real_ones_their_share():
    from affordcore.learn.thresholds import room_weights

    weights = room_weights(np.array([False, True]), 0.75)
    np.testing.assert_allclose(weights, [1.0, 3.0])  # the real room three quarters of the weight
    np.testing.assert_allclose(room_weights(np.array([True, True]), 0.75), [1.0, 1.0])  # no generated room


def test_the_place_threshold_reports_what_it_gives_per_room():
    """Two rooms: the best place F1 keeps the two true skeletons and drops the false one, and its figures
    are the places found of all labels and the false skeletons per room."""
    from affordcore.learn.thresholds import place_threshold

    rooms = [
        _room_scores([1.0, 0.3], [False, True], [1.0], "a"),
        _room_scores([0.8], [False], [0.8, -9.0], "b"),
    ]
    threshold, stats = place_threshold(rooms)
    assert threshold == pytest.approx(0.3)  # the candidates: above 0.3 keeps the two true ones
    assert stats == pytest.approx({"place_f1": 0.8, "place_recall": 2 / 3, "false_per_room": 0.0})
    # one false skeleton among the best-scoring ones: worth keeping all, and it is half a false one a room
    rooms = [
        _room_scores([1.0, 0.9, 0.8], [False, True, False], [1.0, 0.8], "a"),
        _room_scores([0.7], [False], [0.7]),
    ]
    _, stats = place_threshold(rooms)
    assert stats == pytest.approx({"place_f1": 2 * 0.75 / 1.75, "place_recall": 1.0, "false_per_room": 0.5})


def test_the_place_decision_holds_the_real_rooms_apart_and_weighs_them_by_their_share():
    """Generated rooms whose places stand out, real ones of pure noise: judged apart, the real rooms stop the
    walk higher than pooled ones would, the more so the more they weigh; the margin and the cut are the ones
    `place_cut` gives when every candidate is eligible."""
    from dataclasses import replace

    from affordcore.learn.thresholds import place_cut, place_decision

    generated = _rooms_of_candidates(40, 3, overlap=3.0, column=0)
    noisy_real = _rooms_of_candidates(5, 7, overlap=0.0, column=1)
    is_real = np.r_[np.zeros(40, bool), np.ones(5, bool)]
    rooms = [replace(c, peaks=np.full(len(c.xy), 10.0)) for c in [*generated, *noisy_real]]
    pooled = place_decision(rooms, 0.0, 1.0, 0.45)
    apart = place_decision(rooms, 0.0, 1.0, 0.45, is_real=is_real)
    assert pooled == (0.0, place_cut(rooms, 1.0, 0.45)) and apart == (
        0.0,
        place_cut(rooms, 1.0, 0.45, is_real=is_real),
    )
    assert pooled[1] < apart[1]
    shares = [place_cut(rooms, 1.0, 0.45, is_real=is_real, real_share=share) for share in (0.1, 0.5, 0.9)]
    assert shares == sorted(shares) and shares[0] < shares[2]
    assert place_decision(rooms, 0.0, 1.0, 0.45, is_real=is_real, real_share=0.9)[1] == shares[2]


def test_the_place_decision_lets_places_in_whose_peaks_fall_under_the_threshold_and_needs_two_folds():
    """True places peaking 0.6 under the pose threshold, false ones anywhere: the decision takes the
    smallest margin that lets them in (0.75); one room (no fold to judge on) keeps the calibrated 0.5 with no
    margin, as does a set of rooms holding only places."""
    from dataclasses import replace

    from affordcore.learn.thresholds import place_cut, place_decision

    rng = np.random.default_rng(0)
    generated = _rooms_of_candidates(40, 3, overlap=3.0, column=0)
    rooms = [
        replace(c, peaks=np.where(c.matches.any(axis=0), -0.6, rng.uniform(-2, 1, len(c.xy))))
        for c in generated
    ]
    margin, cut = place_decision(rooms, 0.0, 1.0, 0.45)
    assert margin == 0.75 and 0.2 <= cut <= 0.5
    assert (
        place_decision(rooms[:1], 0.0, 1.0, 0.45) == (0.0, 0.5) and place_cut(generated[:1], 1.0, 0.45) == 0.5
    )
    only_places = [replace(c, matches=np.ones_like(c.matches)) for c in rooms]
    assert place_decision(only_places, 0.0, 1.0, 0.45) == (0.0, 0.5)


def test_the_walk_counts_places_as_a_mean_over_the_deals_and_keeps_0_5_when_even_it_breaks_the_budget():
    from affordcore.learn.thresholds import PlaceCandidates, _walk

    def room(false_probability: float):
        evidence = np.zeros((2, len(EVIDENCE)))
        xy = np.array([[0.0, 0.0], [5.0, 0.0]])
        return PlaceCandidates(evidence, np.array([[True, False]]), np.zeros(2, bool), xy), np.array(
            [0.9, false_probability]
        )

    (a, pa), (b, pb) = room(0.42), room(0.27)
    two_deals = [[pa, pb], [pa, pb]]
    assert _walk([a, b], two_deals, 0.5, 0.45, np.zeros(2, bool)) == (0.3, 2.0)  # two places a deal
    (c, pc), (d, pd) = room(0.95), room(0.95)  # a phantom in each room at every cut
    assert _walk([c, d], [[pc, pd]], 0.1, 0.45, np.zeros(2, bool)) == (0.5, 2.0)


def test_the_deals_are_the_same_every_time_and_real_rooms_may_be_marked_by_0_and_1():
    """A cut is reproducible: the rooms are dealt into folds by fixed seeds, so two calls give the same
    held-out probabilities; and rooms marked real by 0 / 1 are judged as by False / True."""
    from affordcore.learn.thresholds import _dealt, place_cut

    generated = _rooms_of_candidates(40, 3, overlap=3.0, column=0)
    noisy_real = _rooms_of_candidates(5, 7, overlap=0.0, column=1)
    rooms, is_real = [*generated, *noisy_real], np.r_[np.zeros(40, bool), np.ones(5, bool)]
    first, second = _dealt(rooms, 5, is_real, 0.5), _dealt(rooms, 5, is_real, 0.5)
    for a, b in zip(first, second):
        for p, q in zip(a, b):
            np.testing.assert_array_equal(p, q)
    as_ints = [int(v) for v in is_real]
    assert place_cut(rooms, 1.0, 0.45, is_real=as_ints) == place_cut(rooms, 1.0, 0.45, is_real=is_real)


def test_one_room_s_false_skeletons_are_its_false_skeletons_per_room():
    from affordcore.learn.thresholds import place_threshold

    _, stats = place_threshold([_room_scores([1.0, 0.9, 0.8], [False, True, False], [1.0, 0.8])])
    assert stats["false_per_room"] == 1.0
