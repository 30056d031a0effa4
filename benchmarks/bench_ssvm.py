"""The structured SVM: time to the best validation F1, the new solver against the previous one side by side
(and against SVMperf when its binary is given), medians over repeats, each run in a fresh process.

What a user waits for is the time until the iteration that validation picks (the model `afford train`
keeps), so that is the first column; the time to convergence at epsilon and the objective reached are
beside it. Set-ups:

* generated rooms: the training set `afford train` builds (every positive pose and 20,000 sampled negatives
  a room, at most 500,000 negatives) from 24 generated training rooms, validated on the 16 validation rooms
  of the accuracy data set (`afford synth --rooms 150 --seed 1`, rooms 110-125); never its test rooms
  (126-149) and never ../shared/data/rooms. Features are cached in `--cache`.
* DESIGN.md's Gaussian: 200,000 training and 200,000 validation examples, 100 features, 1:1000, positives
  shifted by 0.35 (its optimum is next to w = 0, whose objective is within 1 % of it: the validation F1
  there is a property of the solver's path, not of the optimum).
* The largest case: 1.3 million training and 1.3 million validation examples, 222 features (the rooms'
  width), 1:12,000 (the rarest affordance's imbalance: about 108 positives), positives shifted by 0.35,
  features at steps of 0.01 so that SVMperf's text file holds exactly the float32 values we train on.

Solvers (`--solvers`): `previous` is the solver this replaced (kept below, verbatim but for its name: a
stable sort of every negative per argmax, OSQP set up afresh each iteration); `cutting-plane` is the
default (SVMperf's 1-slack algorithm); `bundle` adds OCAS's line search; `METHOD/B` runs METHOD with B
iterations' validation F1 computed in one pass (`validation_batch`; `cutting-plane/1`: one pass each, as
before batching). With `--svmperf PATH`, SVMperf's
`svm_perf_learn -c C -l 1 -w 3 --b 1 -e 0.1` runs on the same data (written in SVMlight's format; the file
writing is not timed) and its model is read back and scored by our objective (w_project = 50 w_svmperf).
SVMperf's time is its own report ("Runtime in cpu-seconds": training only, not reading its text file; CPU
seconds of its one thread, which on a shared machine flatters it against our wall-clock seconds). SVMperf
keeps its last iterate, so the comparison is to the same validation F1: the seconds our solver takes to
first reach SVMperf's validation F1 (`to SVMperf's F1`), against SVMperf's seconds. Its training file is
written once into `--cache` (a few GB for the largest case). SVMperf is licensed for non-commercial use:
it is never vendored or downloaded here; build it from its public source (docs/benchmarks.md).

    .venv/bin/python benchmarks/bench_ssvm.py                   # 15 minutes on 2 cores, + the 1.3M case
    .venv/bin/python benchmarks/bench_ssvm.py --quick           # one room set-up, one repeat
    .venv/bin/python benchmarks/bench_ssvm.py --svmperf ~/svm_perf/svm_perf_learn
    .venv/bin/python benchmarks/bench_ssvm.py --svmperf PATH --only 1.3M --solvers cutting-plane --repeats 2
    .venv/bin/python benchmarks/bench_ssvm.py --sweep-c 1e2,1e3,1e4,1e5,1e6   # the default C's choice
    .venv/bin/python benchmarks/bench_ssvm.py --only 1.3M --solvers cutting-plane --old /tmp/old-afford

With ``--old PATH`` (a git worktree of an earlier commit) every solver also runs as ``old:SOLVER``, that
commit's code in a process spawned with it on PYTHONPATH, alternating with this one's on the same data; the
"previous / this" column is then that commit's time to the best model over this one's.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import pickle
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from affordcore.learn.f1_argmax import f1_at, most_violated_sorted
from affordcore.learn.ssvm import SSVMSettings, c_from_svmperf, objective, train_ssvm

ROOT = Path(__file__).resolve().parents[1]
ROOMS = ROOT / "bench-data" / "accuracy"
TRAIN_ROOMS, VALIDATION, TEST = 24, 16, 24


# --- the data -------------------------------------------------------------------------------------------


def room_set(affordance: str, rooms: Path, cache: Path) -> Path:
    """The training and validation examples of one affordance, cached as .npz."""
    path = cache / f"{affordance}-{TRAIN_ROOMS}.npz"
    if path.exists():
        return path
    from affordcore.geometry.features import FeatureLayout
    from affordcore.learn.defaults import split_by_index
    from affordcore.learn.examples import Task, data_set_rooms, load_rooms, room_examples, stack
    from affordcore.settings import Settings

    files = data_set_rooms(rooms)
    train, validation, _test = split_by_index([f.name for f in files], VALIDATION, TEST)  # test: never read
    train = train[:TRAIN_ROOMS]
    settings = Settings()
    loaded = load_rooms([f for f in files if f.name in set(train) | set(validation)], settings)
    task = Task(affordance, settings, FeatureLayout.from_settings(settings))
    examples = {room.name: room_examples(room, task) for room in loaded}
    training = stack(
        examples,
        train,
        settings.learn.max_negatives,
        np.random.default_rng([0, 2]),
        settings.learn.max_positives,
    )
    held = stack(examples, validation)
    cache.mkdir(parents=True, exist_ok=True)
    np.savez(path, X=training.X, y=training.y, Xv=held.X, yv=held.y)
    return path


def gaussian(rng: np.random.Generator, n: int, d: int = 100, ratio: int = 1000, shift: float = 0.35):
    y = np.where(rng.random(n) < 1 / (ratio + 1), 1, -1)
    y[:5] = 1
    X = rng.normal(size=(n, d)).astype(np.float32)
    X[y > 0] += shift
    return X, y


def gaussian_steps(rng: np.random.Generator, n: int, d: int, ratio: int, shift: float = 0.35):
    """`gaussian`, drawn in float32 blocks (no float64 copy of a GB-sized X) and rounded to steps of 0.01:
    float32(k) / 100 is the float32 nearest k / 100, which is what SVMperf stores when it reads "k/100"."""
    y = np.where(rng.random(n) < 1 / (ratio + 1), 1, -1)
    y[:5] = 1
    X = np.empty((n, d), dtype=np.float32)
    block = 1 << 16
    for i in range(0, n, block):
        part = rng.standard_normal((min(block, n - i), d), dtype=np.float32)
        part[y[i : i + block] > 0] += shift
        X[i : i + block] = np.round(part * 100) / np.float32(100)
    return X, y


BIG = "gaussian 1.3M x 222 1:12000"


def load(setup: str, cache: Path, quick: bool):
    if setup.startswith("rooms "):
        data = np.load(cache / f"{setup.split()[1]}-{TRAIN_ROOMS}.npz")
        return data["X"], data["y"], data["Xv"], data["yv"]
    rng = np.random.default_rng(0)
    if setup == BIG:
        n = 130_000 if quick else 1_300_000
        return *gaussian_steps(rng, n, 222, 12_000), *gaussian_steps(rng, n, 222, 12_000)
    n = 20_000 if quick else 200_000
    X, y = gaussian(rng, n)
    Xv, yv = gaussian(rng, n)
    return X, y, Xv, yv


# --- the runs -------------------------------------------------------------------------------------------


def run(
    setup: str, solver: str, c_svmperf: float, cache: Path, svmperf: str | None, quick: bool, limit: float
) -> dict:
    """One training run in this (fresh) process: time to the best validation F1 and to the end."""
    solver = solver.removeprefix("old:")  # the process imported the older commit's code: the same solver
    X, y, Xv, yv = load(setup, cache, quick)
    settings = SSVMSettings(c_svmperf=c_svmperf, max_iterations=300)
    if solver == "svmperf":
        return _svmperf(X, y, Xv, yv, settings, svmperf, _svmlight_file(setup, cache, quick, X, y), limit)
    start = time.perf_counter()
    if solver == "previous":
        result = previous_train_ssvm(
            X, y, PreviousSettings(C=c_from_svmperf(c_svmperf, len(y)), max_iterations=300), (Xv, yv)
        )
    else:  # "METHOD" or "METHOD/B": B iterations' validation F1 computed together (1: one at a time)
        method, _, batch = solver.partition("/")
        batch = {"validation_batch": int(batch)} if batch else {}
        settings = SSVMSettings(c_svmperf=c_svmperf, method=method, max_iterations=300, **batch)
        result = train_ssvm(X, y, settings, validation=(Xv, yv))
    seconds = time.perf_counter() - start
    best, last = result.best, result.iterations[-1]
    return {
        "to_best": best.seconds,
        "seconds": seconds,
        "best": best.number,
        "iterations": len(result.iterations),
        "converged": result.converged,
        "val_f1": best.validation_f1,
        # F(w) / (C n^2): the objective in loss units (100 = w = 0's), at the last iteration
        "objective": objective(X, y, last.weights, settings) / settings.slack_weight(len(y)),
        "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        # (seconds, validation F1) of every iteration: when it first reaches a given F1
        "trace": [(it.seconds, it.validation_f1) for it in result.iterations],
        "code": str(Path(sys.modules["affordcore"].__file__).parent.parent),  # which commit's code ran
    }


def _svmlight_file(setup: str, cache: Path, quick: bool, X: np.ndarray, y: np.ndarray) -> Path:
    """The training set in SVMlight's text format, written once per set-up into the cache (not timed)."""
    from sklearn.datasets import dump_svmlight_file

    path = cache / f"{setup.replace(' ', '_').replace(':', '-')}{'-quick' if quick else ''}.svmlight"
    if path.exists():
        return path
    cache.mkdir(parents=True, exist_ok=True)
    partial = path.with_suffix(".partial")
    labels = np.where(y > 0, 1, -1)
    with open(partial, "wb") as out:  # in blocks: a float64 copy of one block at a time
        for i in range(0, len(y), 1 << 16):
            part = X[i : i + (1 << 16)].astype(np.float64)
            if setup == BIG:  # k / 100 written as such ("1.23"), not as float32's long expansion
                part = np.round(part * 100) / 100
            dump_svmlight_file(part, labels[i : i + (1 << 16)], out, zero_based=False)
    partial.rename(path)
    return path


