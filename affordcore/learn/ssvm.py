"""Structured SVM that optimises F1 directly (Joachims 2005), trained with 1-slack cutting planes.

The whole training set is one structured example. With Psi(x, y) = (1/n) sum_i y_i [x_i, b] (b = `bias`,
a bias feature regularised like the rest, as SVMperf's `--b`; Psi averaged, so that a plane is the size of
one example), the problem is

    min_w  1/2 |w|^2 + C n^2 xi    s.t.  w . (Psi(y) - Psi(y')) >= Delta(y, y') - xi   for every labelling y'

with Delta = loss_scale x (1 - F1) (percent, as SVMperf).

**Units of C.** `SSVMSettings.C` is the project's C: the slack weighs C n^2. Written with Psi summed and
labels +-1 (w_sum = w / n) it is the C of 1/2 |w_sum|^2 + C xi. SVMperf's is not that: for F1 it scales the
labels to +-50/n (`svm_struct_api.c`, 100 / 2 / n), so its Psi is 50 times ours and it solves the same
problem when

    C_project = 2500 C_svmperf / n^2,       w_project = 50 w_svmperf,

i.e. the slack weight is C n^2 = 2500 C_svmperf, whatever n. `SSVMSettings(c_svmperf=...)` takes SVMperf's
`-c` directly (`c_from_svmperf` / `c_to_svmperf` convert); since the slack weight 2500 C_svmperf does not
depend on n, SVMperf's units are the ones in which a C means the same for any training-set size, and the
default is given in them (`DEFAULT_C_SVMPERF`, chosen on generated validation rooms: docs/learning.md).

**The solver** (`method`):

* ``"cutting-plane"`` (default): SVMperf's 1-slack algorithm (`-w 3`). Each iteration adds the most
  violated labelling (exact, O(n): `f1_argmax.most_violated`) to the working set and re-solves its QP.
* ``"bundle"``: the same planes, plus the line search of OCAS (Franc & Sonnenburg 2009): the
  QP's solution w_c is not taken as the next iterate; the true objective F(w) = 1/2 |w|^2 + C n^2 R(w) is
  minimised on the segment from the best point so far w_b through w_c, and the next plane is cut at
  0.9 w_b + 0.1 w_c. Scores are linear in w, so with X w_b and X w_c known every point on the line is
  scored in O(n) and the line search costs argmax calls, not passes over X. It stops when F(w_b) exceeds the
  working set's lower bound by at most C n^2 epsilon: the guarantee SVMperf's stopping rule gives
  (F(w) - min F <= C n^2 epsilon), so both stop at the same accuracy of the same objective.

The working set's QP, min 1/2 |w|^2 + C n^2 xi s.t. plane_k . w >= Delta_k - xi, is solved with OSQP in its
primal form (d + 2 variables; its dual, over the planes' Gram matrix, is ill-conditioned: planes are sums
over thousands of examples and nearly parallel), one OSQP problem kept for the whole run: a fixed number
of constraint rows (free until a plane takes them), updated in place (`update(Ax=, l=, q=)`, a numeric
refactorisation, no new setup) and warm-started from the previous primal and dual solution. Planes whose
multiplier stays zero for `prune_after` iterations are dropped, as SVMperf does, and their rows freed.

Scores X w are float32 products on the caller's float32 X (never copied to float64): one matrix-vector
product per iteration for the training set; the validation set's are computed `validation_batch`
iterations at a time, one matrix product for all their weights (`_Validation`), since each product reads
the whole set from memory. A plane is summed from the rows its labelling flips (or, when that is most of
the data, from the class totals minus the rest) in float64.

Every iteration's weights are kept with training F1 and (given a validation set) validation F1, so the
caller picks the best on validation rooms; with a validation set it also stops once validation F1 has not
improved for `patience` iterations. It trains on every example given: no subsampling.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .f1_argmax import F1Counter, most_violated

SVMPERF_LABEL = 50.0  # SVMperf's F1 labels are +-SVMPERF_LABEL / n
DEFAULT_C_SVMPERF = 1.0e4  # SVMperf's -c; the slack weighs 2500 x this (chosen on generated validation rooms)


def c_from_svmperf(c_svmperf: float, n: int) -> float:
    """SVMperf's -c (F1 loss, n training examples) as this module's C: 2500 C_svmperf / n^2."""
    return SVMPERF_LABEL**2 * float(c_svmperf) / float(n) ** 2


def c_to_svmperf(C: float, n: int) -> float:
    """This module's C as SVMperf's -c for n training examples: C n^2 / 2500."""
    return float(C) * float(n) ** 2 / SVMPERF_LABEL**2


@dataclass(frozen=True)
class SSVMSettings:
    # The project's C: the slack weighs C n^2 (= 2500 C_svmperf). At most one of C and c_svmperf; with
    # neither, c_svmperf = DEFAULT_C_SVMPERF.
    C: float | None = None
    c_svmperf: float | None = None  # SVMperf's -c, the same at any n: the slack weighs 2500 x this
    bias: float = 1.0  # the bias feature's value, as SVMperf's --b (0: no bias)
    loss_scale: float = 100.0  # Delta in percent, as SVMperf
    epsilon: float = 0.1  # stop within this (loss units) of the optimum's slack, as SVMperf's -e
    method: str = "cutting-plane"  # SVMperf's -w 3; or "bundle" (OCAS's line search: fewer iterations)
    max_iterations: int = 500
    prune_after: int = 50  # drop a plane whose multiplier has been zero this many iterations
    warm_start: bool = True  # one OSQP problem updated and warm-started; False: set up afresh every solve
    patience: int = 100  # with a validation set: stop once its F1 has not improved for this many iterations
    # iterations whose validation F1 is computed together: one pass over the validation set for all of their
    # weights (a matrix product) instead of one each; the same F1 per iteration, known up to this many
    # iterations late (so a run stopped by `patience` may compute as many iterations more, then drops them)
    validation_batch: int = 16

    def __post_init__(self):
        if self.C is not None and self.c_svmperf is not None:
            raise ValueError("give C (this project's units) or c_svmperf (SVMperf's -c), not both")
        if self.method not in ("bundle", "cutting-plane"):
            raise ValueError(f"unknown method {self.method!r}: bundle or cutting-plane")
        if self.validation_batch < 1:
            raise ValueError(f"validation_batch must be at least 1, got {self.validation_batch}")

    def slack_weight(self, n: int) -> float:
        """The weight of the slack in the averaged problem: C n^2 = 2500 C_svmperf."""
        if self.C is not None:
            return float(self.C) * float(n) ** 2
        c = DEFAULT_C_SVMPERF if self.c_svmperf is None else self.c_svmperf
        return SVMPERF_LABEL**2 * float(c)


@dataclass
class Iteration:
    number: int
    weights: np.ndarray  # (n_features + 1,): the last entry multiplies the bias feature (`bias`)
    train_f1: float
    validation_f1: float | None
    violation: float  # cutting-plane: how far the newest plane exceeded the slack; bundle: the gap / (C n^2)
    slack: float
    planes: int
    seconds: float
    objective: float = float("nan")  # F(w) = 1/2 |w|^2 + C n^2 R(w) of these weights


@dataclass
class SSVMResult:
    iterations: list[Iteration] = field(default_factory=list)
    converged: bool = False
    bias: float = 1.0

    @property
    def best(self) -> Iteration:
        """The iteration with the best validation F1 (training F1 when there is no validation set)."""
        key = (
            (lambda it: it.validation_f1)
            if self.iterations[0].validation_f1 is not None
            else (lambda it: it.train_f1)
        )
        return max(self.iterations, key=key)


def decision(X: np.ndarray, weights: np.ndarray, bias: float = 1.0) -> np.ndarray:
    """Scores w . [x, bias], in X's precision (float32 for float32 X: no float64 copy of X)."""
    return X @ weights[:-1].astype(X.dtype, copy=False) + weights[-1] * bias


