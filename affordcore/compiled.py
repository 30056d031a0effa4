"""numba's `njit` as the project compiles its kernels: the GIL released (a service's other threads go on), and
the machine code kept in numba's cache (the package's `__pycache__`, or the user's cache folder where that is
read-only), so a process reads it instead of compiling again. Modules of kernels import numba, which is slow
to import, so they are imported where a kernel is first called, not at the top of their callers."""

from __future__ import annotations

import numba


def compiled(function):
    try:
        return numba.njit(cache=True, nogil=True)(function)
    except RuntimeError:  # no cache folder numba may write to: compiled again by each process
        return numba.njit(nogil=True)(function)
