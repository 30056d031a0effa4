"""The loss-augmented argmax of the structured SVM for F1 (Joachims 2005), exactly, in O(n).

With the whole training set as one structured example, a labelling y' in {-1, +1}^n has the joint feature
map Psi(x, y') = sum_i y'_i x_i, and the most violated constraint under margin rescaling is

    argmax_{y'}  Delta(y, y') + sum_i y'_i s_i,        s_i = w . x_i,  Delta = 1 - F1(y, y').

Delta depends on y' only through its contingency table: a true positives (positives labelled +1) and b false
positives (negatives labelled +1). For a given (a, b) the score term is largest when y' gives +1 to the a
highest-scoring positives and the b highest-scoring negatives, so only (a, b) needs searching. SVMperf
searches all (P + 1)(N + 1) pairs. But for a fixed a the objective is concave in b: its increment

    2 s_neg(b) + 2a / ((P + a + b)(P + a + b + 1))

is a decreasing sequence of scores plus a decreasing positive term, so the best b, b*(a), is the count of
positive increments; and that second term grows with a (its derivative in a has the sign of
(P + b)^2 + P + b - a^2, positive since a <= P), so b*(a) never decreases as a grows.

`most_violated` uses this without sorting the negatives:

* every negative scoring above 0 has a positive increment for every a: it is a false positive of every
  b*(a), so only its sum is needed, never its rank;
* b*(P) = B, the most false positives any a takes, is the first j at which fewer than j + 1 negatives score
  above -P / ((2P + j)(2P + j + 1)): found among the highest-scoring candidates alone (`np.partition`);
* so only the negatives ranked between those two counts (scores in (-1 / (4P + 2), 0]) can flip with a:
  they are selected with `np.argpartition` and only they are sorted, and b*(a) for every a comes from a
  bisection vectorised over a (O(P log B)).

O(n) for the selection and the counts (a few passes over the scores), plus the sort of the few that can flip.
`most_violated_sorted` (the previous sweep: a stable sort of every candidate and a pointer on b) and
`most_violated_double_loop` (SVMperf's search) are kept as references for the tests and the benchmark.
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
    return float(F1Counter(labels).f1(np.asarray(scores), threshold))


class F1Counter:
    """F1 of many score vectors against one labelling (`f1_at` for one): the positives' indices kept, so a
    vector's F1 is one comparison and two counts (false positives are the predicted less the true ones). The
    structured SVM scores every iteration's weights this way on the training and the validation set."""

    def __init__(self, labels: np.ndarray):
        self.positives = np.flatnonzero(np.asarray(labels) > 0)

    def f1(self, scores: np.ndarray, threshold=0.0) -> np.ndarray:
        """F1 of predicting positive where a score exceeds the threshold: scores (n,) -> a 0-d array, or
        (n, k) with a threshold per column -> (k,). The comparison is made in the wider of the two dtypes,
        so float32 scores against float64 thresholds -b decide as float64 sums s + b against 0 do."""
        predicted = scores > threshold
        true_positives = np.count_nonzero(predicted[self.positives], axis=0)
        false_positives = np.count_nonzero(predicted, axis=0) - true_positives
        return 1.0 - f1_loss(true_positives, false_positives, len(self.positives))


@dataclass(frozen=True)
class Violation:
    labelling: np.ndarray  # (n,) in {-1, +1}: the most violated labelling y'
    true_positives: int
    false_positives: int
    loss: float  # Delta(y, y') = 1 - F1
    objective: float  # Delta(y, y') + sum_i y'_i s_i


def most_violated(scores: np.ndarray, labels: np.ndarray) -> Violation:
    """The exact argmax over all labellings of Delta_F1(y, y') + sum_i y'_i s_i (labels in {-1, +1} or {0,
    1}), in O(n) plus the sort of the negatives that can flip (module docstring)."""
    scores, positive = _inputs(scores, labels)
    pos_index = np.flatnonzero(positive)
    pos_order = pos_index[np.argsort(-scores[pos_index], kind="stable")]
    n_pos = len(pos_order)
    negative = ~positive
    all_neg = float(scores.sum() - scores[pos_index].sum())
    # A false positive's increment is 2 s + (a term at most 1 / (2P + 1)): a negative scoring at or below
    # -1 / (4P + 2) is never labelled +1. Those above 0 always are (their increment is positive for every a).
    above = scores > 0
    sure = np.flatnonzero(above & negative)
    b0, sure_sum = len(sure), float(scores[sure].sum())
    maybe = np.flatnonzero(~above & negative & (scores > -1.0 / (4 * n_pos + 2)))
    maybe, flip = _flippable(maybe, scores[maybe], b0, n_pos)
    maybe_scores = scores[maybe]
    if flip < len(maybe):
        top = np.argpartition(-maybe_scores, flip)[:flip]
    else:
        top = np.arange(len(maybe))
    top = top[np.argsort(-maybe_scores[top], kind="stable")]
    s_flip = maybe_scores[top]
    neg_order = np.concatenate([sure, maybe[top]])

    s_pos = scores[pos_order]
    prefix_pos = np.concatenate([[0.0], np.cumsum(s_pos)])
    prefix_neg = np.concatenate([[sure_sum], sure_sum + np.cumsum(s_flip)])  # prefix_neg[b - b0]
    a = np.arange(n_pos + 1, dtype=np.float64)
    # b*(a) - b0: the count of flippable j with a positive increment; the increments decrease in j, so a
    # bisection per a, vectorised over a
    lo_a = np.zeros(n_pos + 1, dtype=np.int64)
    hi_a = np.full(n_pos + 1, flip, dtype=np.int64)
    while flip and np.any(lo_a < hi_a):
        mid = (lo_a + hi_a) // 2
        j = b0 + mid
        gain = 2 * s_flip[np.minimum(mid, flip - 1)] + 2.0 * a / ((n_pos + a + j) * (n_pos + a + j + 1.0))
        lo_a, hi_a = np.where(gain > 0, np.minimum(mid + 1, hi_a), lo_a), np.where(gain > 0, hi_a, mid)
    b = b0 + lo_a
    values = f1_loss(a, b, n_pos) + 2 * prefix_pos - prefix_pos[-1] + 2 * prefix_neg[lo_a] - all_neg
    best = int(np.argmax(values))  # the first maximum, as the sweep keeps
    return _violation((float(values[best]), best, int(b[best])), pos_order, neg_order, scores, n_pos)


