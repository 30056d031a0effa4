"""How `afford evaluate` spends its time: trainings that share a fit go in one job, the longest jobs start
first and come back as they finish, and the progress bar shows the time left from the start."""

from __future__ import annotations

import time
from types import SimpleNamespace

import pytest

from affordcore.learn import evaluate
from affordcore.learn.learners import LEARNERS, SHARED_FIT
from affordcore.parallel import map_as_done


def test_jobs_come_back_as_they_finish_each_with_its_index():
    # the long job goes first: on two workers both short ones finish while it runs
    done = list(map_as_done(time.sleep, [(1.5,), (0.05,), (0.05,)], 2))
    assert sorted(k for k, _ in done) == [0, 1, 2]
    assert done[-1][0] == 0
    assert list(map_as_done(pow, [(2, 3), (3, 2)], 1)) == [(0, 8), (1, 9)]  # here, in order


def test_learners_sharing_a_fit_train_in_one_job_and_the_longest_jobs_start_first(monkeypatch):
    splits = [SimpleNamespace(fold=f) for f in range(2)]
    task = SimpleNamespace(affordance="sitting-working")
    runs = [evaluate._Run(None, s, task, name, None, False) for s in splits for name in LEARNERS]
    runs += [evaluate._Run(None, splits[0], task, name, 4, True) for name in LEARNERS]
    started = []

    def run_here(function, jobs, workers):
        started.extend(jobs)
        return ((k, [f"outcome of {learner}" for learner in job[3]]) for k, job in enumerate(jobs))

    monkeypatch.setattr(evaluate, "map_as_done", run_here)
    outcomes = dict(evaluate._train_runs(runs, {}, 0, None, parallel=False))
    assert outcomes == {i: f"outcome of {run.learner}" for i, run in enumerate(runs)}  # each run once
    groups = [job[3] for job in started]
    # per split and ratio one job holds every learner of SHARED_FIT, every other learner has a job alone
    assert sum(sorted(group) == sorted(SHARED_FIT) for group in groups) == 3
    assert sorted(len(g) for g in groups) == [1] * 3 * (len(LEARNERS) - len(SHARED_FIT)) + [3] * 3
    costs = [sum(LEARNERS[name].cost for name in group) for group in groups]
    assert costs == sorted(costs, reverse=True)


def test_the_progress_bar_shows_the_time_left_before_any_work_is_done():
    pytest.importorskip("rich")
    from affordcli.common import advance_work, work_progress

    now = [1000.0]
    bar = work_progress(quiet=False, seconds_per_unit=0.5)
    bar.get_time = lambda: now[0]  # a clock the test moves
    task = bar.add_task("evaluate", total=200)
    left = bar.columns[-1]
    # before any work: 200 units at the guessed 0.5 s each
    assert left.render(bar.tasks[0]).plain == "0:01:40 left"
    now[0] += 60.0
    advance_work(bar, task, "fields of a room", 0.0)  # preparing: the total does not count it
    assert left.render(bar.tasks[0]).plain == "0:01:40 left"
    now[0] += 60.0
    advance_work(bar, task, "a training", 100.0)  # done at 0.6 s a unit since the preparation
    # the pace moves towards the measured: (60 s + 0.5 s x 20) / (100 + 20) units, 100 units left
    assert left.render(bar.tasks[0]).plain == "0:00:58 left"