def objective(X: np.ndarray, y: np.ndarray, weights: np.ndarray, settings: SSVMSettings) -> float:
    """F(w) = 1/2 |w|^2 + C n^2 R(w), R the largest violation over all labellings (in loss units)."""
    y = np.where(np.asarray(y) > 0, 1, -1).astype(np.int8)
    scores = decision(X, weights, settings.bias).astype(np.float64)
    return 0.5 * float(weights @ weights) + settings.slack_weight(len(y)) * _risk(scores, y, settings)


def _risk(scores: np.ndarray, y: np.ndarray, settings: SSVMSettings, violator=None) -> float:
    """R(w) = max_y' Delta(y') - w . (Psi(y) - Psi(y')) from the scores alone."""
    n = len(y)
    violator = violator or most_violated(scores / (n * settings.loss_scale), y)
    positive = y > 0
    own = float(scores[positive].sum()) * 2 - float(scores.sum())  # sum_i y_i s_i
    return settings.loss_scale * violator.objective - own / n


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
    n, dims = len(y), X.shape[1] + 1
    weight = settings.slack_weight(n)
    planes = _Planes(X, y, settings.bias)
    qp = _WorkingSet(dims, weight, persistent=settings.warm_start)
    result = SSVMResult(bias=settings.bias)
    scorer = None if validation is None else _Validation(*validation, settings, result, on_iteration)
    train_f1 = F1Counter(y)
    start = time.perf_counter()
    # the best point so far (bundle) or the current iterate (cutting planes), its scores and objective
    w_b = np.zeros(dims)
    s_b = np.zeros(n)
    viol_b = most_violated(s_b, y)
    f_b = weight * _risk(s_b, y, settings, viol_b)
    cut_scores, cut_violator = s_b, viol_b
    bundle = settings.method == "bundle"
    for number in range(1, settings.max_iterations + 1):
        # the new plane: at w_b (cutting planes: the iterate) or at 0.9 w_b + 0.1 w_c (bundle)
        plane, loss = planes.plane(cut_violator, settings.loss_scale)
        slack = qp.slack(w_b)
        if bundle:
            violation = (f_b - qp.lower_bound) / weight if number > 1 else np.inf
        else:
            violation = loss - float(plane @ w_b) - slack
        iteration = Iteration(
            number,
            w_b.copy(),
            float(train_f1.f1(s_b)),
            None,  # validation F1: filled in by the scorer, a batch of iterations at a time
            violation,
            slack,
            qp.count,
            time.perf_counter() - start,
            f_b,
        )
        result.iterations.append(iteration)
        result.converged = violation <= settings.epsilon
        last = result.converged or number == settings.max_iterations
        if scorer is None:
            if on_iteration:
                on_iteration(iteration)
        elif scorer.add(iteration, flush=last):  # patience ran out at an iteration of this batch
            return result
        if result.converged:
            break
        qp.add(plane, loss)
        w_c = qp.solve(settings.prune_after)
        s_c = decision(X, w_c, settings.bias).astype(np.float64)
        if not bundle:
            w_b, s_b = w_c, s_c
            cut_scores = s_b
            cut_violator = most_violated(cut_scores / (n * settings.loss_scale), y)
            f_b = 0.5 * float(w_b @ w_b) + weight * _risk(s_b, y, settings, cut_violator)
            continue
        tau, f_b, viol_b = _line_search(w_b, w_c, s_b, s_c, y, settings, weight, f_b, viol_b)
        w_b = w_b + tau * (w_c - w_b)
        s_b = s_b + tau * (s_c - s_b)
        cut_scores = 0.9 * s_b + 0.1 * s_c  # where OCAS cuts: slightly towards the QP's solution
        cut_violator = most_violated(cut_scores / (n * settings.loss_scale), y)
    return result


