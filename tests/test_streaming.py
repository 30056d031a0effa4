"""The learning loop that streams: rooms' fields and sampled rows in a cache on disk, read one room at a time,
and the same models as when every room is held in memory."""

from __future__ import annotations

import gc
import json
import weakref

import numpy as np
import pytest

from affordcore.geometry.features import FeatureLayout
from affordcore.geometry.scene import origins_file
from affordcore.learn import examples as examples_module
from affordcore.learn.cache import RoomCache
from affordcore.learn.evaluate import evaluate
from affordcore.learn.examples import (
    ExampleSet,
    Task,
    data_set_rooms,
    example_set,
    load_rooms,
    split_examples,
    stack,
)
from affordcore.learn.train import train
from affordcore.settings import FeatureSettings, GridSettings, LearnSettings, Settings
from affordcore.synth.batch import synthesize
from affordcore.synth.dataset import SynthOptions

pytestmark = pytest.mark.slow  # each trains or caches three rooms more than once


@pytest.fixture(scope="module")
def data_set(tmp_path_factory):
    folder = tmp_path_factory.mktemp("rooms")
    synthesize(SynthOptions(3, 11, ("workshop",), scanner="uniform"), folder, workers=1)
    return folder


@pytest.fixture(scope="module")
def held_rooms(data_set):
    """The rooms at `_settings()`, fields held in memory (no test changes them)."""
    return load_rooms(data_set_rooms(data_set), _settings())


@pytest.fixture(scope="module")
def stored(tmp_path_factory, data_set) -> RoomCache:
    """A cache holding the rooms' fields at `_settings()`, written once for the tests that only read it."""
    cache = RoomCache(tmp_path_factory.mktemp("stored"))
    load_rooms(data_set_rooms(data_set), _settings(), cache=cache)
    return cache


FAST = {"max_iter": 20}  # trees enough to show the same ones are fitted


def _settings(**learn) -> Settings:
    return Settings(
        features=FeatureSettings(cell_size=0.5),
        grid=GridSettings(n_theta=8, theta_step=np.pi / 4),
        learn=LearnSettings(**{"workers": 1, **learn}),
    )


def _affordance(folder) -> str:
    return json.loads(next(folder.glob("*.labels.json")).read_text())["labels"][0]["affordance"]


def test_a_streamed_cascade_is_the_model_trained_in_memory(data_set, tmp_path):
    """Same seeds, same sampled rows, same rows kept by `stack`: the model file is the same, whether the rooms
    are held, written to the cache or read back from it."""
    affordance = _affordance(data_set)
    settings = _settings(max_negatives=3000)  # below the rooms' sampled negatives: stack subsamples
    held = train(data_set, affordance, "cascade", settings, FAST, seed=3)
    cache = RoomCache(tmp_path / "cache")
    written = train(data_set, affordance, "cascade", settings, FAST, seed=3, cache=cache)
    read_back = train(data_set, affordance, "cascade", settings, FAST, seed=3, cache=cache)
    assert len(list((tmp_path / "cache" / "fields").glob("*.npz"))) == 3
    assert len(list((tmp_path / "cache" / "examples").glob("*.npz"))) == 3
    assert held.training["negatives"] == 3000
    assert len(held.trees.roots) == FAST["max_iter"]  # the trees' settings reach the trees (no early stop)
    texts = [
        m.save(tmp_path / f"{i}.model.json").read_text() for i, m in enumerate((held, written, read_back))
    ]
    assert texts[1] == texts[0] and texts[2] == texts[0]


def test_cached_rooms_hold_no_fields_and_read_back_the_same(data_set, held_rooms, stored):
    held = held_rooms
    cached = load_rooms(data_set_rooms(data_set), _settings(), cache=stored)
    for a, b in zip(held, cached):
        assert b.held_fields is None and b.fields_path.exists()
        fields = b.fields
        assert fields.lattice.shape == a.fields.lattice.shape and fields.footprint == a.fields.footprint
        for name in ("occupancy", "distance", "normals"):
            np.testing.assert_array_equal(getattr(fields, name), getattr(a.fields, name))
        np.testing.assert_array_equal(fields.lattice.origin, a.fields.lattice.origin)


