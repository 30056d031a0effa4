"""The structured SVM's loss-augmented argmax: the O(n) selection against the previous O(n log n) sweep and
SVMperf's O(P N) double loop.

Scores are Gaussian with the positives shifted up (a half-trained model), at growing n and three class
ratios, at two scales: "unit" (scores of order one) and "training" (scores of order 1e-6, the scale the
solver hands the argmax: s / (100 n); there the old filter, "only negatives above -1 / (4P + 2) can flip",
keeps every negative and the sweep sorts them all). All searches find the same optimum (asserted); the table
gives median seconds over repeats and the ratios, measured side by side. The double loop here is already
vectorised over b for each a (numpy), so it understates what SVMperf's plain C double loop costs.

    .venv/bin/python benchmarks/bench_f1_argmax.py            # about a minute on 2 cores
    .venv/bin/python benchmarks/bench_f1_argmax.py --quick
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np

from affordcore.learn.f1_argmax import most_violated, most_violated_double_loop, most_violated_sorted


def _median_seconds(function, repeats: int, *args) -> tuple[float, object]:
    times, result = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        result = function(*args)
        times.append(time.perf_counter() - start)
    return statistics.median(times), result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    sizes = [10_000, 100_000] if args.quick else [10_000, 100_000, 300_000, 1_300_000]
    # positives x negatives the double loop is given (it takes ~4 s per 1e9)
    pair_limit = 2e8 if args.quick else 1e9
    print(f"F1 argmax, {os.cpu_count()} cores, numpy {np.__version__}, median of {args.repeats}")
    print(
        "| n | ratio | positives | scale | selection s | sorted sweep s | double loop s | sweep / selection "
        "| double / selection |"
    )
    print("|---:|---:|---:|---|---:|---:|---:|---:|---:|")
    rng = np.random.default_rng(0)
    for n in sizes:
        for ratio in (500, 3_000, 12_000):
            labels = np.where(rng.random(n) < 1 / (ratio + 1), 1, -1)
            labels[0] = 1
            for scale in ("unit", "training"):
                scores = rng.normal(0, 1, n) + 1.5 * (labels > 0)
                if scale == "training":
                    scores = (scores - 2.0) * 1e-6
                new, fast = _median_seconds(most_violated, args.repeats, scores, labels)
                sweep, old = _median_seconds(most_violated_sorted, args.repeats, scores, labels)
                assert abs(fast.objective - old.objective) < 1e-9 * max(1.0, abs(old.objective))
                if (labels > 0).sum() * n <= pair_limit:
                    double, slow = _median_seconds(most_violated_double_loop, args.repeats, scores, labels)
                    assert abs(fast.objective - slow.objective) < 1e-9 * max(1.0, abs(slow.objective))
                    shown = f"{double:.4f} | {sweep / new:.1f}x | {double / new:.0f}x"
                else:
                    shown = f"- | {sweep / new:.1f}x | -"
                print(
                    f"| {n:,} | 1:{ratio:,} | {int((labels > 0).sum()):,} | {scale} | {new:.4f} | "
                    f"{sweep:.4f} | {shown} |",
                    flush=True,
                )


if __name__ == "__main__":
    main()
