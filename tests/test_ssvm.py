"""The structured SVM for F1: cutting planes converge, keep every iteration, and learn what is learnable."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from conftest import imbalanced_gaussian

from affordcore.learn.f1_argmax import f1_at, f1_loss
from affordcore.learn.ssvm import (
    SSVMSettings,
    c_from_svmperf,
    c_to_svmperf,
    decision,
    objective,
    train_ssvm,
)


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


@pytest.mark.parametrize("method", ["cutting-plane", "bundle"])
@pytest.mark.parametrize("batch", [3, 7, 64])
def test_validation_scored_in_batches_is_the_per_iteration_run(method, batch):
    """Validation F1 computed a batch of iterations at a time: the same iterations, F1 and weights as one at
    a time, and the run stops where patience ran out, not at the end of the batch that found it."""
    X, y = imbalanced_gaussian(6000, 10, 60, 0.8, 3)
    Xv, yv = imbalanced_gaussian(6000, 10, 60, 0.8, 4)
    runs = {}
    for size in (1, batch):
        settings = SSVMSettings(C=0.5, method=method, patience=5, max_iterations=80, validation_batch=size)
        seen = []
        runs[size] = (train_ssvm(X, y, settings, (Xv, yv), on_iteration=seen.append), seen)
    (one, one_seen), (many, many_seen) = runs[1], runs[batch]
    assert not one.converged and len(one.iterations) < 80  # patience stopped it (not the iteration limit)
    assert one.converged == many.converged
    assert [it.number for it in many.iterations] == [it.number for it in one.iterations]
    assert (
        [it.number for it in many_seen]
        == [it.number for it in one_seen]
        == list(range(1, 81))[: len(one_seen)]
    )
    assert [it.validation_f1 for it in many.iterations] == pytest.approx(
        [it.validation_f1 for it in one.iterations]
    )
    np.testing.assert_allclose(many.best.weights, one.best.weights)
    assert many.iterations[-1].number - many.best.number == 5


def test_without_positives_is_an_error():
    X = np.zeros((10, 3), np.float32)
    with pytest.raises(ValueError, match="^no positive examples to learn from$"):
        train_ssvm(X, -np.ones(10))


def test_the_default_slack_weighs_2500_times_svmperfs_default_c():
    """Neither C nor c_svmperf given: SVMperf's default -c, the slack weighing (n x label / n)^2 = 2500 x it
    whatever the number of examples."""
    for n in (7, 200_000):
        assert SSVMSettings().slack_weight(n) == pytest.approx(2500 * 1.0e4)


def test_c_in_svmperf_units_round_trips_and_means_the_same_problem():
    for n in (1, 7, 200_000, 1_300_000):
        for c in (1e-3, 1.0, 3.2e7):
            assert c_to_svmperf(c_from_svmperf(c, n), n) == pytest.approx(c, rel=1e-12)
            assert SSVMSettings(C=c_from_svmperf(c, n)).slack_weight(n) == pytest.approx(
                SSVMSettings(c_svmperf=c).slack_weight(n), rel=1e-12
            )
    assert c_to_svmperf(2.0, 200_000) == pytest.approx(3.2e7)  # the old default, in SVMperf's units
    with pytest.raises(ValueError, match="not both"):
        SSVMSettings(C=1.0, c_svmperf=1.0)


def _svmperf_objective(X, y, w_perf, c_perf, bias):
    """SVMperf's own F1 problem, by brute force over every labelling: labels +-50/n, Delta = 100 (1 - F1),
    1/2 |w|^2 + C max_y' [Delta(y') - w . sum_i (y_i - y'_i) (50 / n) [x_i, bias]]."""
    n = len(y)
    Xb = np.hstack([X, np.full((n, 1), bias)])
    worst = -np.inf
    for bits in itertools.product((-1, 1), repeat=n):
        guess = np.array(bits)
        tp, fp = int(np.sum((guess > 0) & (y > 0))), int(np.sum((guess > 0) & (y < 0)))
        delta = 100.0 * float(f1_loss(tp, fp, int(np.sum(y > 0))))
        worst = max(worst, delta - float(w_perf @ (((y - guess) * (50.0 / n)) @ Xb)))
    return 0.5 * float(w_perf @ w_perf) + c_perf * worst


@pytest.mark.parametrize("seed", range(4))
def test_svmperf_units_solve_svmperf_problem(seed):
    """w_project = 50 w_svmperf and C_project = 2500 C_svmperf / n^2: our objective at 50 w is 2500 times
    SVMperf's at w, for any w (brute force over all labellings, n = 9)."""
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(9, 3)).astype(np.float32)
    y = np.array([1, -1, -1, 1, -1, -1, -1, 1, -1])
    w_perf = rng.normal(size=4) * [0.1, 1.0, 10.0][seed % 3]
    c_perf = [0.01, 1.0, 30.0, 1e4][seed]
    ours = objective(X, y, 50.0 * w_perf, SSVMSettings(c_svmperf=c_perf, bias=1.0))
    assert ours == pytest.approx(
        2500.0 * _svmperf_objective(X.astype(np.float64), y, w_perf, c_perf, 1.0), rel=1e-6
    )
    same = objective(X, y, 50.0 * w_perf, SSVMSettings(C=c_from_svmperf(c_perf, len(y)), bias=1.0))
    assert same == pytest.approx(ours, rel=1e-12)


