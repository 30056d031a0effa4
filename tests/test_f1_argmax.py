"""The structured SVM's loss-augmented argmax for F1: exact against brute force and SVMperf's double loop."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from affordcore.learn.f1_argmax import (
    F1Counter,
    _highest,
    f1_at,
    f1_loss,
    most_violated,
    most_violated_double_loop,
    most_violated_sorted,
)


def _brute_force(scores: np.ndarray, labels: np.ndarray) -> float:
    """max over all 2^n labellings of 1 - F1(y, y') + sum_i y'_i s_i."""
    positive = labels > 0
    best = -np.inf
    for bits in itertools.product((-1, 1), repeat=len(scores)):
        guess = np.array(bits)
        tp = int(np.sum((guess > 0) & positive))
        fp = int(np.sum((guess > 0) & ~positive))
        best = max(best, float(f1_loss(tp, fp, positive.sum())) + float(guess @ scores))
    return best


def _value(violation, scores, labels) -> float:
    """Recompute the objective from the returned labelling (it must be what it claims)."""
    positive = labels > 0
    guess = violation.labelling
    tp, fp = int(np.sum((guess > 0) & positive)), int(np.sum((guess > 0) & ~positive))
    assert (tp, fp) == (violation.true_positives, violation.false_positives)
    assert violation.loss == pytest.approx(float(f1_loss(tp, fp, positive.sum())))
    return float(f1_loss(tp, fp, positive.sum())) + float(guess @ scores)


@pytest.mark.parametrize("seed", range(60))
def test_matches_brute_force_over_all_labellings(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 12))
    labels = np.where(rng.random(n) < rng.uniform(0.1, 0.6), 1, -1)
    if not (labels > 0).any():
        labels[0] = 1
    scale = [0.01, 0.1, 1.0][seed % 3]  # small scores: the loss term decides; large: the scores do
    scores = rng.normal(0, scale, n)
    if seed % 5 == 0:
        scores = np.round(scores, 1)  # ties
    violation = most_violated(scores, labels)
    assert _value(violation, scores, labels) == pytest.approx(violation.objective, abs=1e-12)
    assert violation.objective == pytest.approx(_brute_force(scores, labels), abs=1e-12)


@pytest.mark.parametrize("n, ratio", [(2000, 10), (5000, 500), (20000, 1000)])
def test_matches_svmperf_double_loop_on_imbalanced_data(n, ratio):
    rng = np.random.default_rng(n)
    labels = np.where(rng.random(n) < 1 / (ratio + 1), 1, -1)
    labels[:3] = 1
    for spread in (0.001, 0.05, 1.0):
        scores = rng.normal(0, spread, n) + 0.5 * spread * (labels > 0)
        fast, slow = most_violated(scores, labels), most_violated_double_loop(scores, labels)
        assert fast.objective == pytest.approx(slow.objective, rel=1e-12, abs=1e-12)
        assert _value(fast, scores, labels) == pytest.approx(fast.objective, abs=1e-9)


def test_with_zero_weights_the_loss_picks_everything_positive():
    """w = 0: every labelling scores 0, so the argmax is the worst F1 there is: no true positive (loss 1)."""
    labels = np.array([1, -1, -1, 1, -1])
    violation = most_violated(np.zeros(5), labels)
    assert violation.loss == 1.0 and violation.true_positives == 0


def test_a_perfect_separator_with_a_margin_leaves_nothing_violated():
    """Scores beyond +-1 on the right sides: the true labelling wins, loss 0."""
    labels = np.array([1, 1, -1, -1, -1, -1])
    scores = np.array([2.0, 1.5, -1.5, -2.0, -3.0, -1.2])
    violation = most_violated(scores, labels)
    np.testing.assert_array_equal(violation.labelling, labels)
    assert violation.loss == 0.0


def test_f1_loss_values():
    assert f1_loss(0, 0, 3) == 1.0
    assert f1_loss(3, 0, 3) == 0.0
    assert f1_loss(1, 1, 2) == pytest.approx(1 - 2 / 4)


def test_rejects_mismatched_inputs():
    with pytest.raises(ValueError, match="equal"):
        most_violated(np.zeros(3), np.ones(4))


@pytest.mark.parametrize("seed", range(40))
def test_selection_equals_the_sorted_sweep_with_ties_and_every_scale(seed):
    """The O(n) selection (partition of the negatives that can flip) finds the optimum of the previous
    sort-everything sweep and of SVMperf's double loop: random sizes, class ratios, score scales around the
    flip thresholds (-1/(4P+2)), many exact ties (rounded scores, zeros, all equal)."""
    rng = np.random.default_rng(1000 + seed)
    for _ in range(25):
        n = int(rng.integers(1, 600))
        labels = np.where(rng.random(n) < rng.choice([0.01, 0.1, 0.5]), 1, -1)
        labels[rng.integers(n)] = 1
        scale = 10 ** rng.uniform(-7, 0)
        scores = rng.normal(rng.uniform(-2, 0.5) * scale, scale, n) + rng.uniform(0, 2) * scale * (labels > 0)
        kind = rng.integers(4)
        if kind == 1:
            scores = np.round(scores / scale, 1) * scale  # many ties
        elif kind == 2:
            scores[rng.random(n) < 0.5] = 0.0  # exact zeros: on the edge of "always a false positive"
        elif kind == 3:
            scores[:] = scores[0]  # all equal
        new, old = most_violated(scores, labels), most_violated_sorted(scores, labels)
        assert new.objective == pytest.approx(old.objective, rel=1e-12, abs=1e-12)
        assert _value(new, scores, labels) == pytest.approx(new.objective, abs=1e-9)
        if n <= 200:
            assert new.objective == pytest.approx(
                most_violated_double_loop(scores, labels).objective, rel=1e-12, abs=1e-12
            )


def test_selection_equals_the_sorted_sweep_at_training_scale():
    """200,000 scores at the scale training gives them (tiny: the loose filter keeps every negative)."""
    rng = np.random.default_rng(7)
    labels = np.where(rng.random(200_000) < 1 / 1001, 1, -1)
    for mean in (-3e-6, 0.0, -1e-4):
        scores = rng.normal(mean, 1e-6, len(labels)) + 2e-6 * (labels > 0)
        new, old = most_violated(scores, labels), most_violated_sorted(scores, labels)
        assert new.objective == pytest.approx(old.objective, rel=1e-12)
        assert (new.true_positives, new.false_positives) == (old.true_positives, old.false_positives)


@pytest.mark.parametrize("seed", range(6))
def test_highest_values_through_the_guessed_threshold_are_the_sorted_top(seed):
    """`_highest` filters by a threshold guessed from a sample before its partition: the same values as a full
    sort, in descending order, with ties at the guess, a guess that lets too few through (all values but a
    few equal and low), and counts from one to all of them."""
    rng = np.random.default_rng(seed)
    for _ in range(30):
        n = int(rng.integers(1, 300_000))
        values = rng.normal(size=n)
        kind = rng.integers(3)
        if kind == 1:
            values = np.round(values, 1)  # many ties, also at the guessed threshold
        elif kind == 2:
            values[rng.random(n) < 0.999] = -1.0  # almost all equal and low
        count = int(rng.choice([1, 17, 4096, n // 20 + 1, n]))
        count = min(count, n)
        expected = np.sort(values)[::-1][:count]
        assert np.array_equal(_highest(values, count), expected)


def _f1_by_masks(scores, labels, threshold=0.0) -> float:
    """F1 from the contingency table of two masks over every example: the reference `F1Counter` counts."""
    positive, predicted = labels > 0, scores > threshold
    tp, fp = np.sum(positive & predicted), np.sum(~positive & predicted)
    return 1.0 - float(f1_loss(tp, fp, positive.sum()))


def test_f1_counter_counts_f1_for_vectors_and_columns_with_ties_at_the_threshold():
    """One vector (and `f1_at`) against the two masks' F1; columns of float32 scores against float64
    thresholds -b decide as the float64 sums s + b against 0, also where a score equals -b exactly."""
    rng = np.random.default_rng(3)
    labels = np.where(rng.random(5_000) < 0.05, 1, -1)
    labels[0] = 1
    counter = F1Counter(labels)
    scores = rng.normal(size=5_000)
    for threshold in (0.0, 0.5, -1.0, 10.0):
        expected = _f1_by_masks(scores, labels, threshold)
        assert float(counter.f1(scores, threshold)) == expected == f1_at(scores, labels, threshold)
    columns = np.round(rng.normal(size=(5_000, 4)), 2).astype(np.float32)
    bias = -columns[range(4), range(4)].astype(np.float64)  # each column has scores exactly at its threshold
    bias[3] = 0.1 + 1e-12  # and one whose threshold is no float32
    expected = [_f1_by_masks(columns[:, k].astype(np.float64) + bias[k], labels) for k in range(4)]
    assert counter.f1(columns, -bias).tolist() == expected
    assert float(F1Counter(-np.ones(3)).f1(np.ones(3))) == 0.0  # no positives, all predicted: F1 0