def _svmperf(X, y, Xv, yv, settings: SSVMSettings, binary: str, train: Path, limit: float) -> dict:
    """SVMperf on the same data: `svm_perf_learn -c C -l 1 -w 3 --b 1 -e eps train model` (-l 1: F1 loss,
    -w 3: the 1-slack dual algorithm, --b: the bias feature's value, -e: epsilon). Its model file is
    SVMlight's: a header ending in the line `<b> # threshold b`, then `<alpha*y> <index>:<value> ...` lines
    whose sum is w (one line for a linear model); its score is w . x - b. Stopped after `limit` seconds
    of wall time: then only the CPU seconds it had used (file reading included) are known."""
    with tempfile.TemporaryDirectory(prefix="svmperf-") as folder:
        model = Path(folder) / "model"
        command = [binary, "-c", f"{settings.c_svmperf:g}", "-l", "1", "-w", "3", "--b", f"{settings.bias:g}"]
        command += ["-e", f"{settings.epsilon:g}", str(train), str(model)]
        start = time.perf_counter()
        try:
            report = subprocess.run(command, check=True, capture_output=True, text=True, timeout=limit).stdout
        except subprocess.TimeoutExpired:  # killed and waited for: its CPU time is this process's children's
            used = resource.getrusage(resource.RUSAGE_CHILDREN)
            return {
                **dict.fromkeys(("best", "iterations"), "-"),
                **dict.fromkeys(("val_f1", "objective"), float("nan")),
                "to_best": used.ru_utime + used.ru_stime,
                "seconds": used.ru_utime + used.ru_stime,
                "converged": False,
                "stopped": limit,
                "peak_mb": used.ru_maxrss / 1024,
            }
        wall = time.perf_counter() - start
        lines = model.read_text().splitlines()
    seconds = _reported(report, "Runtime in cpu-seconds:", float)
    d = X.shape[1]
    at = next(i for i, line in enumerate(lines) if "threshold b" in line)
    threshold = float(lines[at].split()[0])
    w = np.zeros(d + 1)  # index d + 1 (1-based): the bias feature, when SVMperf writes it out
    for line in lines[at + 1 :]:
        tokens = line.split("#")[0].split()
        if tokens:
            factor = float(tokens[0])
            for token in tokens[1:]:
                index, value = token.split(":")
                if index.isdigit() and int(index) <= d + 1:
                    w[int(index) - 1] += factor * float(value)
    # our weights score 50 times SVMperf's: w . [x, bias] = 50 (w_perf . x + w_perf,bias bias - b)
    weights = 50.0 * np.append(w[:d], (w[d] * settings.bias - threshold) / max(settings.bias, 1e-12))
    scores_v = Xv @ weights[:-1].astype(np.float32) + weights[-1] * settings.bias
    return {
        "to_best": seconds,  # SVMperf keeps its last iterate: its model is the one at convergence
        "seconds": seconds,
        "wall": wall,  # with reading the text file
        "best": "-",
        "iterations": _reported(report, "Number of iterations:", int),
        "converged": True,
        "val_f1": f1_at(scores_v, yv),
        "objective": objective(X, y, weights, settings) / settings.slack_weight(len(y)),
        "peak_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024,
    }


