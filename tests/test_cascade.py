"""The second stage: trees stored as data score as scikit-learn does, a cascade model file round-trips,
and the place threshold is the best one."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import skeleton_document

from affordcore.learn.model import AffordanceModel, ModelError, load_model
from affordcore.learn.thresholds import RoomScores, place_floor, place_threshold
from affordcore.learn.trees import TreeEnsemble


@pytest.fixture(scope="module")
def boosted():
    from sklearn.ensemble import HistGradientBoostingClassifier

    rng = np.random.default_rng(0)
    X = rng.normal(size=(3000, 6)).astype(np.float32)
    y = (X[:, 0] * X[:, 1] + 0.3 * rng.normal(size=3000) > 0.8).astype(int)
    model = HistGradientBoostingClassifier(max_iter=40, max_depth=5, random_state=0).fit(X, y)
    return model, X


def test_stored_trees_score_as_scikit_learn(boosted):
    model, X = boosted
    trees = TreeEnsemble.from_dict(TreeEnsemble.from_sklearn(model).to_dict())
    np.testing.assert_allclose(trees.log_odds(X), model.decision_function(X), atol=1e-9)
    # NaN follows each split's missing-value side, as scikit-learn's does
    X_nan = X[:50].copy()
    X_nan[::3, 0] = np.nan
    np.testing.assert_allclose(trees.log_odds(X_nan), model.decision_function(X_nan), atol=1e-9)


def test_the_complete_layout_reaches_the_leaves_the_node_tables_reach(boosted, monkeypatch):
    """The walk over complete trees (float32 thresholds for float32 rows) gives the node tables' walk's
    values to the bit, at every split's threshold and one float step either side of it, and with NaN."""
    import affordcore.learn.trees as trees_module

    model, X = boosted
    complete = TreeEnsemble.from_sklearn(model)
    assert complete._complete is not None  # laid out now, while the limit allows it
    monkeypatch.setattr(trees_module, "COMPLETE_POSITIONS", 0)
    tables = TreeEnsemble.from_sklearn(model)
    assert tables._complete is None
    splits = np.flatnonzero(complete.feature >= 0)
    edges = complete.threshold[splits].astype(np.float32)
    rows = np.repeat(X[:1], 3 * len(splits), axis=0)
    for k, step in enumerate((-np.inf, None, np.inf)):  # below, at (rounded to float32), above
        near = edges if step is None else np.nextafter(edges, np.float32(step))
        rows[k * len(splits) + np.arange(len(splits)), complete.feature[splits]] = near
    finite = np.concatenate([rows, X])  # walked without reading the splits' missing sides
    rows = finite.copy()
    rows[::7, 1] = np.nan
    for sample in (finite, rows, finite.astype(np.float64), rows.astype(np.float64)):
        np.testing.assert_array_equal(complete.log_odds(sample), tables.log_odds(sample))
    np.testing.assert_allclose(complete.log_odds(rows), model.decision_function(rows), atol=1e-9)


def test_malformed_tree_tables_are_refused(boosted):
    document = TreeEnsemble.from_sklearn(boosted[0]).to_dict()
    document["nodes"]["left"][0] = 10**6
    with pytest.raises(ValueError, match="links outside"):
        TreeEnsemble.from_dict(document)
    document = TreeEnsemble.from_sklearn(boosted[0]).to_dict()
    document["depth"] = -1
    with pytest.raises(ValueError, match="depth of -1"):
        TreeEnsemble.from_dict(document)


def _cascade_model(trees: TreeEnsemble, n_features: int) -> AffordanceModel:
    return AffordanceModel(
        affordance="sitting-relaxing",
        layout={"n_features": n_features},
        fingerprint="f",
        weights=np.arange(n_features, dtype=float),
        bias=0.5,
        threshold=0.1,
        learner="cascade",
        place_threshold=0.7,
        rescorer={"fraction": 0.03, "trees": trees.to_dict()},
        skeleton=skeleton_document(),
    )


def test_a_cascade_model_file_round_trips_and_a_broken_one_is_named(boosted, tmp_path):
    model = _cascade_model(TreeEnsemble.from_sklearn(boosted[0]), 6)
    path = model.save(tmp_path / "m.model.json")
    back = load_model(path)
    assert back.id == model.id and back.skeleton_threshold == 0.7
    np.testing.assert_array_equal(back.trees.log_odds(boosted[1][:20]), model.trees.log_odds(boosted[1][:20]))
    other = _cascade_model(TreeEnsemble.from_sklearn(boosted[0]), 6)
    other.place_threshold = 0.8
    assert other.id != model.id  # the id names the whole model, second stage included
    good = path.read_text()
    for broken, message in (
        (good.replace('"roots": [', '"roots": [99999, '), "m.model.json"),
        (good.replace('"fraction": 0.03', '"fraction": 1.5'), "fraction must lie in"),
        (
            good.replace('"fraction": 0.03', '"fraction": 0.03, "max_poses": -4'),
            "max_poses must be a positive",
        ),
        (good.replace('"fraction": 0.03', '"fraction": 0.03, "local_detail": "yes"'), "true or false"),
    ):
        path.write_text(broken)
        with pytest.raises(ModelError, match=message):
            load_model(path)


