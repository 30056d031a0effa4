"""The structured SVM for F1: cutting planes converge, keep every iteration, and learn what is learnable."""

from __future__ import annotations

import numpy as np
import pytest

from affordcore.learn.ssvm import SSVMSettings, decision, f1_score_at_zero, train_ssvm


def _gaussian(n: int, d: int, ratio: int, shift: float, seed: int):
    rng = np.random.default_rng(seed)
    y = np.where(rng.random(n) < 1 / (ratio + 1), 1, -1)
    y[:3] = 1
    X = rng.normal(size=(n, d)).astype(np.float32)
    X[y > 0] += shift
    return X, y


def test_separable_data_is_learned_perfectly():
    X, y = _gaussian(3000, 5, 50, 6.0, 0)
    result = train_ssvm(X, y, SSVMSettings(C=1e6))
    assert result.converged
    assert result.iterations[-1].train_f1 == 1.0


def test_converges_to_epsilon_and_keeps_every_iteration():
    X, y = _gaussian(20000, 20, 100, 1.0, 1)
    Xv, yv = _gaussian(20000, 20, 100, 1.0, 2)
    settings = SSVMSettings(C=1e7, epsilon=0.5, max_iterations=600)
    result = train_ssvm(X, y, settings, validation=(Xv, yv))
    assert result.converged and result.iterations[-1].violation <= settings.epsilon
    assert [it.number for it in result.iterations] == list(range(1, len(result.iterations) + 1))
    # the kept weights are the ones the scores came from
    best = result.best
    assert best.validation_f1 == pytest.approx(f1_score_at_zero(decision(Xv, best.weights), yv))
    assert best.validation_f1 == max(it.validation_f1 for it in result.iterations)
    assert best.validation_f1 > 0.7  # Bayes-optimal F1 here is about 0.8


def test_without_positives_is_an_error():
    X = np.zeros((10, 3), np.float32)
    with pytest.raises(ValueError, match="no positive"):
        train_ssvm(X, -np.ones(10))