def _reported(report: str, label: str, kind):
    """A number SVMperf prints after `label`."""
    line = next((line for line in report.splitlines() if line.startswith(label)), None)
    if line is None:
        raise RuntimeError(f"SVMperf's output has no {label!r} line:\n{report[-2000:]}")
    return kind(line[len(label) :].split()[0])


# --- the previous solver, kept to be measured against ------------------------------------------------------


@dataclass(frozen=True)
class PreviousSettings:
    C: float = 2.0
    loss_scale: float = 100.0
    epsilon: float = 0.1
    max_iterations: int = 500
    prune_after: int = 50
    patience: int = 100


@dataclass
class PreviousIteration:
    number: int
    weights: np.ndarray
    train_f1: float
    validation_f1: float | None
    violation: float
    slack: float
    planes: int
    seconds: float


@dataclass
class PreviousResult:
    iterations: list[PreviousIteration] = field(default_factory=list)
    converged: bool = False

    @property
    def best(self) -> PreviousIteration:
        return max(self.iterations, key=lambda it: it.validation_f1)


def _decision(X, weights):
    return X @ weights[:-1].astype(X.dtype, copy=False) + weights[-1]


def previous_train_ssvm(X, y, settings, validation, on_iteration: Callable | None = None) -> PreviousResult:
    y = np.where(np.asarray(y) > 0, 1, -1).astype(np.int8)
    weights = np.zeros(X.shape[1] + 1)
    planes = np.empty((0, X.shape[1] + 1))
    losses = np.empty(0)
    idle = np.empty(0, dtype=int)
    result = PreviousResult()
    start = time.perf_counter()
    for number in range(1, settings.max_iterations + 1):
        scores = _decision(X, weights)
        violator = most_violated_sorted(scores / (len(y) * settings.loss_scale), y)
        plane = _previous_plane(X, y, violator.labelling)
        loss = settings.loss_scale * violator.loss
        slack = max(0.0, float(np.max(losses - planes @ weights))) if len(losses) else 0.0
        violation = loss - float(plane @ weights) - slack
        result.iterations.append(
            PreviousIteration(
                number,
                weights.copy(),
                f1_at(scores, y),
                f1_at(_decision(validation[0], weights), validation[1]),
                violation,
                slack,
                len(losses),
                time.perf_counter() - start,
            )
        )
        if violation <= settings.epsilon:
            result.converged = True
            break
        if number - result.best.number >= settings.patience:
            break
        planes, losses = np.vstack([planes, plane]), np.append(losses, loss)
        weights, slack, alpha = _previous_solve(
            planes, losses, settings.C * float(len(y)) ** 2, np.append(weights, slack)
        )
        idle = np.append(idle, 0)
        idle = np.where(alpha > 1e-9 * max(1.0, alpha.max(initial=0.0)), 0, idle + 1)
        keep = idle <= settings.prune_after
        planes, losses, alpha, idle = planes[keep], losses[keep], alpha[keep], idle[keep]
    return result


