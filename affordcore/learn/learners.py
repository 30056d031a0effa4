"""The learners, registered once: training (`train.fit`), the evaluation, the command line and the docs read
this table. A new learner is a fit function and one line here (and its tests). Nothing heavy is imported until
a learner fits, so the command line can list them instantly."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from .fitted import Fitted

if TYPE_CHECKING:
    import numpy as np

    from .examples import RoomExamples


@dataclass(frozen=True)
class Learner:
    name: str
    summary: str  # one line for --help and the docs
    # train, validation, params, rng
    fit: Callable[[RoomExamples, RoomExamples, dict, np.random.Generator], Fitted]
    # rough seconds of one training of `afford evaluate` at its defaults on 12 generated rooms (one thread,
    # scoring included; after `SHARED_FIT`'s fit, what it adds): the evaluation starts the longest jobs first
    # and weighs its progress bar's time left by these (docs/learning.md "How long" measures them)
    cost: float = 10.0


def _ssvm(train: RoomExamples, validation: RoomExamples, params: dict, rng) -> Fitted:
    from .ssvm import SSVMSettings, train_ssvm

    result = train_ssvm(train.X, train.y, SSVMSettings(**params), validation=(validation.X, validation.y))
    best = result.best
    # per example (the solver's Psi is summed over n): the same sign, scores of order one (not SVMperf's w,
    # which is these / 50: docs/learning.md, C units)
    weights = best.weights / len(train.y)
    return Fitted(
        weights[:-1],
        float(weights[-1]),
        0.0,
        {
            "iterations": len(result.iterations),
            "best_iteration": best.number,
            "converged": result.converged,
            "train_f1": [it.train_f1 for it in result.iterations],
            "validation_f1": [it.validation_f1 for it in result.iterations],
        },
    )


def _baseline(make: Callable) -> Callable[..., Fitted]:
    """A scikit-learn baseline as a fit function: `make(train, validation, params, rng)` returns a
    LinearModel."""

    def fit(train: RoomExamples, validation: RoomExamples, params: dict, rng) -> Fitted:
        model = make(train, validation, params, rng)
        return Fitted(model.weights, model.bias, model.threshold)

    return fit


def _undersample(train, validation, params, rng):
    from .baselines import undersample

    return undersample(train.X, train.y, params.get("ratio", 1.0), rng, params.get("C", 1.0))


def _focused(train, validation, params, rng):
    from .baselines import focused_resampling

    return focused_resampling(train.X, train.y, rng, params.get("C", 1.0))


def _zsvm(train, validation, params, rng):
    from .baselines import zsvm

    return zsvm(train.X, train.y, (validation.X, validation.y), rng, params.get("C", 1.0))


def _different_costs(train, validation, params, rng):
    from .baselines import different_costs

    positives = int((train.y > 0).sum())
    cost_ratio = params.get("cost_ratio", (len(train.y) - positives) / max(1, positives))
    return different_costs(train.X, train.y, cost_ratio, params.get("C", 1.0))


def _linear_tuned(train, validation, params, rng):
    from .baselines import linear_tuned

    return linear_tuned(train.X, train.y, params.get("C", 1.0))


def _cascade(train, validation, params, rng) -> Fitted:
    from .cascade import fit_cascade

    first = params.get("first", "linear-tuned")
    if first == "cascade":
        raise ValueError("a cascade's first stage must be a linear learner")
    # the cascade is handed its first stage's fit: it need not know the registry that lists it
    return fit_cascade(train, validation, params, rng, get_learner(first).fit)


# the learners whose fit starts with the same LinearSVC on every training example (linear-tuned; focused's
# first fit; the cascade's default first stage): the evaluation trains them in one process, which fits it once
# (`baselines.reused_fits`)
SHARED_FIT = ("linear-tuned", "focused", "cascade")

LEARNERS: dict[str, Learner] = {
    learner.name: learner
    for learner in (
        Learner("ssvm", "structured SVM optimising F1 with cutting planes (Joachims 2005)", _ssvm, 6),
        Learner("undersample", "linear SVM on randomly undersampled negatives", _baseline(_undersample), 3),
        Learner(
            "focused",
            "focused resampling near the boundary (Batuwita & Palade 2010)",
            _baseline(_focused),
            4,
        ),
        Learner(
            "zsvm", "zSVM: positive support vectors weighted by z (Imam et al. 2006)", _baseline(_zsvm), 11
        ),
        Learner("dcm", "different cost model: C+ and C- by the class ratio", _baseline(_different_costs), 27),
        Learner(
            "linear-tuned",
            "linear SVM on all data, threshold tuned for F1 (the baseline to beat)",
            _baseline(_linear_tuned),
            22,
        ),
        Learner(
            "cascade",
            "a linear first stage over every pose, its best few percent rescored by boosted trees",
            _cascade,
            14,
        ),
    )
}


def get_learner(name: str) -> Learner:
    if name not in LEARNERS:
        raise ValueError(f"unknown learner {name!r}; choose from {', '.join(LEARNERS)}")
    return LEARNERS[name]
