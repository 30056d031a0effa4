"""The structured SVM for F1 against LinearSVC with a tuned threshold: time, memory and F1, side by side.

Two set-ups, each measured in a fresh process (peak memory is per process):

* DESIGN.md's Gaussian: 200,000 training and 200,000 validation examples, 100 features, 1 positive per
  1,000 (positives shifted by 0.35 in every feature). SVMperf's reference there: 196 iterations, 35 s at its
  C = 1e4, F1 0.45 at its own threshold; LinearSVC with its threshold tuned on training data: 0.56.
* The paper's size: 1,300,000 training poses at 1:12,000 with 222 features (our 25 cm-cell layout), plus
  300,000 validation poses; the target is <= 60 s and <= 8 GB for the structured SVM on all negatives.

C is SVMperf's (our solver weighs the averaged slack by C n^2).

    .venv/bin/python benchmarks/bench_ssvm.py              # about 5 minutes on 2 cores
    .venv/bin/python benchmarks/bench_ssvm.py --quick
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import resource
import time

import numpy as np

from affordcore.learn.baselines import linear_tuned
from affordcore.learn.f1_argmax import f1_at
from affordcore.learn.ssvm import SSVMSettings, train_ssvm


def gaussian(rng: np.random.Generator, n: int, d: int = 100, ratio: int = 1000, shift: float = 0.35):
    """n examples, d features, about one positive per `ratio` negatives, positives shifted in every
    feature."""
    y = np.where(rng.random(n) < 1 / (ratio + 1), 1, -1)
    y[:5] = 1
    X = rng.normal(size=(n, d)).astype(np.float32)
    X[y > 0] += shift
    return X, y


SETUPS = {  # name: (training n, features, negatives per positive, shift)
    "gaussian 200k x 100, 1:1000": (200_000, 100, 1000, 0.35),
    "paper size 1.3M x 222, 1:12000": (1_300_000, 222, 12000, 0.2),
}


def run(setup: str, learner: str, C: float, quick: bool) -> dict:
    n, d, ratio, shift = SETUPS[setup]
    n = n // 10 if quick else n
    rng = np.random.default_rng(0)
    (X, y), (Xv, yv) = (
        gaussian(rng, n, d, ratio, shift),
        gaussian(rng, max(n // 4, 200_000 // (10 if quick else 1)), d, ratio, shift),
    )
    start = time.perf_counter()
    if learner == "linear-tuned":
        model = linear_tuned(X, y)
        weights, iterations = np.append(model.weights, model.bias - model.threshold), "-"
    else:
        result = train_ssvm(X, y, SSVMSettings(C=C), validation=(Xv, yv))
        weights, iterations = result.best.weights, f"{result.best.number}/{len(result.iterations)}"
    seconds = time.perf_counter() - start
    scores, scores_v = (
        X @ weights[:-1].astype(np.float32) + weights[-1],
        Xv @ weights[:-1].astype(np.float32) + weights[-1],
    )
    return {
        "setup": setup,
        "learner": learner if learner != "ssvm" else f"ssvm C={C:g}",
        "positives": int((y > 0).sum()),
        "iterations": iterations,
        "seconds": seconds,
        "train_f1": f1_at(scores, y),
        "val_f1": f1_at(scores_v, yv),
        "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    jobs = [
        (setup, learner, C)
        for setup in SETUPS
        for learner, C in (("linear-tuned", 0.0), ("ssvm", 0.1), ("ssvm", 2.0))
    ]
    context = multiprocessing.get_context("forkserver")  # a fresh small process per run: honest peak memory
    print(
        f"{os.cpu_count()} cores; iterations = kept (best on validation) / run; "
        "peak = the process's high-water mark"
    )
    print("| set-up | learner | positives | iterations | seconds | train F1 | validation F1 | peak MB |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for setup, learner, C in jobs:
        with context.Pool(1) as pool:
            r = pool.apply(run, (setup, learner, C, args.quick))
        print(
            f"| {r['setup']} | {r['learner']} | {r['positives']} | {r['iterations']} | "
            f"{r['seconds']:.1f} | {r['train_f1']:.3f} | {r['val_f1']:.3f} | {r['peak_mb']:,.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