def test_a_model_whose_trees_split_past_the_end_of_their_rows_is_refused(boosted, tmp_path):
    """The trees' kernel reads rows unchecked, so a split on a column the second stage does not make must be
    refused when the file is read, naming both widths; the fine columns widen the rows they may split on."""
    from affordcore.geometry.columns import N_FEATURES

    trees = TreeEnsemble.from_sklearn(boosted[0])  # splits on features up to 5
    assert trees.n_features_used == 6
    narrow = _cascade_model(trees, 4).save(tmp_path / "narrow.model.json")
    with pytest.raises(ModelError, match="split on feature 5; the second stage's rows have 4"):
        load_model(narrow)
    detailed = _cascade_model(trees, 4)
    detailed.rescorer = {**detailed.rescorer, "local_detail": True}
    assert load_model(detailed.save(tmp_path / "detailed.model.json")).second_stage_width == 4 + N_FEATURES


def test_the_second_stage_takes_the_best_fraction_of_the_candidates_and_at_most_max_poses():
    from affordcore.mapping.inference import best_poses
    from affordcore.mapping.maps import RULED_OUT

    scores = np.random.default_rng(0).normal(size=1000).astype(np.float32)
    scores[::2] = RULED_OUT  # 500 candidates
    best = best_poses(scores, 0.03)
    assert len(best) == 15 and scores[best].min() >= np.sort(scores[scores > RULED_OUT])[-15]
    capped = best_poses(scores, 0.03, max_poses=4)
    assert sorted(capped) == sorted(best[np.argsort(scores[best])[-4:]])
    assert len(best_poses(np.full(10, RULED_OUT, np.float32), 0.5)) == 0


def test_a_map_setting_caps_the_poses_the_trees_rescore_to_the_first_stages_best():
    from affordcore.example import example_room
    from affordcore.learn.model import shipped_models
    from affordcore.mapping.maps import RULED_OUT
    from affordcore.mapping.pipeline import RoomMapper, prepare_scene
    from affordcore.settings import Settings

    model = load_model(shipped_models()["sitting-working"])
    scene = prepare_scene(example_room(), Settings(), "none")
    rescored = {}
    for cap in (None, 2000):
        settings = Settings(map={"rescore_max_poses": cap})
        _, scores = RoomMapper([model], scene.layout, settings).scores(model, scene.fields)
        rescored[cap] = scores.ravel()
    full, capped = (np.flatnonzero(rescored[c] > RULED_OUT) for c in (None, 2000))
    assert len(full) > 2000 and len(capped) == 2000
    assert np.isin(capped, full).all()  # a subset, each pose scored by the same trees
    np.testing.assert_array_equal(rescored[2000][capped], rescored[None][capped])


def test_the_place_threshold_maximises_place_f1():
    # room a: two labels found by skeletons scoring 0.9 and 0.4, false skeletons at 0.6 and 0.2
    # room b: no label, one false skeleton at 0.5
    rooms = [
        RoomScores("a", np.zeros(0), np.zeros(0), np.array([0.9, 0.4, 0.6, 0.2]),
                   np.array([False, False, True, True]), np.array([0.9, 0.4]), 0.0),
        RoomScores("b", np.zeros(0), np.zeros(0), np.array([0.5]), np.array([True]), np.zeros(0), 0.0),
    ]  # fmt: skip
    threshold, stats = place_threshold(rooms)

    def place_f1(t):
        kept = sum(int((r.place_scores > t).sum()) for r in rooms)
        false = sum(int((r.place_false & (r.place_scores > t)).sum()) for r in rooms)
        found = sum(int((r.label_best > t).sum()) for r in rooms)
        recall, precision = found / 2, (kept - false) / kept if kept else 0.0
        return 2 * recall * precision / (recall + precision) if recall + precision else 0.0

    best = max(place_f1(t) for t in np.linspace(-1, 1, 2001))
    assert stats["place_f1"] == pytest.approx(best) and place_f1(threshold) == pytest.approx(best)
    # with nothing to find, the threshold keeps no skeleton at all
    threshold, stats = place_threshold(rooms[1:])
    assert stats["false_per_room"] == 0 and threshold >= 0.5


def test_a_relative_place_threshold_moves_with_a_room_whose_scores_all_drop():
    # the same two rooms, room a scanned unlike the training rooms: every score (its median too) 2 lower
    def room(name, places, false, labels, shift):
        return RoomScores(name, np.zeros(0), np.zeros(0), np.array(places) + shift, np.array(false),
                          np.array(labels) + shift, shift)  # fmt: skip

    same = [room("a", [0.9, 0.4, 0.6, 0.2], [False, False, True, True], [0.9, 0.4], 0.0),
            room("b", [0.5], [True], [], 0.0)]  # fmt: skip
    dropped = [room("a", [0.9, 0.4, 0.6, 0.2], [False, False, True, True], [0.9, 0.4], -2.0), same[1]]
    _, absolute = place_threshold(same)
    threshold, relative = place_threshold(dropped, relative=True)
    assert relative == absolute  # counted from each room's median, the drop changes nothing
    _, carried = place_threshold(dropped)
    assert carried["place_recall"] < absolute["place_recall"] or carried["false_per_room"] > 0
    # a model applies it the same way: the cut is the threshold above the room's median candidate score
    found, kept, false = dropped[0].places(threshold + dropped[0].reference)
    assert (found, kept - false) == (round(relative["place_recall"] * 2), found)


