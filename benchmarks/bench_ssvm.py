"""The structured SVM for F1 against LinearSVC with a tuned threshold, on DESIGN.md's Gaussian set-up.

200,000 training and 200,000 validation examples, 100 features, 1 positive per 1,000 (positives shifted by
0.35 in every feature). DESIGN.md's reference: SVMperf takes 196 iterations and 35 s at C = 1e4 and reaches
F1 0.45 at its own threshold; LinearSVC with its threshold tuned for F1 on the training data reaches 0.56.
This prints iterations, seconds, peak memory, and training / validation F1 for each, measured side by side.
(Our Psi is averaged over the examples, so our C is not SVMperf's: useful values are 1e6-1e8.)

    .venv/bin/python benchmarks/bench_ssvm.py              # about a minute on 2 cores
    .venv/bin/python benchmarks/bench_ssvm.py --quick
"""

from __future__ import annotations

import argparse
import os
import resource
import time

import numpy as np

from affordcore.learn.baselines import linear_tuned
from affordcore.learn.f1_argmax import f1_at
from affordcore.learn.ssvm import SSVMSettings, train_ssvm


def gaussian(rng: np.random.Generator, n: int, d: int = 100, ratio: int = 1000, shift: float = 0.35):
    y = np.where(rng.random(n) < 1 / (ratio + 1), 1, -1)
    y[:5] = 1
    X = rng.normal(size=(n, d)).astype(np.float32)
    X[y > 0] += shift
    return X, y


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    n = 20_000 if args.quick else 200_000
    rng = np.random.default_rng(0)
    (X, y), (Xv, yv) = gaussian(rng, n), gaussian(rng, n)
    print(f"{n:,} x 100 at 1:1000 ({int((y > 0).sum())} positives), {os.cpu_count()} cores")
    print(f"{'learner':<22} {'iterations':>10} {'seconds':>8} {'train F1':>9} {'val F1':>7}")
    start = time.perf_counter()
    baseline = linear_tuned(X, y)
    seconds = time.perf_counter() - start
    print(f"{'LinearSVC, tuned':<22} {'-':>10} {seconds:>8.1f} {f1_at(baseline.decision(X), y, baseline.threshold):>9.3f} "
          f"{f1_at(baseline.decision(Xv), yv, baseline.threshold):>7.3f}")
    for C in (1e7, 1e8):
        start = time.perf_counter()
        result = train_ssvm(X, y, SSVMSettings(C=C, max_iterations=500), validation=(Xv, yv))
        seconds = time.perf_counter() - start
        best = result.best
        print(f"{f'SSVM C={C:g}':<22} {len(result.iterations):>10} {seconds:>8.1f} {best.train_f1:>9.3f} {best.validation_f1:>7.3f}"
              f"  (best of {len(result.iterations)} on validation; converged: {result.converged})")
    print(f"peak memory {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main()
