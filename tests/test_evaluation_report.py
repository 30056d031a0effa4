"""What `afford evaluate` reports: the table's means over folds, and the report a reader compares with the
paper, from outcomes made by hand (the learners' own runs are tests/test_train.py's)."""

from __future__ import annotations

import pytest

from affordcore.learn.evaluate import Evaluation, Outcome, results_markdown


def _outcome(learner, fold, f1, ratio=None, sweep=False, seconds=10.0):
    return Outcome(
        "sitting-working", learner, fold, ratio, precision=f1 + 0.1, recall=f1 - 0.1, f1=f1,
        train_seconds=seconds, train_ratio=500.0, sweep=sweep,
    )  # fmt: skip


@pytest.fixture
def evaluation():
    outcomes = [
        _outcome("ssvm", 0, 0.40, seconds=30.0),
        _outcome("ssvm", 1, 0.50, seconds=50.0),
        _outcome("dcm", 0, 0.30),
        _outcome("dcm", 1, 0.30),
        # the imbalance test: fold 1's runs at 1:4 and on every negative, not in the table's means
        _outcome("ssvm", 0, 0.20, ratio=4, sweep=True),
        _outcome("ssvm", 0, 0.90, sweep=True),
        _outcome("dcm", 0, 0.10, ratio=4, sweep=True),
    ]
    counts = {"sitting-working": {"positives": 1200, "negatives": 3_000_000, "ratio": 2500.0}}
    return Evaluation([["a", "b"], ["c"]], outcomes, counts)


def test_the_table_holds_each_learners_means_over_its_folds_and_leaves_out_the_imbalance_test(evaluation):
    rows = {r["learner"]: r for r in evaluation.table()}
    ssvm = rows["ssvm"]
    assert ssvm["f1"] == pytest.approx(0.45) and ssvm["f1_std"] == pytest.approx(0.05)
    assert ssvm["precision"] == pytest.approx(0.55) and ssvm["recall"] == pytest.approx(0.35)
    assert (ssvm["train_seconds"], ssvm["folds"]) == (pytest.approx(40.0), 2)
    assert rows["dcm"]["f1_std"] == pytest.approx(0.0)
    assert len(evaluation.sweep()) == 3


def test_the_report_gives_each_learners_cell_the_paper_beside_it_and_the_imbalance_test(evaluation):
    report = results_markdown(evaluation)
    lines = report.splitlines()
    assert lines[0] == "# Learners compared (2-fold over 3 rooms)"
    assert "| ssvm | 0.55 / 0.35 / **0.45** ± 0.05 (40 s) |" in lines
    assert "| dcm | 0.40 / 0.20 / **0.30** ± 0.00 (10 s) |" in lines
    assert "Class counts (all rooms): sitting-working 1,200 / 3,000,000 (1:2,500)" in lines
    # the paper's figures (data/paper_results.json) beside the best learner and the structured SVM
    assert "| sitting-working | 0.52 (dcm) | 0.40 / 0.77 / 0.48 | 0.45 (ssvm) | 0.55 / 0.35 / 0.45 |" in lines
    sweep = lines[lines.index("**sitting-working**") :]
    assert sweep[2] == "| learner | 1:4 | all |"
    assert "| ssvm | 0.20 | 0.90 |" in sweep and "| dcm | 0.10 |  |" in sweep
    assert report.endswith("|\n")


def test_results_json_holds_the_folds_the_table_and_every_run(evaluation):
    document = evaluation.to_json()
    assert document["format"] == "affordance-evaluation/1"
    assert document["folds"] == [["a", "b"], ["c"]]
    assert document["results"] == evaluation.table()
    assert [(r["learner"], r["fold"], r["sweep"]) for r in document["runs"]] == [
        (o.learner, o.fold, o.sweep) for o in evaluation.outcomes
    ]