class _Validation:
    """Validation F1 of the iterations' weights, `validation_batch` iterations at a time: X_v W for their
    weights W in one matrix product reads the validation set once instead of once per iteration (a float32
    matrix-vector product is memory-bound: at 1.3M x 222 that pass cost as much as the training set's).
    Stops the run where the per-iteration check did: at the first iteration `patience` after the best."""

    def __init__(self, X, y, settings: SSVMSettings, result: SSVMResult, on_iteration):
        self.X, self.counter = X, F1Counter(y)
        self.settings, self.result, self.on_iteration = settings, result, on_iteration
        self.pending: list[Iteration] = []
        self.best: Iteration | None = None

    def add(self, iteration: Iteration, flush: bool) -> bool:
        """Queue an iteration; score the queue when it is full or `flush`. True when patience ran out: the
        result is then cut after the iteration where it did (not converged)."""
        self.pending.append(iteration)
        if not flush and len(self.pending) < self.settings.validation_batch:
            return False
        pending, self.pending = self.pending, []
        weights = np.stack([it.weights for it in pending], axis=1)  # (d + 1, k)
        # X w > -b w_b rather than X w + b w_b > 0: the same decisions (a float64 sum is 0 only when exact),
        # without an (n, k) float64 copy of the scores
        scores = self.X @ weights[:-1].astype(self.X.dtype, copy=False)
        f1s = self.counter.f1(scores, -weights[-1] * self.settings.bias)
        for it, f1 in zip(pending, f1s):
            it.validation_f1 = float(f1)
            if self.best is None or it.validation_f1 > self.best.validation_f1:  # the first maximum, as max
                self.best = it
            if self.on_iteration:
                self.on_iteration(it)
            converged = self.result.converged and it is self.result.iterations[-1]
            if not converged and it.number - self.best.number >= self.settings.patience:
                del self.result.iterations[it.number :]
                self.result.converged = False
                return True
        return False