def _previous_plane(X, y, labelling):
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


def _previous_solve(planes, losses, C, warm):
    import osqp
    from scipy import sparse

    k, dims = planes.shape
    norms = np.linalg.norm(planes, axis=1)
    norms = np.where(norms > 0, norms, 1.0)
    t = max(float(losses.max(initial=0.0)), 1e-12)
    s = max(float(np.max(losses / norms, initial=0.0)), 1e-12)
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
    problem.warm_start(x=np.append(warm[:dims] / s, warm[dims] / t))
    solution = problem.solve(raise_error=False)
    alpha = np.clip(-solution.y[:k], 0.0, None) / norms
    return s * solution.x[:dims], max(0.0, t * float(solution.x[dims])), alpha


# --- the table ------------------------------------------------------------------------------------------


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--svmperf", help="path to SVMperf's svm_perf_learn (not shipped: non-commercial licence)"
    )
    parser.add_argument(
        "--rooms", type=Path, default=ROOMS, help="`afford synth --rooms 150 --seed 1` output"
    )
    parser.add_argument("--cache", type=Path, default=ROOT / "bench-data" / "ssvm")
    parser.add_argument("--c-svmperf", type=float, default=None, help="C in SVMperf's units (default: ours)")
    parser.add_argument("--sweep-c", help="comma-separated C (SVMperf's units): validation F1 per affordance")
    parser.add_argument(
        "--only", help="run the set-ups whose name contains one of these (comma-separated: 1.3M,rooms)"
    )
    parser.add_argument("--solvers", default="previous,cutting-plane,bundle", help="comma-separated")
    parser.add_argument(
        "--svmperf-limit", type=float, default=1800.0, help="seconds (wall) after which SVMperf is stopped"
    )
    parser.add_argument("--old", type=Path, help="a worktree of an earlier commit: its solvers side by side")
    args = parser.parse_args()
    if args.sweep_c:
        sweep_c([float(c) for c in args.sweep_c.split(",")], args.rooms, args.cache)
        return
    from affordcore.learn.ssvm import DEFAULT_C_SVMPERF

    c = args.c_svmperf or DEFAULT_C_SVMPERF
    setups = [
        ("rooms sitting-relaxing", c),
        ("rooms standing-working", c),
        ("gaussian 200k x 100", 1e4),
        (BIG, c),
    ]
    if args.only:
        wanted = args.only.split(",")
        setups = [(setup, c_setup) for setup, c_setup in setups if any(w in setup for w in wanted)]
    if args.quick:  # the first set-up (of those --only leaves), at a tenth of its size for the Gaussians
        setups, args.repeats = setups[:1], 1
    for setup, _ in setups:
        if setup.startswith("rooms "):
            if not args.rooms.is_dir():
                raise SystemExit(
                    f"{args.rooms}: make it with `afford synth --rooms 150 --seed 1 --out {args.rooms}`"
                )
            room_set(setup.split()[1], args.rooms, args.cache)
    solvers = args.solvers.split(",")
    solvers += [f"old:{solver}" for solver in solvers if args.old] + (["svmperf"] if args.svmperf else [])
    context = multiprocessing.get_context("forkserver")  # a fresh small process per run: honest peak memory
    print(
        f"{os.cpu_count()} cores, median of {args.repeats} (solvers alternated within each repeat); "
        "to best = seconds to the iteration validation picks (SVMperf: its reported CPU seconds, reading "
        "its file excluded); objective = F(w) / (C n^2) at the end (100: w = 0's); to SVMperf's F1 = "
        "seconds to the first iteration whose validation F1 reaches SVMperf's"
    )
    print(
        "| set-up (C in SVMperf's units) | solver | to best s | total s | iterations (best / run) | "
        "converged | validation F1 | objective | peak MB | previous / this, to best | "
        "to SVMperf's F1 s | SVMperf / this |"
    )
    print("|---|---|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|")
    for setup, c_setup in setups:
        runs: dict[str, list[dict]] = {s: [] for s in solvers}
        for _ in range(args.repeats):
            for solver in solvers:
                given = (setup, solver, c_setup, args.cache, args.svmperf, args.quick, args.svmperf_limit)
                if solver.startswith("old:"):
                    runs[solver].append(_run_older(given, args.old))
                else:
                    with context.Pool(1) as pool:
                        runs[solver].append(pool.apply(run, given))
                r = runs[solver][-1]  # each run as it ends, on stderr: a long run's results survive a stop
                print(
                    f"{setup} {solver}: {r['to_best']:.1f} s, F1 {r['val_f1']:.3f}"
                    + (f" ({r['code']})" if "code" in r else ""),
                    file=sys.stderr,
                    flush=True,
                )
        for solver in solvers:
            print(f"| {setup} (C={c_setup:g}) | {solver} | " + _row(runs, solver), flush=True)


