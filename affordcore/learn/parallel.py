"""Independent jobs (a room's fields, a room's examples, one training of the k-fold evaluation) in parallel
processes: the one place that decides where they run."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context

from ..settings import Settings


def workers_for(jobs: int, settings: Settings) -> int:
    """`learn.workers` processes (0: one per core), never more than there are jobs."""
    return max(1, min(jobs, settings.learn.workers or cores()))


def map_in_processes(function: Callable, jobs: list[tuple], workers: int) -> Iterator:
    """`function(*job)` for every job, in the order given; in this process when `workers` is 1."""
    if workers <= 1:
        yield from (function(*job) for job in jobs)
        return
    # spawn, not fork: open3d and BLAS threads do not survive a fork
    context, threads = get_context("spawn"), max(1, cores() // workers)
    with ProcessPoolExecutor(workers, context, _share_cores, (threads,)) as pool:
        futures = [pool.submit(function, *job) for job in jobs]
        for future in futures:
            yield future.result()


def cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def _share_cores(threads: int) -> None:
    """Each process's BLAS and OpenMP threads (liblinear, the boosted trees) get its share of the cores: one
    thread per core in all, since threads that outnumber cores wait on each other at every barrier
    (HistGradientBoosting fitted 2.5 times slower with two threads than with one on this 2-core machine
    under load)."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # without the learn extra: only fields and features run here, numpy's own BLAS
        return
    global _LIMITS
    _LIMITS = threadpool_limits(threads)  # kept: the limits hold while the object lives


_LIMITS = None
