"""Baseline learners: exact threshold and z sweeps against brute force, and each learner on Gaussian data."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import imbalanced_gaussian

from affordcore.learn.baselines import (
    best_z,
    different_costs,
    focused_resampling,
    linear_tuned,
    tune_threshold,
    undersample,
    zsvm,
)
from affordcore.learn.f1_argmax import f1_at


@pytest.mark.parametrize("seed", range(20))
def test_tuned_threshold_is_the_best_there_is(seed):
    rng = np.random.default_rng(seed)
    scores = np.round(rng.normal(size=300), 1 if seed % 2 else 6)
    labels = np.where(rng.random(300) < 0.2, 1, -1)
    threshold, f1 = tune_threshold(scores, labels)
    brute = max(
        f1_at(scores, labels, t) for t in np.concatenate([np.unique(scores) - 1e-9, [scores.max() + 1]])
    )
    assert f1 == pytest.approx(brute) and f1_at(scores, labels, threshold) == pytest.approx(f1)


@pytest.mark.parametrize("seed", range(20))
def test_best_z_is_the_best_there_is(seed):
    rng = np.random.default_rng(seed)
    plus, minus = rng.normal(size=200), rng.normal(size=200)
    labels = np.where(rng.random(200) < 0.3, 1, -1)
    z = best_z(plus, minus, labels)
    breaks = np.unique((minus / plus)[minus / plus > 0])
    # one z per interval
    grid = np.concatenate([[breaks[0] / 2], (breaks[1:] + breaks[:-1]) / 2, [breaks[-1] * 2]])
    brute = max(f1_at(g * plus - minus, labels) for g in grid)
    assert z > 0 and f1_at(z * plus - minus, labels) == pytest.approx(brute)


def test_best_z_stays_below_every_breakpoint_when_the_start_is_best():
    """The positive is on for every z > 0, the negative turns on at z = 1: F1 is 1 below it and 2/3 above, so
    the best z lies below the first breakpoint."""
    plus, minus, labels = np.array([1.0, 1.0]), np.array([-1.0, 1.0]), np.array([1, -1])
    z = best_z(plus, minus, labels)
    assert 0 < z < 1 and f1_at(z * plus - minus, labels) == 1.0


def test_every_baseline_learns_a_separable_problem():
    X, y = imbalanced_gaussian(4000, 8, 100, 5.0, 0)
    rng = np.random.default_rng(0)
    models = {
        "linear-tuned": linear_tuned(X, y),
        "undersample": undersample(X, y, 10, rng),
        "dcm": different_costs(X, y, 50.0),
        "focused": focused_resampling(X, y, rng),
        "zsvm": zsvm(X, y, (X, y), rng),
    }
    for name, model in models.items():
        assert f1_at(model.decision(X), y, model.threshold) > 0.95, name


def test_undersampling_keeps_every_positive_and_the_ratio():
    from affordcore.learn.baselines import undersampled_indices

    y = np.where(np.arange(10000) < 20, 1, -1)
    keep = undersampled_indices(y, 5, np.random.default_rng(0))
    assert np.sum(y[keep] > 0) == 20 and np.sum(y[keep] < 0) == 100
    assert len(undersampled_indices(y, None, np.random.default_rng(0))) == 10000


def test_the_different_cost_model_is_the_same_model_on_the_same_data():
    """Its dual solver visits the examples in a random order, bounded in epochs: unseeded, two fits of the
    same data came out different (afford evaluate's dcm F1 moved by up to 0.019 from run to run)."""
    X, y = imbalanced_gaussian(3000, 20, 50, 0.6, seed=4)
    np.random.seed(1)  # whatever the global generator holds, the fit does not read it
    first = different_costs(X, y, cost_ratio=50.0)
    np.random.seed(2)
    second = different_costs(X, y, cost_ratio=50.0)
    assert np.array_equal(first.weights, second.weights) and first.bias == second.bias


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_standardised_rows_are_the_float32_values_liblinear_was_given_before_in_blocks(dtype):
    from affordcore.learn.baselines import _standardised

    rng = np.random.default_rng(5)
    X = (rng.normal(size=(1000, 7)) * [1, 10, 0.1, 3, 1, 1, 5]).astype(dtype)
    mean, scale = X.mean(axis=0, dtype=np.float64), X.std(axis=0, dtype=np.float64)
    # the one expression it replaces, then scikit-learn's float64 copy of it
    before = ((X - mean.astype(X.dtype)) / scale.astype(X.dtype)).astype(np.float32).astype(np.float64)
    standard = _standardised(X, mean, scale, rows=128)  # blocks that do not divide the rows
    assert standard.dtype == np.float64 and standard.flags.c_contiguous
    np.testing.assert_array_equal(standard, before)


def test_the_undersampling_learner_takes_its_c_from_the_parameters():
    from affordcore.learn.examples import RoomExamples
    from affordcore.learn.learners import get_learner

    X, y = imbalanced_gaussian(2000, 6, 20, 1.0, 5)
    rooms = RoomExamples("train", X, y), RoomExamples("validation", X, y)
    fit = get_learner("undersample").fit
    strong, weak = (fit(*rooms, {"C": c}, np.random.default_rng(0)).weights for c in (1e-4, 1.0))
    assert np.linalg.norm(strong) < 0.2 * np.linalg.norm(weak)  # C = 1e-4 regularises far harder