def _line_search(w_b, w_c, s_b, s_c, y, settings, weight, f_b, at_b, steps: int = 6):
    """min over tau >= 0 of F(w_b + tau (w_c - w_b)), F convex: a quadratic plus C n^2 times R, a convex
    piecewise-linear function of tau. Kelley's method in one dimension: each evaluation of R at a tau (one
    O(n) argmax on interpolated scores) gives its value and slope; the lower model (the quadratic plus the
    largest of those lines) is minimised exactly, and that is where R is evaluated next, until the model is
    within a tenth of epsilon of F (or `steps` evaluations). `at_b` is the most violated labelling at w_b
    (known from the previous search). Returns (tau, F at tau, the most violated labelling there)."""
    n = len(y)
    d = w_c - w_b
    a2, a1, a0 = (
        float(d @ d),
        float(w_b @ d),
        0.5 * float(w_b @ w_b),
    )  # 1/2 |w(tau)|^2 = a0 + a1 tau + a2 tau^2/2
    if a2 <= 0:
        return 0.0, f_b, at_b
    ds = s_c - s_b
    yf = y.astype(np.float64)
    y_ds, y_sb = float(ds @ yf) / n, float(s_b @ yf) / n

    def evaluate(tau: float, v=None):
        scores = s_b + tau * ds
        v = v or most_violated(scores / (n * settings.loss_scale), y)
        risk = settings.loss_scale * v.objective - (y_sb + tau * y_ds)
        # slope of R along the line: d/dtau of (1/n) sum y'_i s_i(tau) - (1/n) sum y_i s_i(tau)
        slope = float(v.labelling @ ds) / n - y_ds
        return risk, slope, v

    lines = []  # (tau_k, R_k, slope_k)
    best = (0.0, f_b, at_b)
    for tau, known in ((0.0, at_b), (1.0, None)):
        risk, slope, v = evaluate(tau, known)
        lines.append((tau, risk, slope))
        f = a0 + a1 * tau + 0.5 * a2 * tau**2 + weight * risk
        if f < best[1]:
            best = (tau, f, v)
    tolerance = 0.1 * settings.epsilon * weight
    for _ in range(steps):
        tau, model = _minimise_model(lines, a0, a1, a2, weight)
        if best[1] - model <= tolerance:
            break
        risk, slope, v = evaluate(tau)
        lines.append((tau, risk, slope))
        f = a0 + a1 * tau + 0.5 * a2 * tau**2 + weight * risk
        if f < best[1]:
            best = (tau, f, v)
    return best


