"""Model files round-trip, and refuse to run against another feature layout."""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest
from conftest import skeleton_document

from affordcore.geometry.features import FeatureLayout
from affordcore.learn.model import KEPT_TEXTS, AffordanceModel, ModelError, load_model


def _model(layout: FeatureLayout) -> AffordanceModel:
    rng = np.random.default_rng(0)
    return AffordanceModel(
        affordance="leaning",
        layout=layout.describe(),
        fingerprint=layout.fingerprint,
        weights=rng.normal(size=layout.n_features),
        bias=-0.3,
        threshold=0.1,
        learner="ssvm",
        parameters={"C": 1e7},
        training={"rooms": ["a", "b"], "class_counts": {"positives": 10, "negatives": 9990}},
        validation={"precision": 0.5, "recall": 0.6, "f1": 0.545},
        skeleton=skeleton_document(),
    )


def test_round_trip(tmp_path):
    layout = FeatureLayout(cell_size=0.25)
    model = _model(layout)
    loaded = load_model(model.save(tmp_path / "m.json"), layout)
    np.testing.assert_array_equal(loaded.weights, model.weights)
    assert (loaded.bias, loaded.threshold, loaded.learner, loaded.validation) == (
        model.bias,
        model.threshold,
        "ssvm",
        model.validation,
    )
    X = np.random.default_rng(1).normal(size=(5, layout.n_features)).astype(np.float32)
    np.testing.assert_allclose(loaded.decision(X), model.decision(X), rtol=1e-6)


def test_another_layout_is_refused_with_both_layouts_named(tmp_path):
    path = _model(FeatureLayout(cell_size=0.25)).save(tmp_path / "m.json")
    with pytest.raises(
        ModelError,
        match=r"m.json: trained on .*222 features, 0.25 m cells.* computes .*3030 features, 0.1 m cells",
    ):
        load_model(path, FeatureLayout())


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda d: d.update(format="other/9"), "not an affordance-model/3"),
        (lambda d: d.pop("weights"), "malformed"),
        (lambda d: d.update(weights=[1.0, 2.0]), "2 weights for a layout of 222"),
        (lambda d: d.update(surprise=1), "malformed"),
        (lambda d: d.update(place_reference="room-mean"), "malformed.*place_reference"),
        # each field of its type, the wrong one named
        (lambda d: d.update(bias="abc"), r"malformed model: bias: .*number.*'abc'"),
        (lambda d: d.update(threshold=None), r"malformed model: threshold: .*number.*None"),
        (lambda d: d.update(layout=[]), r"malformed model: layout: .*dictionary"),
        (lambda d: d["layout"].pop("n_features"), r"malformed model: layout.n_features: Field required"),
        (lambda d: d.update(place_floor=float("nan")), r"malformed model: place_floor: .*finite"),
        (lambda d: d["weights"].__setitem__(3, "1.5"), r"malformed model: weights.3: .*number"),
        (lambda d: d["skeleton"]["joints"].pop(), r"malformed model: skeleton.joints: .*15 items"),
        (lambda d: d["skeleton"]["joints"][2].append(0.0), r"malformed model: skeleton.joints.2: .*3 items"),
        (
            lambda d: d["skeleton"].update(torso_height=-1),
            r"malformed model: skeleton.torso_height: .*greater",
        ),
        (lambda d: d.update(rescorer=[]), r"malformed model: rescorer: .*dictionary"),
    ],
)
def test_bad_files_are_named_errors(tmp_path, mutate, message):
    path = _model(FeatureLayout(cell_size=0.25)).save(tmp_path / "m.json")
    document = json.loads(path.read_text())
    mutate(document)
    path.write_text(json.dumps(document))
    with pytest.raises(ModelError, match=message):
        load_model(path)


def test_missing_file(tmp_path):
    with pytest.raises(ModelError, match="cannot read"):
        load_model(tmp_path / "none.json")


def test_a_relative_place_threshold_counts_from_the_room_s_median_candidate_score(tmp_path):
    from affordcore.mapping.maps import RULED_OUT

    layout = FeatureLayout(cell_size=0.25)
    model = _model(layout)
    model.place_threshold, model.place_reference = 0.5, "room-median"
    scores = np.array([[RULED_OUT, 1.0], [2.0, 3.0], [RULED_OUT, RULED_OUT]], dtype=np.float32)
    assert model.place_cut(scores) == pytest.approx(2.5)  # ruled-out poses are no candidates
    assert model.place_cut(np.full(3, RULED_OUT, np.float32)) == pytest.approx(0.5)
    loaded = load_model(model.save(tmp_path / "m.json"), layout)
    assert loaded.place_cut(scores) == pytest.approx(2.5) and loaded.id == model.id
    model.place_reference = None
    assert model.place_cut(scores) == pytest.approx(0.5) and model.id != loaded.id