def test_a_changed_setting_cloud_or_layout_is_a_new_cache_entry(data_set, tmp_path):
    cache = RoomCache(tmp_path)
    files = data_set_rooms(data_set)[:1]
    affordance = _affordance(data_set)
    base = _settings()
    (room,) = load_rooms(files, base, cache=cache)
    (same,) = load_rooms(files, _settings(workers=2), cache=cache)  # how many workers changes nothing
    (finer,) = load_rooms(
        files, _settings().model_copy(update={"grid": GridSettings(n_theta=4)}), cache=cache
    )
    assert same.fields_path == room.fields_path and finer.fields_path != room.fields_path

    def examples_path(settings, layout=None):
        task = Task(affordance, settings, layout or FeatureLayout.from_settings(settings))
        return example_set([room], task, cache=cache)._stored[room.name][1]

    first = examples_path(base)
    assert examples_path(base) == first
    assert examples_path(_settings(negatives_per_room=50)) != first
    assert examples_path(base, FeatureLayout(1.0, 0.25, 0.1)) != first

    changed = tmp_path / "changed"
    changed.mkdir()
    for source in (files[0].cloud, files[0].labels, origins_file(files[0].cloud)):
        (changed / source.name).write_bytes(source.read_bytes())
    (moved,) = load_rooms(data_set_rooms(changed), base, cache=cache)
    assert moved.fields_path == room.fields_path  # the same bytes elsewhere: the same entry
    with open(changed / files[0].cloud.name, "ab") as f:
        f.write(b"\n")  # a different file: a new entry, never the old fields
    (edited,) = load_rooms(data_set_rooms(changed), base, cache=cache)
    assert edited.fields_path != room.fields_path
    origins_file(changed / files[0].cloud.name).unlink()  # the sensor positions are part of the room
    (unseen,) = load_rooms(data_set_rooms(changed), base, cache=cache)
    assert unseen.fields_path != edited.fields_path


def test_stack_reads_one_room_at_a_time_and_keeps_the_same_rows(data_set, held_rooms, stored, monkeypatch):
    settings = _settings()
    affordance = _affordance(data_set)
    task = Task(affordance, settings, FeatureLayout.from_settings(settings))
    files = data_set_rooms(data_set)
    names = [f.name for f in files]
    held = split_examples({r.name: r for r in held_rooms}, names[:2], names[2:], task)
    streamed = split_examples(
        {r.name: r for r in load_rooms(files, settings, cache=stored)}, names[:2], names[2:], task, stored
    )
    assert isinstance(streamed, ExampleSet) and list(streamed) == names
    alive, most = [], [0]
    read = examples_module.load_example_rows

    def counted(path):
        gc.collect()
        # every room read before is let go before the next is read
        most[0] = max(most[0], sum(r() is not None for r in alive) + 1)
        rows = read(path)
        alive.append(weakref.ref(rows))
        return rows

    monkeypatch.setattr(examples_module, "load_example_rows", counted)
    a = stack(held, names, 400, np.random.default_rng(5))
    b = stack(streamed, names, 400, np.random.default_rng(5))
    assert len(alive) == 3 and most[0] == 1
    for field in ("X", "y", "weight"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert [r.name for r in b.rooms] == names and all(r.held_fields is None for r in b.rooms)


def test_a_streamed_evaluation_gives_the_same_results(data_set, stored):
    affordance = _affordance(data_set)
    settings = _settings()
    # held in memory, one process; from the cache, trainings in two processes
    runs = [
        evaluate(data_set, [affordance], ["linear-tuned"], 3, s, ratios=(4,), cache=cache)
        for s, cache in ((settings, None), (_settings(workers=2), stored))
    ]
    same = [
        [(o.learner, o.fold, o.ratio, o.precision, o.recall, o.f1, o.train_ratio) for o in r.outcomes]
        for r in runs
    ]
    assert same[0] == same[1] and len(same[0]) == 4
    assert runs[0].class_counts == runs[1].class_counts
