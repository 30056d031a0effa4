"""`affordcore.compiled`: kernels compile with numba's cache where a cache folder can be written, and without
it (compiled again by each process) where none can, as on a read-only install whose user has no home."""

from __future__ import annotations

import numpy as np


def _add_one(values):
    for i in range(values.shape[0]):
        values[i] += 1


def test_a_kernel_compiles_with_numbas_cache_or_without_it(monkeypatch):
    from numba.core import caching

    from affordcore.compiled import compiled

    cached = compiled(_add_one)
    assert cached._cache.__class__.__name__ == "FunctionCache"  # this checkout's __pycache__ is writable
    # no folder numba may write to: numba refuses to cache, and the kernel is compiled without its cache
    monkeypatch.setattr(caching.CacheImpl, "_locator_classes", [])
    uncached = compiled(_add_one)
    assert uncached._cache.__class__.__name__ == "NullCache"
    values = np.zeros(3)
    cached(values)
    uncached(values)
    np.testing.assert_array_equal(values, [2.0, 2.0, 2.0])