def test_a_place_floor_stops_phantoms_in_a_room_whose_scores_all_run_low():
    # room a holds two places, room b none: its median is far lower, so the relative cut (0.1 above each
    # median) lets its best non-places through; an absolute floor keeps them out and keeps a's places
    def room(name, places, false, labels, reference):
        return RoomScores(name, np.zeros(0), np.zeros(0), np.array(places), np.array(false),
                          np.array(labels), reference)  # fmt: skip

    rooms = [room("a", [2.0, 1.8, 1.2], [False, False, True], [2.0, 1.8], 1.0),
             room("b", [0.9, 0.7], [True, True], [], 0.0)]  # fmt: skip
    relative, before = place_threshold(rooms, relative=True)
    assert before["false_per_room"] > 0  # b's 0.9 and 0.7 beat its median + the relative threshold
    floor, after = place_floor(rooms, relative)
    assert after["place_f1"] == 1.0 and after["false_per_room"] == 0 and 0.9 <= floor < 1.8
    # where the relative cut alone is best, there is no floor
    assert place_floor(rooms[:1], place_threshold(rooms[:1], relative=True)[0])[0] is None


def _weighted_rows(seed: int, rows: int = 6000):
    """Rows like the second stage's: continuous columns, ties, a few distinct values, NaN, zero weights,
    negatives weighted up."""
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(rows, 5))
    X[:, 1] = np.round(X[:, 1], 1)  # ties
    X[:, 2] = rng.integers(0, 7, rows)  # fewer distinct values than bins: midpoints
    X[rng.random(rows) < 0.1, 3] = np.nan
    y = (X[:, 0] + 0.5 * rng.normal(size=rows) > 1.2).astype(int)
    weight = np.where(y > 0, 1.0, rng.choice([1.0, 7.5, 30.0], rows))
    weight[rng.random(rows) < 0.02] = 0.0
    return X, y, weight


def test_fast_weighted_binning_gives_scikit_learns_thresholds_and_trees():
    pytest.importorskip("sklearn")
    import sklearn
    from sklearn.ensemble._hist_gradient_boosting import binning

    from affordcore.learn.binning import _binning_module, fast_weighted_binning
    from affordcore.learn.cascade import TreeSettings, tree_classifier

    if _binning_module() is None:
        # 1.6-1.9 (the versions whose weighted binner asks one percentile at a time) must be recognised
        assert not (1, 6) <= tuple(int(p) for p in sklearn.__version__.split(".")[:2]) <= (1, 9)
        pytest.skip(f"scikit-learn {sklearn.__version__}'s binner is not the one this replaces")
    X, y, weight = _weighted_rows(1)
    original = binning._find_binning_thresholds
    with fast_weighted_binning():
        assert binning._find_binning_thresholds is not original
        fast = [binning._find_binning_thresholds(X[:, f], 255, sample_weight=weight) for f in range(5)]
    assert binning._find_binning_thresholds is original  # put back after the block
    for f in range(5):
        np.testing.assert_array_equal(fast[f], original(X[:, f], 255, sample_weight=weight))
    settings = TreeSettings(max_iter=15)
    plain = tree_classifier(settings, 3).fit(X, y, sample_weight=weight)
    with fast_weighted_binning():
        patched = tree_classifier(settings, 3).fit(X, y, sample_weight=weight)
    plain, patched = TreeEnsemble.from_sklearn(plain).to_dict(), TreeEnsemble.from_sklearn(patched).to_dict()
    assert patched == plain


def test_second_stage_rows_are_joined_into_float64_in_order_and_let_go():
    from affordcore.learn.cascade import _joined_float64

    rng = np.random.default_rng(2)
    parts = [rng.normal(size=(n, 4)).astype(np.float32) for n in (3, 0, 5, 1)]
    expected = np.concatenate(parts).astype(np.float64)
    joined = _joined_float64(parts)
    np.testing.assert_array_equal(joined, expected)
    assert joined.dtype == np.float64 and parts == []  # each room's rows were let go once copied
    with pytest.raises(ValueError, match="no training room"):
        _joined_float64([])


def test_the_cascade_refuses_examples_that_come_without_their_rooms():
    """Its second stage learns from the first stage's best poses of each room: rows alone cannot train it."""
    from types import SimpleNamespace

    from affordcore.learn.cascade import fit_cascade

    with pytest.raises(ValueError, match="^the cascade learns from rooms: train it with `afford train`"):
        fit_cascade(SimpleNamespace(task=None, rooms=[]), None, {}, None, None)