@pytest.mark.parametrize("method", ["cutting-plane", "bundle"])
def test_warm_started_working_set_reaches_the_cold_objective(method):
    """One OSQP problem updated and warm-started each iteration against a fresh set-up each iteration:
    both stop within C n^2 epsilon of the optimum, so their objectives agree within that, and each stays
    above the working set's lower bound."""
    X, y = imbalanced_gaussian(3000, 8, 30, 1.2, 3)
    runs = {}
    for warm in (True, False):
        settings = SSVMSettings(
            c_svmperf=30.0, epsilon=0.1, method=method, warm_start=warm, max_iterations=400
        )
        result = train_ssvm(X, y, settings)
        assert result.converged
        runs[warm] = objective(X, y, result.iterations[-1].weights, settings)
    tolerance = settings.slack_weight(len(y)) * settings.epsilon
    assert abs(runs[True] - runs[False]) <= tolerance
    assert runs[True] < settings.slack_weight(len(y)) * 100.0 * 0.8  # a real optimum, not w = 0


def test_bundle_and_cutting_planes_reach_the_same_optimum():
    X, y = imbalanced_gaussian(3000, 8, 30, 1.2, 4)
    values = []
    for method in ("cutting-plane", "bundle"):
        settings = SSVMSettings(c_svmperf=30.0, epsilon=0.05, method=method, max_iterations=400)
        result = train_ssvm(X, y, settings)
        assert result.converged
        values.append(objective(X, y, result.iterations[-1].weights, settings))
    assert abs(values[0] - values[1]) <= settings.slack_weight(len(y)) * settings.epsilon


def test_the_structured_svm_as_a_learner_decides_as_its_best_iteration_did():
    """The learner's model (weights and bias per example) labels the validation rows as the solver's best
    iteration did: the same validation F1 at threshold 0."""
    from affordcore.learn.examples import RoomExamples
    from affordcore.learn.learners import get_learner

    X, y = imbalanced_gaussian(3000, 6, 50, 1.5, 3)
    Xv, yv = imbalanced_gaussian(2000, 6, 50, 1.5, 4)
    train, validation = RoomExamples("train", X, y), RoomExamples("validation", Xv, yv)
    fitted = get_learner("ssvm").fit(train, validation, {"max_iterations": 40}, np.random.default_rng(0))
    best = max(fitted.report["validation_f1"])
    assert best > 0.3 and f1_at(Xv @ fitted.weights + fitted.bias, yv) == pytest.approx(best)
