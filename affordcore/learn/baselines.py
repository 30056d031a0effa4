"""The paper's SVM baselines for extreme imbalance, on scikit-learn's linear SVMs, as linear models.

* `linear_tuned`: LinearSVC on all data, threshold tuned for F1 on the training data (the simple strong
  baseline every learner here must beat).
* `undersample`: all positives and `ratio` x as many random negatives (None: all of them).
* `different_costs`: the different cost model, C+ = cost_ratio x C- (class weights).
* `focused_resampling` (Batuwita & Palade 2010): train on all, resample only where the boundary is decided
  (every positive, the negatives nearest the boundary, rebalanced), retrain.
* `zsvm` (Imam, Ting & Kamruzzaman 2006): a linear SVM's weight split into what its positive and its
  negative support vectors contribute, w_z = z w+ - w-, with z chosen by an exact sweep over the values
  where a validation example changes side (`best_z`).
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from .f1_argmax import f1_loss

DUAL_EPOCHS = 300  # passes of dual coordinate descent for class-weighted fits


@dataclass(frozen=True)
class LinearModel:
    weights: np.ndarray
    bias: float
    threshold: float = 0.0

    def decision(self, X: np.ndarray) -> np.ndarray:
        return X @ self.weights.astype(X.dtype, copy=False) + self.bias

    def predict(self, X: np.ndarray) -> np.ndarray:
        return self.decision(X) > self.threshold


def tune_threshold(scores: np.ndarray, labels: np.ndarray) -> tuple[float, float]:
    """The threshold with the best F1 (predict positive above it) and that F1: exact, one sort."""
    order = np.argsort(-scores, kind="stable")
    ranked, positive = scores[order], labels[order] > 0
    tp, fp = np.cumsum(positive), np.cumsum(~positive)
    f1 = 2 * tp / (positive.sum() + tp + fp)
    distinct = np.append(ranked[1:] < ranked[:-1], True)  # cut only between different scores
    k = int(np.argmax(np.where(distinct, f1, -1)))
    below = ranked[k + 1] if k + 1 < len(ranked) else ranked[k] - 1.0
    return float((ranked[k] + below) / 2), float(f1[k])


# unweighted `_svc` fits by their data's digest while `reused_fits` is open; None: fit every time
_fits: dict[str, LinearModel] | None = None


@contextmanager
def reused_fits() -> Iterator[None]:
    """Within the block, an unweighted LinearSVC fit on data it has fitted before is not made again.
    `linear_tuned`, `focused_resampling`'s first fit and the cascade's default first stage fit the same
    LinearSVC on the same training set, the evaluation's costliest fit (docs/learning.md "How long"). The
    primal solver draws no random numbers, so the reused fit is the one a new fit would give."""
    global _fits
    previous, _fits = _fits, {}
    try:
        yield
    finally:
        _fits = previous


def _data_digest(X: np.ndarray, y: np.ndarray, C: float) -> str:
    digest = hashlib.blake2b(digest_size=20)
    for array in (X, y):
        array = np.ascontiguousarray(array)
        digest.update(f"{array.dtype}{array.shape}".encode())
        digest.update(memoryview(array).cast("B"))
    digest.update(repr(float(C)).encode())
    return digest.hexdigest()


def _svc(X: np.ndarray, y: np.ndarray, C: float, class_weight=None) -> LinearModel:
    """`_fit_svc`, or its earlier fit on the same data inside `reused_fits` (unweighted fits only)."""
    if _fits is None or class_weight is not None:
        return _fit_svc(X, y, C, class_weight)
    key = _data_digest(X, y, C)
    if key not in _fits:
        _fits[key] = _fit_svc(X, y, C)
    return _fits[key]


def _fit_svc(X: np.ndarray, y: np.ndarray, C: float, class_weight=None) -> LinearModel:
    """LinearSVC on standardised features, returned as a model of the raw features. Unstandardised room
    features (metres, fractions, normal components) left liblinear's solvers unconverged after 10 minutes
    with a 1:1,300 class weight. Even standardised, the primal (trust-region Newton) solver with such a weight
    took over 10 minutes on 400k poses, so weighted fits use the dual coordinate-descent solver with a bounded
    number of epochs (its cost is then at most `DUAL_EPOCHS` passes over the data)."""
    import warnings

    from sklearn.exceptions import ConvergenceWarning
    from sklearn.svm import LinearSVC

    mean = X.mean(axis=0, dtype=np.float64)
    scale = X.std(axis=0, dtype=np.float64)
    scale = np.where(scale > 1e-9, scale, 1.0)
    standard = _standardised(X, mean, scale)
    if class_weight is None:
        svc = LinearSVC(C=C, dual="auto", max_iter=5000).fit(standard, y)
    else:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)  # bounded on purpose; see above
            # the dual solver visits the examples in a random order: a fixed one, so the same data give the
            # same model (unseeded, two runs of afford evaluate differed in dcm's F1 by up to 0.019)
            svc = LinearSVC(
                C=C, class_weight=class_weight, dual=True, max_iter=DUAL_EPOCHS, random_state=0
            ).fit(standard, y)
    # w . (x - mean) / scale + b = (w / scale) . x + b'
    weights = svc.coef_.ravel().astype(np.float64) / scale
    return LinearModel(weights, float(svc.intercept_[0]) - float(weights @ mean))


def _standardised(X: np.ndarray, mean: np.ndarray, scale: np.ndarray, rows: int = 65_536) -> np.ndarray:
    """(X - mean) / scale as liblinear is given it: worked out in X's precision and rounded to float32, then
    held in float64, the dtype scikit-learn hands to liblinear, a block of rows at a time. As one expression,
    the float32 result, its temporaries and scikit-learn's float64 copy of it were all held at once beside
    liblinear's own copy (16 bytes a value): the largest training sets' peak memory. The values are the same
    to the bit."""
    standard = np.empty(X.shape, dtype=np.float64)
    mean, scale = mean.astype(X.dtype), scale.astype(X.dtype)
    for start in range(0, len(X), rows):
        block = slice(start, start + rows)
        standard[block] = ((X[block] - mean) / scale).astype(np.float32)
    return standard


def linear_tuned(X: np.ndarray, y: np.ndarray, C: float = 1.0) -> LinearModel:
    model = _svc(X, y, C)
    return LinearModel(model.weights, model.bias, tune_threshold(model.decision(X), y)[0])


def undersample(
    X: np.ndarray, y: np.ndarray, ratio: float | None, rng: np.random.Generator, C: float = 1.0
) -> LinearModel:
    keep = undersampled_indices(y, ratio, rng)
    return _svc(X[keep], y[keep], C)


def undersampled_indices(y: np.ndarray, ratio: float | None, rng: np.random.Generator) -> np.ndarray:
    """Sorted indices of every positive and `ratio` x as many random negatives (all of them when None or
    fewer)."""
    positives, negatives = np.flatnonzero(y > 0), np.flatnonzero(y <= 0)
    if ratio is not None and ratio * len(positives) < len(negatives):
        negatives = rng.choice(negatives, int(round(ratio * len(positives))), replace=False)
    return np.sort(np.concatenate([positives, negatives]))


def different_costs(X: np.ndarray, y: np.ndarray, cost_ratio: float, C: float = 1.0) -> LinearModel:
    return _svc(X, y, C, class_weight={1: cost_ratio, -1: 1.0})


def focused_resampling(
    X: np.ndarray,
    y: np.ndarray,
    rng: np.random.Generator,
    C: float = 1.0,
    band: float = 1.0,
    balance: float = 1.0,
) -> LinearModel:
    """Train on all; keep every positive and the negatives within `band` of the boundary (at least as many
    as there are positives, nearest first), where the boundary is decided; rebalance them to `balance`
    negatives per positive by undersampling; retrain."""
    first = _svc(X, y, C)
    margin = np.abs(first.decision(X))
    positives, negatives = np.flatnonzero(y > 0), np.flatnonzero(y <= 0)
    nearest = negatives[np.argsort(margin[negatives], kind="stable")]
    near = nearest[: max(len(positives), int(np.sum(margin[negatives] <= band)))]
    near = rng.choice(near, min(len(near), int(round(balance * len(positives)))), replace=False)
    keep = np.sort(np.concatenate([positives, near]))
    return _svc(X[keep], y[keep], C)


def zsvm(
    X: np.ndarray,
    y: np.ndarray,
    validation: tuple[np.ndarray, np.ndarray],
    rng: np.random.Generator,
    C: float = 1.0,
    max_negatives: int = 20000,
) -> LinearModel:
    """zSVM on a linear SVC (libsvm exposes the dual coefficients LinearSVC does not); the SVC sees every
    positive and at most `max_negatives` negatives, since kernel SVMs do not scale to millions."""
    from sklearn.svm import SVC

    keep = undersampled_indices(y, max_negatives / max(1, np.sum(y > 0)), rng)
    svc = SVC(kernel="linear", C=C).fit(X[keep], y[keep])
    coef, support = svc.dual_coef_.ravel(), svc.support_  # coef = alpha_i y_i
    sv = X[keep][support].astype(np.float64)
    w_plus, w_minus = coef[coef > 0] @ sv[coef > 0], -(coef[coef < 0] @ sv[coef < 0])
    z = best_z(validation[0] @ w_plus, validation[0] @ w_minus - float(svc.intercept_[0]), validation[1])
    return LinearModel(z * w_plus - w_minus, float(svc.intercept_[0]))


def best_z(plus: np.ndarray, minus: np.ndarray, labels: np.ndarray) -> float:
    """The z > 0 maximising F1 of the rule z * plus - minus > 0, exactly: F1 only changes where an example
    changes side, at z_i = minus_i / plus_i, so one sweep over the sorted breakpoints finds the best."""
    positive = labels > 0
    rising = plus > 0  # these turn positive as z passes their breakpoint; plus < 0 turn negative
    flat = plus == 0
    breaks = np.where(flat, np.inf, minus / np.where(flat, 1.0, plus))  # no division by zero: flat ones by 1
    z0 = 1e-12
    state = np.where(flat, -minus > 0, z0 * plus - minus > 0)  # sides just above z = 0
    tp, fp = int(np.sum(state & positive)), int(np.sum(state & ~positive))
    moving = np.flatnonzero(~flat & (breaks > z0))
    order = moving[np.argsort(breaks[moving], kind="stable")]
    values = breaks[order]
    # crossing a breakpoint upwards turns a rising example on, others off
    step = np.where(rising[order], 1, -1)
    tps = tp + np.cumsum(step * positive[order])
    fps = fp + np.cumsum(step * ~positive[order])
    f1 = 1.0 - f1_loss(tps, fps, positive.sum())
    distinct = np.append(values[1:] > values[:-1], True)  # score only between distinct breakpoints
    f1 = np.where(distinct, f1, -1.0)
    start_f1 = 1.0 - float(f1_loss(tp, fp, positive.sum()))
    if len(order) == 0 or f1.max() <= start_f1:
        return z0 if len(order) == 0 else float(min(values[0] / 2, 1.0)) if values[0] > 2 * z0 else z0
    k = int(np.argmax(f1))
    upper = values[k + 1] if k + 1 < len(values) else values[k] * 2 + 1.0
    return float((values[k] + upper) / 2)
