"""`ForkedRoomMapper` (the inference service's models scored in worker processes) gives the `RoomMapper`'s
maps, in the models' order, each handed on as it comes; updates stay exact in the workers; errors come back
and leave the workers ready for the next fields."""

from __future__ import annotations

import dataclasses
import os
import sys

import numpy as np
import pytest

from affordcore.example import example_room
from affordcore.geometry.features import FeatureLayout
from affordcore.learn.model import choose_models
from affordcore.mapping.pipeline import RoomMapper, Superseded, prepare_scene
from affordcore.mapping.workers import ForkedRoomMapper, mapping_workers
from affordcore.settings import Settings

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="workers are forked on Linux")


@pytest.fixture(scope="module")
def room():
    settings = Settings()
    scene = prepare_scene(example_room(), settings, "none")
    models = choose_models([], [], FeatureLayout.from_settings(settings))
    return scene, models, settings


def assert_same_map(a, b) -> None:
    for name in ("scores", "confidence", "positives", "skeletons", "probabilities"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_workers_map_as_one_process(room):
    scene, models, settings = room
    serial = RoomMapper(models, scene.layout, settings).maps(scene.fields)
    mapper = ForkedRoomMapper(models, scene.layout, settings, workers=2)  # 3 models dealt to 2 workers
    try:
        mapper.warm_up()  # a made-up room, mapped and forgotten: nothing of it is updated from
        assert mapper.reports == {}
        heard = []
        maps = mapper.maps(scene.fields, on_map=lambda affordance, _: heard.append(affordance))
        assert list(maps) == list(serial) and sorted(heard) == sorted(serial)
        assert mapper.describe(list(maps)).startswith("scored in full"), mapper.describe(list(maps))
        for affordance in serial:
            assert_same_map(maps[affordance], serial[affordance])
        # the same fields again: an update in each worker, nothing rescored, the same maps
        again = mapper.maps(scene.fields, models=models[1:])
        assert list(again) == [m.affordance for m in models[1:]]
        assert mapper.describe(list(again)) == "updated: 0 % of the poses rescored"
        for affordance, amap in again.items():
            assert_same_map(amap, serial[affordance])
    finally:
        mapper.close()


def test_an_error_comes_back_and_the_next_call_starts_clean(room):
    scene, models, settings = room
    mapper = ForkedRoomMapper(models[:2], scene.layout, settings, workers=2)
    try:

        def failing(affordance, _):
            raise OSError(f"cannot publish {affordance}")

        with pytest.raises(OSError, match="cannot publish"):
            mapper.maps(scene.fields, on_map=failing)
        other = "floor" if scene.layout.steep_facing != "floor" else "centre"
        with pytest.raises(ValueError, match="steep normals"):  # raised in the workers
            mapper.maps(dataclasses.replace(scene.fields, steep_facing=other))
        estimator = "cube" if scene.layout.normal_estimator != "cube" else "nearest"
        with pytest.raises(ValueError, match="normals by"):
            mapper.maps(dataclasses.replace(scene.fields, normal_estimator=estimator))
        maps = mapper.maps(scene.fields)  # the pipes hold nothing left over from the failures
        assert list(maps) == [m.affordance for m in models[:2]]
    finally:
        mapper.close()


def test_maps_given_up_for_newer_fields_leave_the_room_as_the_last_maps_did(room):
    """`cancel` from another thread (here the first map's hand-on) gives up the rest of the call: the models
    not reached keep no state of it, and the next call maps as a fresh mapper does."""
    scene, models, settings = room
    serial = RoomMapper(models, scene.layout, settings).maps(scene.fields)
    mapper = RoomMapper(models, scene.layout, settings)
    heard = []

    def first_then_cancel(affordance, _):
        heard.append(affordance)
        mapper.cancel()

    with pytest.raises(Superseded):
        mapper.maps(scene.fields, on_map=first_then_cancel)
    assert heard == [models[0].affordance] and list(mapper.states) == heard
    mapper.cancel()  # between calls: gives up nothing to come
    maps = mapper.maps(scene.fields)
    for affordance in serial:
        assert_same_map(maps[affordance], serial[affordance])


def test_workers_give_up_a_call_through_the_shared_flag(room):
    scene, models, settings = room
    serial = RoomMapper(models, scene.layout, settings).maps(scene.fields)
    mapper = ForkedRoomMapper(models, scene.layout, settings, workers=2)
    try:
        mapper.cancelled_through.value = mapper.call + 1  # the call to come, as `cancel` would mark it
        heard = []
        with pytest.raises(Superseded):
            mapper.maps(scene.fields, on_map=lambda affordance, _: heard.append(affordance))
        assert heard == []  # every worker gave up at its first checkpoint
        maps = mapper.maps(scene.fields)  # the next call is not given up, and maps from clean states
        for affordance in serial:
            assert_same_map(maps[affordance], serial[affordance])
        assert mapper.describe(list(maps)).startswith("scored in full")
    finally:
        mapper.close()


def test_worker_count():
    assert mapping_workers(3, asked=1) == 1
    assert mapping_workers(3, asked=5) == 3
    assert 1 <= mapping_workers(3) <= 3


def test_workers_are_forked_one_per_model_on_linux_with_two_cores_and_not_otherwise(monkeypatch):
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    assert mapping_workers(3) == 3 and mapping_workers(12) == 8
    monkeypatch.setattr(os, "cpu_count", lambda: 1)
    assert mapping_workers(3) == 1
    monkeypatch.setattr(os, "cpu_count", lambda: 4)
    monkeypatch.setattr(sys, "platform", "darwin")  # no fork to share the fields: all in this process
    assert mapping_workers(3) == 1 and mapping_workers(3, asked=2) == 2


def test_preload_compiles_the_kernels_a_map_calls(room):
    """Workers are forked after `preload`: if it compiled the second stage's kernels for other argument types
    than the maps pass, every worker would compile them again at its first map (about a second each)."""
    from affordcore.geometry import pose_reads
    from affordcore.learn import tree_walk
    from affordcore.mapping.pipeline import preload

    scene, models, settings = room
    preload()
    kernels = (pose_reads.read_rows, tree_walk.walk_complete)
    compiled = [len(kernel.signatures) for kernel in kernels]
    assert all(compiled)
    RoomMapper(models, scene.layout, settings).maps(scene.fields)
    assert [len(kernel.signatures) for kernel in kernels] == compiled
