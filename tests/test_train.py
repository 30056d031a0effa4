"""Every learner trains through one interface on a small generated data set and writes a usable model."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from affordcore.learn.model import load_model
from affordcore.learn.train import LEARNERS, split_rooms, train
from affordcore.settings import FeatureSettings, GridSettings, Settings

SMALL = {"AFFORD_FEATURES__CELL_SIZE": "0.5", "AFFORD_GRID__N_THETA": "8", "AFFORD_GRID__THETA_STEP": "0.785398"}


@pytest.fixture(scope="module")
def data_set(tmp_path_factory):
    folder = tmp_path_factory.mktemp("rooms")
    result = subprocess.run([sys.executable, "-m", "affordcore.cli", "synth", "--rooms", "3", "--seed", "11", "--out", str(folder),
                             "--kinds", "workshop", "--scanner", "uniform", "--quiet"], capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    return folder


def _settings() -> Settings:
    return Settings(features=FeatureSettings(cell_size=0.5), grid=GridSettings(n_theta=8, theta_step=np.pi / 4))


def _affordance(folder) -> str:
    return json.loads(next(folder.glob("*.labels.json")).read_text())["labels"][0]["affordance"]


@pytest.mark.parametrize("learner", LEARNERS)
def test_every_learner_trains_and_beats_chance(data_set, learner):
    params = {"C": 1e7, "max_iterations": 60} if learner == "ssvm" else {}
    model = train(data_set, _affordance(data_set), learner, _settings(), params)
    assert model.learner == learner and len(model.weights) == 30 + 3 * 8
    assert set(model.training["rooms"]).isdisjoint(model.validation["rooms"])  # split by room
    assert model.validation["recall"] > 0 and model.validation["f1"] > 0.05  # better than nothing at 1:300


def test_split_is_by_room_and_seeded():
    names = [f"room-{i}" for i in range(8)]
    train_a, val_a = split_rooms(names, 3)
    assert len(val_a) == 2 and sorted(train_a + val_a) == names
    assert split_rooms(names, 3) == (train_a, val_a)


@pytest.mark.slow
def test_afford_train_writes_a_model(data_set, tmp_path):
    out = tmp_path / "model.json"
    env = {**os.environ, **SMALL}
    result = subprocess.run([sys.executable, "-m", "affordcore.cli", "train", "--data", str(data_set), "--affordance",
                             _affordance(data_set), "--learner", "linear-tuned", "--out", str(out), "--quiet"],
                            capture_output=True, text=True, timeout=600, env=env)
    assert result.returncode == 0, result.stderr
    model = load_model(out)
    assert model.affordance == _affordance(data_set) and "f1" in result.stdout
