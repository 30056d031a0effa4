"""The structured SVM for F1: cutting planes converge, keep every iteration, and learn what is learnable."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import imbalanced_gaussian

from affordcore.learn.f1_argmax import f1_at
from affordcore.learn.ssvm import SSVMSettings, decision, train_ssvm


def test_separable_data_is_learned_perfectly():
    X, y = imbalanced_gaussian(3000, 5, 50, 6.0, 0)
    result = train_ssvm(X, y, SSVMSettings(C=0.1))
    assert result.converged
    assert result.iterations[-1].train_f1 == 1.0


def test_converges_to_epsilon_and_keeps_every_iteration():
    X, y = imbalanced_gaussian(20000, 20, 100, 1.0, 1)
    Xv, yv = imbalanced_gaussian(20000, 20, 100, 1.0, 2)
    settings = SSVMSettings(C=0.025, epsilon=0.5, max_iterations=600)
    result = train_ssvm(X, y, settings, validation=(Xv, yv))
    assert result.converged and result.iterations[-1].violation <= settings.epsilon
    assert [it.number for it in result.iterations] == list(range(1, len(result.iterations) + 1))
    # the kept weights are the ones the scores came from
    best = result.best
    assert best.validation_f1 == pytest.approx(f1_at(decision(Xv, best.weights), yv))
    assert best.validation_f1 == max(it.validation_f1 for it in result.iterations)
    assert best.validation_f1 > 0.7  # Bayes-optimal F1 here is about 0.8


def test_without_positives_is_an_error():
    X = np.zeros((10, 3), np.float32)
    with pytest.raises(ValueError, match="no positive"):
        train_ssvm(X, -np.ones(10))
