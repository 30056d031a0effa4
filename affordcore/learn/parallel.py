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
    with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as pool:
        futures = [pool.submit(function, *job) for job in jobs]
        for future in futures:
            yield future.result()


def cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