def _minimise_model(lines, a0, a1, a2, weight) -> tuple[float, float]:
    """min over tau >= 0 of a0 + a1 tau + a2 tau^2 / 2 + weight max_k (R_k + g_k (tau - tau_k)): the
    minimiser lies where one line is active (a stationary point inside its interval) or at a crossing of
    two lines (or at 0); with a handful of lines every candidate is tried."""
    t = np.array([line[0] for line in lines])
    r = np.array([line[1] for line in lines])
    g = np.array([line[2] for line in lines])
    offsets = r - g * t  # line k: offsets_k + g_k tau
    candidates = [0.0]
    candidates += list(np.maximum(0.0, -(a1 + weight * g) / a2))
    for i in range(len(lines)):
        for j in range(i + 1, len(lines)):
            if g[i] != g[j]:
                cross = (offsets[j] - offsets[i]) / (g[i] - g[j])
                if cross > 0:
                    candidates.append(float(cross))
    taus = np.array(candidates)
    models = (
        a0
        + a1 * taus
        + 0.5 * a2 * taus**2
        + weight * np.max(offsets[None, :] + g[None, :] * taus[:, None], 1)
    )
    k = int(np.argmin(models))
    return float(taus[k]), float(models[k])


class _Planes:
    """Cutting planes Psi(y) - Psi(y') = (2/n) sum over the examples y' gets wrong of y_i [x_i, b], summed
    from the rows that flip, or from the class totals minus the rest when most rows flip."""

    block = 1 << 15

    def __init__(self, X: np.ndarray, y: np.ndarray, bias: float):
        self.X, self.y, self.bias = X, y, bias
        self.positive = y > 0
        self.pos_index, self.neg_index = np.flatnonzero(self.positive), np.flatnonzero(~self.positive)
        self.pos_total = self._sum(self.pos_index)
        self.neg_total = self._sum(self.neg_index)

    def _sum(self, index: np.ndarray) -> np.ndarray:
        total = np.zeros(self.X.shape[1])
        for i in range(0, len(index), self.block):
            total += self.X[index[i : i + self.block]].sum(axis=0, dtype=np.float64)
        return total

    def _class_sum(self, chosen: np.ndarray, members: np.ndarray, total: np.ndarray) -> np.ndarray:
        """Sum of X over `chosen`, a subset of the class `members` (whose sum is `total`)."""
        if len(chosen) <= len(members) // 2:
            return self._sum(chosen)
        mask = np.zeros(len(self.y), dtype=bool)
        mask[members] = True
        mask[chosen] = False
        return total - self._sum(np.flatnonzero(mask))

    def plane(self, violator, loss_scale: float) -> tuple[np.ndarray, float]:
        labelling = violator.labelling
        n = len(self.y)
        missed = self.pos_index[labelling[self.pos_index] < 0]  # false negatives: y = +1
        false_pos = self.neg_index[labelling[self.neg_index] > 0]  # false positives: y = -1
        total = self._class_sum(missed, self.pos_index, self.pos_total) - self._class_sum(
            false_pos, self.neg_index, self.neg_total
        )
        plane = np.append(total, self.bias * (len(missed) - len(false_pos))) * (2.0 / n)
        return plane, loss_scale * violator.loss