def test_a_place_floor_raises_a_low_room_s_cut_and_travels_with_the_model(tmp_path):
    layout = FeatureLayout(cell_size=0.25)
    model = _model(layout)
    model.place_threshold, model.place_reference = 0.5, "room-median"
    unfloored = model.id
    model.place_floor = 1.0
    assert model.place_cut_from(2.0) == pytest.approx(2.5)  # above the floor: the relative cut
    assert model.place_cut_from(-3.0) == pytest.approx(1.0)  # a room whose scores run low: the floor
    loaded = load_model(model.save(tmp_path / "m.json"), layout)
    assert loaded.place_floor == 1.0 and loaded.id == model.id != unfloored


def test_a_new_place_model_is_the_one_the_model_answers_with():
    """A refit gives a model another place model: `places` must follow it, not keep the first one it made
    (a cached copy did, and the refit reported the old cut and figures beside the new coefficients)."""
    from affordcore.learn.model import shipped_models

    model = load_model(shipped_models()["sitting-working"])
    before = model.places
    assert model.places is before  # made once while the document stays
    model.place_model = {**model.place_model, "cut": 0.35, "intercept": model.place_model["intercept"] - 1}
    assert model.places.cut == 0.35 and model.places.intercept == pytest.approx(before.intercept - 1)
    model.place_model = None
    assert model.places is None


def test_a_model_s_id_follows_a_replaced_place_model_and_rescorer_and_keeps_the_saved_id(tmp_path):
    """An id serialises the trees once per rescorer dict (every map names its model): replacing the place
    model or the rescorer must still change it, and a model read back has the same id."""
    from affordcore.learn.model import shipped_models

    model = load_model(shipped_models()["sitting-working"])
    first = model.id
    assert model.id == first == load_model(model.save(tmp_path / "m.json")).id
    model.place_model = {**model.place_model, "cut": 0.35}
    changed = model.id
    assert changed != first
    assert changed == load_model(model.save(tmp_path / "n.json")).id  # read back: serialised afresh
    model.rescorer = {**model.rescorer, "max_poses": 6000}
    assert model.id not in (first, changed)
    model.place_model = None
    assert model.id == load_model(model.save(tmp_path / "o.json")).id
    sent = pickle.loads(pickle.dumps(model))  # to a worker process: the same model, without the kept texts
    assert not set(KEPT_TEXTS) & set(vars(sent)) and sent.id == model.id


def test_the_shipped_models_record_the_split_they_were_trained_for(tmp_path):
    """`accuracy.py --shipped` scores the shipped models on the test rooms their files name, so the record
    must be the recipe's: `afford synth` rooms of the default seed and count, every scan style, and the
    held-out rooms exactly the ones `split_by_index` deals to test (none of them trained or validated on); a
    rebuild's record (`data_record` of the data set's summary) says the same."""
    import json

    from affordcore.learn.defaults import (
        ROOMS,
        SEED,
        TEST,
        VALIDATION,
        data_record,
        data_set_styles,
        split_by_index,
    )
    from affordcore.learn.model import shipped_models
    from affordcore.synth.dataset import SynthOptions
    from affordcore.synth.styles import STYLES

    options = SynthOptions(ROOMS, SEED)
    _, _, test = split_by_index([options.room_name(i) for i in range(ROOMS)], VALIDATION, TEST)
    for affordance, path in shipped_models().items():
        data = load_model(path).parameters["data"]
        assert (data["generator"], data["rooms"], data["seed"]) == ("afford synth", ROOMS, SEED), affordance
        assert data["styles"] == list(STYLES), affordance
        assert data["held_out_test_rooms"] == test, affordance
    (tmp_path / "summary.json").write_text(json.dumps({"rooms": ROOMS, "styles": list(STYLES)}))
    assert data_record(ROOMS, SEED, test, data_set_styles(tmp_path)) == data


def test_a_rebuild_trains_on_rooms_it_generates_with_their_cache_beside_them_and_keeps_neither(
    tmp_path, monkeypatch
):
    """`afford models rebuild` generates the recipe's rooms into a temporary folder and trains there with
    the rooms' cache inside it: nothing of it lands in the user's learn.cache_dir, and all of it goes
    after."""
    from pathlib import Path

    from affordcore.learn import defaults
    from affordcore.synth import batch

    seen = {}

    def synthesize(options, out, workers):
        seen.update(options=options, data=Path(out), workers=workers)

    def train(data, out, learners, seed, on_step, cache, real):
        seen.update(train_data=data, cache=cache.folder, seed=seed, real=real, exists=data.is_dir())
        return [out / "m.model.json"]

    monkeypatch.setattr(batch, "synthesize", synthesize)
    monkeypatch.setattr(defaults, "train_default_models", train)
    said = []
    written = defaults.rebuild_default_models(tmp_path, rooms=120, seed=7, workers=2, on_step=said.append)
    assert written == [tmp_path / "m.model.json"] and said == ["120 rooms generated"]
    assert (seen["options"].rooms, seen["options"].seed, seen["workers"]) == (120, 7, 2)
    assert seen["train_data"] == seen["data"] and seen["cache"] == seen["data"] / "cache" and seen["exists"]
    assert seen["seed"] == 7 and seen["real"] is None
    assert not seen["data"].exists()  # the rooms and their cache went with the rebuild
