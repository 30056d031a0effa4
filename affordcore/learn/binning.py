"""scikit-learn's histogram binning with sample weights, the same thresholds in one pass per feature.

Since scikit-learn 1.6, HistGradientBoosting bins weighted data (under 200,000 rows) at weighted
percentiles, and up to 1.9 it asks `_weighted_percentile` for each of the 254 percentiles of each feature
in turn: every call sorts the feature's column again. On the cascade's second stage (about 60,000 rows x 222
features) that was 35 of the 42 s a tree fit took (cProfile, docs/learning.md "How long"). The function
accepts every percentile at once and sorts once; `fast_weighted_binning` has the binner ask that way, and
nothing else changes: the thresholds, and so the trees, are the same to the bit (tests/test_cascade.py).
scikit-learn's own fix (scikit-learn#34248, merged June 2026) is not in a release yet; where the installed
version's binner differs from what this replaces, it is left alone.
"""

from __future__ import annotations

import inspect
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np


def _binning_module():
    """scikit-learn's binning module when it is the one this replaces (weighted thresholds found one
    percentile at a time, `average` supported), else None."""
    try:
        from sklearn.ensemble._hist_gradient_boosting import binning
        from sklearn.utils.stats import _weighted_percentile
    except ImportError:
        return None
    finds = getattr(binning, "_find_binning_thresholds", None)
    if finds is None or "sample_weight" not in inspect.signature(finds).parameters:
        return None  # before 1.6 the binner ignores weights: it is fast already
    if "average" not in inspect.signature(_weighted_percentile).parameters:
        return None
    return binning


def weighted_thresholds(original, col_data: np.ndarray, max_bins: int, sample_weight=None) -> np.ndarray:
    """`original(col_data, max_bins, sample_weight)` (scikit-learn's `_find_binning_thresholds`), with the
    weighted percentiles asked for at once. Only the case that sorted per percentile is done here."""
    from sklearn.ensemble._hist_gradient_boosting.common import ALMOST_INF
    from sklearn.utils.stats import _weighted_percentile

    if sample_weight is None:
        return original(col_data, max_bins, sample_weight=None)
    keep = ~np.isnan(col_data)  # missing values and zero weights take no part, as in the original
    keep &= sample_weight != 0
    values, weights = col_data[keep], sample_weight[keep]
    order = np.argsort(values)
    values, weights = values[order], weights[order]
    if len(np.unique(values)) <= max_bins:  # midpoints of the distinct values: no percentile, cheap
        return original(col_data, max_bins, sample_weight=sample_weight)
    percentiles = np.linspace(0, 100, num=max_bins + 1)[1:-1]
    thresholds = np.unique(_weighted_percentile(values, weights, percentiles, average=True))
    np.clip(thresholds, a_min=None, a_max=ALMOST_INF, out=thresholds)
    return thresholds


@contextmanager
def fast_weighted_binning() -> Iterator[None]:
    """Within the block, scikit-learn's histogram binner finds weighted thresholds with
    `weighted_thresholds` (the same values, one sort per feature)."""
    binning = _binning_module()
    if binning is None:
        yield
        return
    original = binning._find_binning_thresholds

    def thresholds(col_data, max_bins, sample_weight=None):
        return weighted_thresholds(original, col_data, max_bins, sample_weight)

    binning._find_binning_thresholds = thresholds
    try:
        yield
    finally:
        binning._find_binning_thresholds = original
