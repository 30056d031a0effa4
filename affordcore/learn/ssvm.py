"""Structured SVM that optimises F1 directly (Joachims 2005), trained with 1-slack cutting planes.

The whole training set is one structured example. With Psi(x, y) = (1/n) sum_i y_i [x_i, 1] (a bias column
that is regularised like the rest, as SVMperf's; averaged, so that a plane is the size of one example and the
cutting-plane iteration bound, which grows with C max|plane|^2, does not grow with n^2: unaveraged, 50,000
Gaussian examples did not converge in 300 iterations, averaged they converge in 37-167), the problem is

    min_w  1/2 |w|^2 + C xi    s.t.  w . (Psi(y) - Psi(y')) >= Delta(y, y') - xi   for every labelling y'

with Delta = loss_scale x (1 - F1). `SSVMSettings.C` is SVMperf's C, for its unaveraged Psi; with w = n w_perf
the same problem weighs the slack by C n^2, so a C means the same at every n (and the iteration count,
governed by C and how many labels a plane flips, does not grow with n). The default C was chosen on held-out
generated rooms (docs/learning.md). Each iteration
adds the most violated labelling (exact, O(n log n): `f1_argmax.most_violated`) to a working set and re-solves
the working set's dual with OSQP, warm-started from the previous solution:

    max_alpha  Delta . alpha - 1/2 |D^T alpha|^2    s.t.  alpha >= 0,  sum(alpha) <= C,    w = D^T alpha

where row k of D is Psi(y) - Psi(y'_k). Planes whose alpha stays zero for `prune_after` iterations are
dropped, as SVMperf does. It stops when no labelling is violated by more than `epsilon` beyond the current
slack, or (given validation rooms) when their F1 has not improved for `patience` iterations. Every
iteration's weights are kept, with training F1 and (given a validation set) validation F1, so the caller
picks the best on validation rooms. It trains on every example given: no subsampling.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .f1_argmax import f1_at, most_violated


@dataclass(frozen=True)
class SSVMSettings:
    C: float = 2.0  # SVMperf's C (Psi summed, not averaged): the solver weighs the slack by C n^2
    loss_scale: float = 100.0  # Delta in percent, as SVMperf
    epsilon: float = 0.1  # stop when the most violated constraint is within this of the slack (loss units)
    max_iterations: int = 500
    prune_after: int = 50
    patience: int = 100  # with a validation set: stop once its F1 has not improved for this many iterations


@dataclass
class Iteration:
    number: int
    weights: np.ndarray  # (n_features + 1,): the last entry is the bias
    train_f1: float
    validation_f1: float | None
    violation: float  # how far the newest plane exceeded the slack
    slack: float
    planes: int
    seconds: float


@dataclass
class SSVMResult:
    iterations: list[Iteration] = field(default_factory=list)
    converged: bool = False

    @property
    def best(self) -> Iteration:
        """The iteration with the best validation F1 (training F1 when there is no validation set)."""
        key = (
            (lambda it: it.validation_f1)
            if self.iterations[0].validation_f1 is not None
            else (lambda it: it.train_f1)
        )
        return max(self.iterations, key=key)


def decision(X: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Scores w . [x, 1]."""
    return X @ weights[:-1].astype(X.dtype, copy=False) + weights[-1]


def train_ssvm(
    X: np.ndarray,
    y: np.ndarray,
    settings: SSVMSettings | None = None,
    validation: tuple[np.ndarray, np.ndarray] | None = None,
    on_iteration: Callable[[Iteration], None] | None = None,
) -> SSVMResult:
    settings = settings or SSVMSettings()
    y = np.where(np.asarray(y) > 0, 1, -1).astype(np.int8)
    if not (y > 0).any():
        raise ValueError("no positive examples to learn from")
    weights = np.zeros(X.shape[1] + 1)
    planes = np.empty((0, X.shape[1] + 1))
    losses = np.empty(0)
    idle = np.empty(0, dtype=int)
    result = SSVMResult()
    start = time.perf_counter()
    for number in range(1, settings.max_iterations + 1):
        scores = decision(X, weights)
        # argmax of loss_scale Delta + Psi(y') . w
        violator = most_violated(scores / (len(y) * settings.loss_scale), y)
        plane = _plane(X, y, violator.labelling)
        loss = settings.loss_scale * violator.loss
        slack = max(0.0, float(np.max(losses - planes @ weights))) if len(losses) else 0.0
        violation = loss - float(plane @ weights) - slack
        result.iterations.append(
            Iteration(
                number,
                weights.copy(),
                f1_at(scores, y),
                None if validation is None else f1_at(decision(validation[0], weights), validation[1]),
                violation,
                slack,
                len(losses),
                time.perf_counter() - start,
            )
        )
        if on_iteration:
            on_iteration(result.iterations[-1])
        if violation <= settings.epsilon:
            result.converged = True
            break
        if validation is not None and number - result.best.number >= settings.patience:
            break
        planes, losses = np.vstack([planes, plane]), np.append(losses, loss)
        weights, slack, alpha = _solve_working_set(
            planes, losses, settings.C * float(len(y)) ** 2, np.append(weights, slack)
        )
        idle = np.append(idle, 0)
        idle = np.where(alpha > 1e-9 * max(1.0, alpha.max(initial=0.0)), 0, idle + 1)
        keep = idle <= settings.prune_after
        planes, losses, alpha, idle = planes[keep], losses[keep], alpha[keep], idle[keep]
    return result