class _WorkingSet:
    """The working set's QP in one OSQP problem, kept for the whole run (module docstring).

    Variables are rescaled to order one (w = s v, xi = t eta; C n^2 reaches 1e12 on room data and OSQP
    crawls on raw scales) and rows normalised to unit length; the scales follow the working set, so each
    solve updates A's values, the bounds and q in place and warm-starts from the previous solution."""

    def __init__(self, dims: int, weight: float, capacity: int = 64, persistent: bool = True):
        self.dims, self.weight, self.persistent = dims, weight, persistent
        self.rows = np.zeros((0, dims))
        self.losses = np.empty(0)
        self.idle = np.empty(0, dtype=int)
        self.count = 0
        self.lower_bound = 0.0  # the working set's optimum: a lower bound on min F
        self._capacity = 0
        self._problem = None
        self._w = None
        self._y = None
        self._grow(capacity)

    def _grow(self, capacity: int):
        self._capacity = capacity
        self._problem = None  # set up again at the next solve, with room for `capacity` planes

    def slack(self, w: np.ndarray) -> float:
        if not self.count:
            return 0.0
        return max(0.0, float(np.max(self.losses - self.rows @ w)))

    def add(self, plane: np.ndarray, loss: float):
        self.rows = np.vstack([self.rows, plane])
        self.losses = np.append(self.losses, loss)
        self.idle = np.append(self.idle, 0)
        if self._y is not None:
            self._y = np.insert(self._y, self.count, 0.0)
        self.count += 1
        if self.count > self._capacity:
            self._grow(2 * self._capacity)

    def _setup(self, settings: dict):
        import osqp
        from scipy import sparse

        k, dims = self._capacity, self.dims
        # A: k plane rows over [v, eta] (dense) and the row eta >= 0; CSC with every entry stored
        indptr = np.concatenate([np.arange(dims + 1) * k, [dims * k + k + 1]])
        indices = np.concatenate([np.tile(np.arange(k), dims), np.arange(k + 1)])
        A = sparse.csc_matrix((np.zeros(len(indices)), indices, indptr), shape=(k + 1, dims + 1))
        P = sparse.diags(np.append(np.ones(dims), 0.0)).tocsc()
        problem = osqp.OSQP()
        problem.setup(
            P=P,
            q=np.zeros(dims + 1),
            A=A,
            l=np.append(np.full(k, -np.inf), 0.0),
            u=np.full(k + 1, np.inf),
            **settings,
        )
        self._problem = problem

    def solve(self, prune_after: int) -> np.ndarray:
        k, dims = self.count, self.dims
        norms = np.linalg.norm(self.rows, axis=1)
        norms = np.where(norms > 0, norms, 1.0)
        t = max(float(self.losses.max(initial=0.0)), 1e-12)
        s = max(float(np.max(self.losses / norms, initial=0.0)), 1e-12)
        if self._problem is None or not self.persistent:
            self._setup(
                dict(
                    verbose=False,
                    eps_abs=1e-6,
                    eps_rel=1e-6,
                    max_iter=100000,
                    polishing=True,
                    warm_starting=True,
                )
            )
            previous = None if not self.persistent else (self._w, self._y)
        else:
            previous = (self._w, self._y)
        cap = self._capacity
        coefficients = np.zeros((cap, dims + 1))
        coefficients[:k, :dims] = self.rows / norms[:, None]
        coefficients[:k, dims] = t / (s * norms)
        Ax = np.concatenate([coefficients.T.ravel(), [1.0]])
        lower = np.append(np.full(cap, -np.inf), 0.0)
        lower[:k] = self.losses / (s * norms)
        q = np.zeros(dims + 1)
        q[dims] = self.weight * t / s**2
        self._problem.update(Ax=Ax, l=lower, q=q)
        if self.persistent and previous is not None and previous[0] is not None:
            (w0, xi0), y0 = previous
            y_full = np.zeros(cap + 1)
            y_full[: min(len(y0), cap)] = y0[: min(len(y0), cap)]
            self._problem.warm_start(x=np.append(w0 / s, xi0 / t), y=y_full)
        solution = self._problem.solve(raise_error=False)
        if solution.x is None or not np.all(np.isfinite(solution.x)):
            raise RuntimeError(f"OSQP failed on the working set ({solution.info.status})")
        w = s * solution.x[:dims]
        xi = max(0.0, t * float(solution.x[dims]))
        self.lower_bound = 0.5 * float(w @ w) + self.weight * xi
        # warm start next time in the next scales' units: keep the solution in w, xi and convert then
        alpha = np.clip(-solution.y[:k], 0.0, None) / norms  # up to one common factor
        self.idle = np.where(alpha > 1e-9 * max(1.0, alpha.max(initial=0.0)), 0, self.idle + 1)
        keep = self.idle <= prune_after
        duals = solution.y[:k][keep]
        self.rows, self.losses, self.idle = self.rows[keep], self.losses[keep], self.idle[keep]
        self.count = len(self.losses)
        self._w, self._y = (w.copy(), xi), duals.copy()
        return w
