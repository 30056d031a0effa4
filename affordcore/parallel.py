"""Independent jobs (a room generated and scanned, a room's fields, a room's examples, one training of the
k-fold evaluation) in parallel: the one place that decides where they run. Local processes by default; a
caller may hand them to something else (`jobs_run_by`: the command line's Ray cluster, affordcli/cluster.py),
so the library itself knows no cluster engine."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from multiprocessing import get_context

from .settings import Settings

# a job runner: (function, jobs) -> each job's result, in order; None: local processes
Runner = Callable[[Callable, list[tuple]], Iterator]
_runner: Runner | None = None


def workers_for(jobs: int, settings: Settings) -> int:
    """`learn.workers` processes (0: one per core), never more than there are jobs."""
    return max(1, min(jobs, settings.learn.workers or cores()))


@contextmanager
def jobs_run_by(runner: Runner) -> Iterator[None]:
    """Within the block, `map_in_processes` hands its jobs to `runner`."""
    global _runner
    previous, _runner = _runner, runner
    try:
        yield
    finally:
        _runner = previous


def map_in_processes(function: Callable, jobs: list[tuple], workers: int) -> Iterator:
    """`function(*job)` for every job, in the order given: by the runner of `jobs_run_by` when there is one,
    else in `workers` local processes (in this one when `workers` is 1). Functions and jobs must pickle."""
    if _runner is not None and jobs:
        yield from _runner(function, jobs)
        return
    if workers <= 1:
        yield from (function(*job) for job in jobs)
        return
    with _pool(workers) as pool:
        futures = [pool.submit(function, *job) for job in jobs]
        for future in futures:
            yield future.result()


def map_as_done(function: Callable, jobs: list[tuple], workers: int) -> Iterator[tuple[int, object]]:
    """(k, `function(*jobs[k])`) for every job as each finishes, the jobs started in the order given (list
    the longest first, so that none is left to run alone at the end); in order where `map_in_processes`
    would run them in this process or on a runner."""
    if (_runner is not None and jobs) or workers <= 1:
        yield from enumerate(map_in_processes(function, jobs, workers))
        return
    with _pool(workers) as pool:
        futures = {pool.submit(function, *job): k for k, job in enumerate(jobs)}
        for future in as_completed(futures):
            yield futures[future], future.result()


@contextmanager
def _pool(workers: int) -> Iterator[ProcessPoolExecutor]:
    # spawn, not fork: open3d and BLAS threads do not survive a fork
    threads = max(1, cores() // workers)
    with _threads_each(threads), ProcessPoolExecutor(workers, get_context("spawn")) as pool:
        yield pool


def where() -> tuple[str, int]:
    """The host and process a job runs in (a job that reports where it ran: tests, benchmarks)."""
    import socket

    return socket.gethostname(), os.getpid()


def cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


@contextmanager
def _threads_each(threads: int) -> Iterator[None]:
    """Processes started within the block run at most `threads` OpenMP / BLAS threads each (the cores'
    share; a lower limit already set is kept), as Ray limits its tasks: threads that outnumber the cores wait
    on one another at every barrier (scikit-learn's HistGradientBoosting, the cascade's trees, fitted 30,000
    rows in 2.9 s with one thread and 7.0 s with two on this 2-core machine under load)."""
    saved = {name: os.environ.get(name) for name in THREAD_VARIABLES}
    for name, value in saved.items():
        if value is None or not value.isdigit() or int(value) > threads:
            os.environ[name] = str(threads)
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