def _plane(X: np.ndarray, y: np.ndarray, labelling: np.ndarray) -> np.ndarray:
    """Psi(y) - Psi(y') = (2/n) sum over the examples y' gets wrong of y_i [x_i, 1]. Early planes flip most
    of the data: those go through one float32 matrix-vector product per block, summed in float64."""
    differ = np.flatnonzero(labelling != y)
    if len(differ) < len(y) // 8:
        total = y[differ].astype(np.float64) @ X[differ]
    else:
        signs = np.zeros(len(y), dtype=X.dtype)
        signs[differ] = y[differ]
        block = 1 << 16
        total = np.sum(
            [signs[i : i + block] @ X[i : i + block] for i in range(0, len(y), block)],
            axis=0,
            dtype=np.float64,
        )
    return np.append(2.0 * total, 2.0 * float(y[differ].sum())) / len(y)


def _solve_working_set(planes: np.ndarray, losses: np.ndarray, C: float, warm: np.ndarray | None):
    """The working set's QP, min 1/2 |w|^2 + C xi s.t. plane_k . w >= Delta_k - xi, xi >= 0, with OSQP.

    Solved in its primal form, and each plane's dual variable alpha_k read from OSQP's multipliers: the dual's
    Gram matrix of planes (sums over thousands of examples, many nearly parallel) is so ill-conditioned that
    OSQP returned weights off by orders of magnitude, while the primal's quadratic term is the identity.
    Rows are normalised to unit length and the variables rescaled to order one (w = s v, xi = t eta):
    C n^2 reaches 1e12 on room data and OSQP crawled on the raw scales. Returns (w, xi, alpha)."""
    import osqp
    from scipy import sparse

    k, dims = planes.shape
    norms = np.linalg.norm(planes, axis=1)
    norms = np.where(norms > 0, norms, 1.0)
    t = max(float(losses.max(initial=0.0)), 1e-12)  # the loss scale
    s = max(float(np.max(losses / norms, initial=0.0)), 1e-12)  # the weight scale that meets every plane
    # [plane_k, 1] . [w, xi] >= Delta_k, scaled
    rows = np.hstack([planes / norms[:, None], (t / (s * norms))[:, None]])
    A = sparse.vstack(
        [sparse.csc_matrix(rows), sparse.csc_matrix(([1.0], ([0], [dims])), shape=(1, dims + 1))]
    ).tocsc()
    P = sparse.diags(np.append(np.ones(dims), 0.0)).tocsc()
    q = np.append(np.zeros(dims), C * t / s**2)
    problem = osqp.OSQP()
    problem.setup(
        P=P,
        q=q,
        A=A,
        l=np.append(losses / (s * norms), 0.0),
        u=np.full(k + 1, np.inf),
        verbose=False,
        eps_abs=1e-6,
        eps_rel=1e-6,
        max_iter=100000,
        polishing=True,
    )
    if warm is not None:
        problem.warm_start(x=np.append(warm[:dims] / s, warm[dims] / t))
    solution = problem.solve(raise_error=False)
    if solution.x is None or not np.all(np.isfinite(solution.x)):
        raise RuntimeError(f"OSQP failed on the working set ({solution.info.status})")
    # up to one common factor: only compared with each other
    alpha = np.clip(-solution.y[:k], 0.0, None) / norms
    return s * solution.x[:dims], max(0.0, t * float(solution.x[dims])), alpha