def _flippable(index: np.ndarray, values: np.ndarray, b0: int, n_pos: int) -> tuple[np.ndarray, int]:
    """The candidates (scores in (-1 / (4P + 2), 0]) that can be false positives, and how many of them
    (at most) are: B - b0, where B = b*(P) is the first j >= b0 with at most j negatives scoring above
    -half_gain(j) (b0 of them score above 0). Each candidate passes that threshold for j below a rank limit
    r (the root of a quadratic in j; rounded up, so B can only come out too large, which the exact
    bisection per a then corrects). r grows with the score, so with the candidates' scores in descending
    order B = b0 + the first m whose (m + 1)-th limit is at most b0 + m: only the few highest scores are
    needed, selected with `np.partition` (no sort of the rest, no count over every j). The B best all score
    above -half_gain(B - 1), which leaves about B - b0 candidates to sort."""
    if not len(values):
        return index, 0
    big = b0 + _settled_rank(values, b0, n_pos)
    if big == b0:
        return index[:0], 0
    keep = values > -_half_gain(big - 1, n_pos)
    index = index[keep]
    return index, min(big - b0, len(index))


def _settled_rank(values: np.ndarray, b0: int, n_pos: int, first: int = 4096) -> int:
    """The smallest m >= 0 at which at most m candidates still count (their rank limit exceeds b0 + m):
    with the limits in descending order L, the first m with L[m] <= b0 + m (L[m] - m falls strictly, so
    the first is found among the highest scores), or all of them."""
    count = min(len(values), first)
    while True:
        highest = _highest(values, count)
        with np.errstate(divide="ignore"):
            ratio = n_pos / np.abs(highest)  # (2P + j)(2P + j + 1) < ratio: the candidate counts at j
        limit = np.floor((np.sqrt(1.0 + 4.0 * ratio) - 1.0) / 2.0 - 2.0 * n_pos) + 2.0
        settled = np.flatnonzero(limit <= b0 + np.arange(count))
        if len(settled):
            return int(settled[0])
        if count == len(values):
            return count
        count = min(len(values), 8 * count)


def _highest(values: np.ndarray, count: int) -> np.ndarray:
    """The `count` highest values in descending order, `np.partition` taken over the values at or above a
    threshold guessed from every `stride`-th value (about twice `count` pass it) instead of over all of them
    (a million candidates on a 1:12,000 set): the same values, since when at least `count` pass, the
    `count` highest are among them; else over all."""
    stride = min(64, len(values) // (4 * max(count, 1)))
    if stride >= 4:
        sample = values[::stride]
        k = min(len(sample), 2 * (count // stride) + 16)
        above = values[values >= np.partition(sample, len(sample) - k)[len(sample) - k]]
        if len(above) >= count:
            values = above
    return np.sort(np.partition(values, len(values) - count)[len(values) - count :])[::-1]


def _half_gain(j: int, n_pos: int) -> float:
    """Half the largest loss term of the (j+1)-th false positive's increment (at a = P)."""
    return n_pos / ((2.0 * n_pos + j) * (2.0 * n_pos + j + 1.0))


def _inputs(scores, labels) -> tuple[np.ndarray, np.ndarray]:
    scores = np.asarray(scores, dtype=np.float64)
    positive = np.asarray(labels) > 0
    if scores.shape != positive.shape or scores.ndim != 1:
        raise ValueError(f"scores {scores.shape} and labels {positive.shape} must be two equal 1-d arrays")
    return scores, positive


def most_violated_sorted(scores: np.ndarray, labels: np.ndarray) -> Violation:
    """The same argmax by the previous O(n log n) sweep: a stable sort of every negative scoring above
    -1 / (4P + 2) and a pointer on b. For tests and the benchmark that measures what the selection saves."""
    scores, positive = _inputs(scores, labels)
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
    scores, positive = _inputs(scores, labels)
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
