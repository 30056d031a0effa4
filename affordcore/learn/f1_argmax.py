"""The loss-augmented argmax of the structured SVM for F1 (Joachims 2005), exactly, in O(n log n).

With the whole training set as one structured example, a labelling y' in {-1, +1}^n has the joint feature
map Psi(x, y') = sum_i y'_i x_i, and the most violated constraint under margin rescaling is

    argmax_{y'}  Delta(y, y') + sum_i y'_i s_i,        s_i = w . x_i,  Delta = 1 - F1(y, y').

Delta depends on y' only through its contingency table: a true positives (positives labelled +1) and b false
positives (negatives labelled +1). For a given (a, b) the score term is largest when y' gives +1 to the a
highest-scoring positives and the b highest-scoring negatives, so only (a, b) needs searching. SVMperf
searches all (P + 1)(N + 1) pairs. But for a fixed a the objective is concave in b: its increment

    2 s_neg(b) + 2a / ((P + a + b)(P + a + b + 1))

is a decreasing sequence of scores plus a decreasing positive term, so the best b is the count of positive
increments; and that second term grows with a (its derivative in a has the sign of (P + b)^2 + P + b - a^2,
positive since a <= P), so the best b never decreases as a grows. One sweep of a with a pointer on b after
sorting finds the exact optimum: O(n log n) for the sort, O(n) for the sweep. And only negatives scoring
above -1 / (4P + 2) can ever be labelled positive, so only those are sorted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def f1_loss(true_positives, false_positives, positives) -> np.ndarray:
    """1 - F1 of a contingency table; F1 = 2 tp / (P + tp + fp), and 0 when nothing is right."""
    tp, fp = np.asarray(true_positives, dtype=np.float64), np.asarray(false_positives, dtype=np.float64)
    denominator = positives + tp + fp
    return 1.0 - np.divide(2 * tp, denominator, out=np.zeros_like(denominator + tp), where=denominator > 0)


def f1_at(scores: np.ndarray, labels: np.ndarray, threshold: float = 0.0) -> float:
    """F1 of predicting positive where the score exceeds the threshold."""
    positive, predicted = np.asarray(labels) > 0, scores > threshold
    return 1.0 - float(f1_loss(np.sum(positive & predicted), np.sum(~positive & predicted), positive.sum()))


@dataclass(frozen=True)
class Violation:
    labelling: np.ndarray  # (n,) in {-1, +1}: the most violated labelling y'
    true_positives: int
    false_positives: int
    loss: float  # Delta(y, y') = 1 - F1
    objective: float  # Delta(y, y') + sum_i y'_i s_i


def most_violated(scores: np.ndarray, labels: np.ndarray) -> Violation:
    """The exact argmax over all labellings of Delta_F1(y, y') + sum_i y'_i s_i (labels in {-1, +1} or {0,
    1})."""
    scores = np.asarray(scores, dtype=np.float64)
    positive = np.asarray(labels) > 0
    if scores.shape != positive.shape or scores.ndim != 1:
        raise ValueError(f"scores {scores.shape} and labels {positive.shape} must be two equal 1-d arrays")
    pos_order = np.flatnonzero(positive)[np.argsort(-scores[positive], kind="stable")]
    n_pos = len(pos_order)
    # A false positive's increment is 2 s + (a term at most 1 / (2P + 1)), so a negative scoring at or below
    # -1 / (4P + 2) is never labelled +1: only the rest need sorting (after a few iterations, a sliver).
    candidates = np.flatnonzero(~positive & (scores > -1.0 / (4 * n_pos + 2)))
    neg_order = candidates[np.argsort(-scores[candidates], kind="stable")]
    s_pos, s_neg = scores[pos_order], scores[neg_order]
    all_neg = float(np.sum(scores[~positive]))

    prefix_pos = np.concatenate([[0.0], np.cumsum(s_pos)])
    prefix_neg = np.concatenate([[0.0], np.cumsum(s_neg)])
    best = (-np.inf, 0, 0)
    b = 0
    for a in range(n_pos + 1):
        b = _advance(b, a, s_neg, n_pos)  # the best b for this a: it never decreases as a grows
        value = float(f1_loss(a, b, n_pos) + 2 * prefix_pos[a] - prefix_pos[-1] + 2 * prefix_neg[b] - all_neg)
        if value > best[0]:
            best = (value, a, b)
    return _violation(best, pos_order, neg_order, scores, n_pos)


def _advance(b: int, a: int, s_neg: np.ndarray, n_pos: int) -> int:
    """From b, move past every false positive that raises the objective (its increment > 0); the increments
    decrease, so this stops at the first one that does not. Scanned in growing numpy blocks: O(moves) work."""
    block = 64
    while b < len(s_neg):
        candidates = np.arange(b, min(len(s_neg), b + block))
        gain = 2 * s_neg[candidates] + 2.0 * a / ((n_pos + a + candidates) * (n_pos + a + candidates + 1.0))
        stop = np.flatnonzero(gain <= 0)
        if len(stop):
            return int(candidates[stop[0]])
        b, block = int(candidates[-1]) + 1, block * 2
    return b


def most_violated_double_loop(scores: np.ndarray, labels: np.ndarray) -> Violation:
    """The same argmax by SVMperf's search of every (a, b) pair: O(P N), vectorised per a. For tests and the
    benchmark that measures what the sweep saves."""
    scores = np.asarray(scores, dtype=np.float64)
    positive = np.asarray(labels) > 0
    pos_order = np.flatnonzero(positive)[np.argsort(-scores[positive], kind="stable")]
    neg_order = np.flatnonzero(~positive)[np.argsort(-scores[~positive], kind="stable")]
    s_pos, s_neg = scores[pos_order], scores[neg_order]
    n_pos = len(s_pos)
    prefix_pos = np.concatenate([[0.0], np.cumsum(s_pos)])
    prefix_neg = np.concatenate([[0.0], np.cumsum(s_neg)])
    b = np.arange(len(s_neg) + 1)
    best = (-np.inf, 0, 0)
    for a in range(n_pos + 1):
        values = f1_loss(a, b, n_pos) + 2 * prefix_pos[a] - prefix_pos[-1] + 2 * prefix_neg - prefix_neg[-1]
        j = int(values.argmax())
        if values[j] > best[0]:
            best = (float(values[j]), a, j)
    return _violation(best, pos_order, neg_order, scores, n_pos)


def _violation(best, pos_order, neg_order, scores, n_pos) -> Violation:
    value, a, b = best
    labelling = -np.ones(len(scores), dtype=np.int8)
    labelling[pos_order[:a]] = 1
    labelling[neg_order[:b]] = 1
    return Violation(labelling, int(a), int(b), float(f1_loss(a, b, n_pos)), float(value))