def _run_older(given: tuple, code: Path) -> dict:
    """`run` in a fresh interpreter that imports the older commit's affordcore from `code` (first on its
    path); the arguments and the result go through pickle on its standard streams."""
    script = (
        "import pickle, sys; sys.path[:0] = sys.argv[1:3]; import affordcore, bench_ssvm; "
        "sys.stdout.buffer.write(pickle.dumps(bench_ssvm.run(*pickle.loads(sys.stdin.buffer.read()))))"
    )
    done = subprocess.run(
        [sys.executable, "-c", script, str(code), str(Path(__file__).parent)],
        input=pickle.dumps(given),
        capture_output=True,
        cwd=code,
    )
    if done.returncode:
        raise RuntimeError(f"the run with {code}'s code failed:\n{done.stderr.decode(errors='replace')}")
    return pickle.loads(done.stdout)


def _row(runs: dict[str, list[dict]], solver: str) -> str:
    """The table's columns after the set-up and the solver, medians over the repeats."""
    rs = runs[solver]
    to_best = statistics.median(r["to_best"] for r in rs)
    r = rs[len(rs) // 2]
    cells = [
        f"{to_best:.1f}",
        f"{statistics.median(x['seconds'] for x in rs):.1f}",
        f"{r['best']} / {r['iterations']}",
        "yes" if r["converged"] else "no",
        f"{statistics.median(x['val_f1'] for x in rs):.3f}",
        f"{statistics.median(x['objective'] for x in rs):.2f}",
        f"{max(x['peak_mb'] for x in rs):,.0f}",
    ]
    previous = runs.get(f"old:{solver}") or runs.get("previous")
    cells.append(f"{statistics.median(x['to_best'] for x in previous) / to_best:.1f}x" if previous else "-")
    stopped = [x for x in runs.get("svmperf", []) if x.get("stopped")]
    if stopped:  # SVMperf did not finish: no F1 of its own, only the CPU seconds it used before it stopped
        svmperf_cpu = min(x["to_best"] for x in stopped)
        cells += (
            [f"stopped unfinished after {stopped[0]['stopped']:.0f} s wall, {svmperf_cpu:.0f} CPU s", "-"]
            if solver == "svmperf"
            else ["-", f"> {svmperf_cpu / to_best:.0f}x (to our best)"]
        )
    elif "svmperf" not in runs or solver == "svmperf":
        cells += ["-", "-"] if solver != "svmperf" else [f"{to_best:.1f}", "1.0x"]
    else:
        target = statistics.median(x["val_f1"] for x in runs["svmperf"])
        reached = [next((t for t, f in x["trace"] if f >= target), None) for x in rs]
        if any(t is None for t in reached):
            cells += [f"not reached in {sum(t is None for t in reached)} of {len(rs)}", "-"]
        else:
            seconds = statistics.median(reached)
            cells += [
                f"{seconds:.2f}",
                f"{statistics.median(x['to_best'] for x in runs['svmperf']) / seconds:.1f}x",
            ]
    return " | ".join(cells) + " |"


def sweep_c(values: list[float], rooms: Path, cache: Path) -> None:
    """The default C's choice: the best validation F1 of the default solver per C and affordance."""
    print("| affordance | C (SVMperf's units) | validation F1 | best iteration / run | to best s |")
    print("|---|---:|---:|---:|---:|")
    for affordance in ("sitting-relaxing", "sitting-working", "standing-working"):
        data = np.load(room_set(affordance, rooms, cache))
        for c in values:
            result = train_ssvm(
                data["X"], data["y"], SSVMSettings(c_svmperf=c, max_iterations=300), (data["Xv"], data["yv"])
            )
            best = result.best
            print(
                f"| {affordance} | {c:g} | {best.validation_f1:.3f} | "
                f"{best.number} / {len(result.iterations)} | {best.seconds:.1f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
