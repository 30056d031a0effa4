"""k-fold evaluation over rooms: every learner, every affordance, and the paper's imbalance test.

Rooms are dealt into k folds (seeded). Each fold's rooms are the test set; the other rooms train, and a
quarter of them (by room, `train.split_rooms`) is held out inside training to pick the structured SVM's
iteration and zSVM's z and to choose the thresholds. Test metrics are pose-level (DESIGN.md, "Metrics") over
every pose of the fold's rooms, scored as `afford map` scores them; results are means (and the standard
deviation of F1) over folds.

The imbalance test (the paper's): on the first fold, the training examples' negatives are undersampled to
1:r for r = 1, 2, 4, ... 2048 and all, every learner is trained on that, and F1 is measured on the full test
rooms, each learner at its own threshold (the table's runs use thresholds chosen on the validation rooms).
For `undersample` the ratio is the learner's own, so its curve is the plain SVM at each ratio. "All"
is every positive and `learn.negatives_per_room` negatives per room (examples.py): the sample, not the grid.
Features are computed once per room and affordance for the sampled poses only.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..geometry.features import FeatureLayout
from ..labels import load_labels
from ..parallel import map_as_done, workers_for
from ..settings import Settings
from .baselines import reused_fits
from .cache import RoomCache
from .examples import ExampleSet, Task, data_set_rooms, example_set, load_rooms
from .learners import LEARNERS, SHARED_FIT, get_learner
from .thresholds import room_scores
from .train import metrics, split_rooms, train_on_rooms

SWEEP_RATIOS: tuple[int | None, ...] = (*(2**k for k in range(12)), None)  # 1:1 ... 1:2048, then all data


@dataclass
class Outcome:
    """One learner trained on one fold (at one imbalance ratio) and scored on the fold's test rooms."""

    affordance: str
    learner: str
    fold: int
    ratio: int | None  # negatives per positive in training; None = every negative
    precision: float
    recall: float
    f1: float
    train_seconds: float
    train_ratio: float  # the training set's actual negatives per positive
    sweep: bool = False  # a point of the imbalance test rather than a row of the table
    report: dict = field(default_factory=dict)


@dataclass
class Evaluation:
    folds: list[list[str]]
    outcomes: list[Outcome] = field(default_factory=list)
    class_counts: dict[str, dict] = field(default_factory=dict)

    def table(self) -> list[dict]:
        """The results.json rows: means over folds of the full-data runs."""
        rows = []
        for affordance in dict.fromkeys(o.affordance for o in self.outcomes):
            for learner in dict.fromkeys(o.learner for o in self.outcomes):
                runs = [
                    o
                    for o in self.outcomes
                    if o.affordance == affordance and o.learner == learner and not o.sweep
                ]
                if runs:
                    rows.append(
                        {
                            "affordance": affordance,
                            "learner": learner,
                            **{
                                k: float(np.mean([getattr(o, k) for o in runs]))
                                for k in ("precision", "recall", "f1")
                            },
                            "f1_std": float(np.std([o.f1 for o in runs])),
                            "train_seconds": float(np.mean([o.train_seconds for o in runs])),
                            "folds": len(runs),
                        }
                    )
        return rows

    def sweep(self) -> list[Outcome]:
        return [o for o in self.outcomes if o.sweep]

    def to_json(self) -> dict:
        return {
            "format": "affordance-evaluation/1",
            "folds": self.folds,
            "class_counts": self.class_counts,
            "results": self.table(),
            "runs": [_without_curves(asdict(o)) for o in self.outcomes],
        }


def _without_curves(run: dict) -> dict:
    run["report"] = {k: v for k, v in run["report"].items() if k not in ("train_f1", "validation_f1")}
    return run


def deal_folds(names: list[str], k: int, seed: int, groups: dict[str, str] | None = None) -> list[list[str]]:
    """k folds of rooms, stratified: rooms of one group (say, the affordances they hold) are shuffled and
    dealt round-robin, so that no fold's training rooms lose a whole kind of room."""
    if not 2 <= k <= len(names):
        raise ValueError(f"{k} folds need at least {k} rooms and k >= 2; the data set has {len(names)} rooms")
    rng = np.random.default_rng(seed)
    groups = groups or {}
    order = [
        name
        for key in sorted(set(groups.get(n, "") for n in names))
        for name in rng.permutation(sorted(n for n in names if groups.get(n, "") == key))
    ]
    return [sorted(order[f::k]) for f in range(k)]


def evaluate(
    data: str | Path,
    affordances: list[str],
    learners: list[str],
    k: int,
    settings: Settings | None = None,
    seed: int = 0,
    ratios: tuple[int | None, ...] = SWEEP_RATIOS,
    params: dict[str, dict] | None = None,
    on_step: Callable[[str, float], None] | None = None,
    cache: RoomCache | None = None,
) -> Evaluation:
    """Runs len(affordances) x (k x len(learners) + len(ratios) x len(learners)) trainings; `on_step`
    hears each room's fields, each room's examples per affordance and each training, with the work it was
    (`evaluation_work`: a training's `Learner.cost`; the rooms' preparation, read from the cache when made
    before, is not counted). With `cache`, rooms' fields and examples are kept there and read one room at a
    time, and the trainings of every affordance run in parallel processes, the longest first."""
    unknown = [name for name in learners if name not in LEARNERS]
    if unknown:
        raise ValueError(f"unknown learner(s) {', '.join(unknown)}; choose from {', '.join(LEARNERS)}")
    settings = settings or Settings()
    layout = FeatureLayout.from_settings(settings)
    files = data_set_rooms(data)
    held = {f.name: ",".join(load_labels(f.labels).affordances) for f in files}
    folds = deal_folds([f.name for f in files], k, seed, held)
    rooms = load_rooms(files, settings, lambda name: _tell(on_step, f"fields of {name}", 0.0), cache)
    result = Evaluation(folds)
    runs: list[_Run] = []
    for affordance in affordances:
        task = Task(affordance, settings, layout)
        examples = example_set(
            rooms,
            task,
            cache=cache,
            on_room=lambda name, a=affordance: _tell(on_step, f"{a}: examples of {name}", 0.0),
        )
        result.class_counts[affordance] = _class_counts(examples)
        splits = [_split(examples, test_rooms, affordance, f, seed) for f, test_rooms in enumerate(folds)]
        # the table's runs, then the imbalance test's on the first fold
        runs += [_Run(examples, split, task, name, None, False) for split in splits for name in learners]
        runs += [
            _Run(examples, splits[0], task, name, ratio, True)
            for ratio in (ratios if splits else ())
            for name in learners
        ]
    # trainings in parallel processes when the rooms are in the cache (each process reads them from there);
    # held rooms would be copied to every job, so those train here
    outcomes: list = [None] * len(runs)
    for i, outcome in _train_runs(runs, params or {}, seed, settings, parallel=cache is not None):
        outcomes[i], run = outcome, runs[i]
        at = "all data" if run.ratio is None else f"1:{run.ratio}"
        step = f"at {at}" if run.sweep else f"fold {run.split.fold + 1}/{k}"
        message = f"{run.task.affordance}: {run.learner}, {step}: F1 {outcome.f1:.3f}"
        _tell(on_step, message, LEARNERS[run.learner].cost)
    result.outcomes = outcomes  # in the order of the runs, whatever order they finished in
    return result


def evaluation_work(learners: list[str], affordances: int, k: int, ratios: int) -> float:
    """The work `evaluate` tells `on_step` of in all: every training's `Learner.cost`."""
    return sum(get_learner(name).cost for name in learners) * affordances * (k + ratios)


def _class_counts(examples: ExampleSet) -> dict:
    positives = sum(examples.positives(n) for n in examples)
    negatives = sum(float(w[y < 0].sum()) for y, w in map(examples.labels, examples))
    ratio = negatives / max(1, positives)
    return {"positives": positives, "negatives": int(round(negatives)), "ratio": ratio}


def _tell(on_step, message: str, work: float) -> None:
    if on_step:
        on_step(message, work)


@dataclass
class _Split:
    """One fold's rooms: the test rooms, and the training rooms split into fitting and validation."""

    fold: int
    test_rooms: list[str]
    fit_rooms: list[str]
    validation_rooms: list[str]


def _split(examples: ExampleSet, test_rooms: list[str], affordance: str, fold: int, seed: int) -> _Split:
    train_names = [name for name in examples if name not in test_rooms]
    fit_names, validation_names = split_rooms(
        train_names, seed + fold, positives={n: examples.positives(n) for n in train_names}
    )
    if sum(examples.positives(n) for n in fit_names) == 0:
        raise ValueError(
            f"fold {fold + 1}: the training rooms {', '.join(fit_names)} hold no {affordance} label; use "
            "fewer folds or more rooms"
        )
    return _Split(fold, test_rooms, fit_names, validation_names)


@dataclass(frozen=True)
class _Run:
    """One training of the evaluation: a learner on a split of one affordance's examples."""

    examples: ExampleSet
    split: _Split
    task: Task
    learner: str
    ratio: int | None
    sweep: bool

    @property
    def shares_with(self) -> tuple:
        """Runs with the same value here train in one job: the learners of `SHARED_FIT` on one training set
        (which fit their common LinearSVC once); every other run alone."""
        if self.learner not in SHARED_FIT:
            return (id(self),)
        return (self.task.affordance, self.split.fold, self.ratio, self.sweep)


def _train_runs(runs: list[_Run], params: dict, seed: int, settings: Settings, parallel: bool) -> Iterator:
    """(index of the run, its `Outcome`) for every run, as they finish: runs grouped into jobs
    (`_Run.shares_with`), the jobs started longest first (`Learner.cost`), in `learn.workers` processes when
    `parallel`, else here."""
    groups: dict[tuple, list[int]] = {}
    for i, run in enumerate(runs):
        groups.setdefault(run.shares_with, []).append(i)
    order = sorted(groups.values(), key=lambda g: -sum(LEARNERS[runs[i].learner].cost for i in g))
    jobs = []
    for group in order:
        first = runs[group[0]]
        learners = [runs[i].learner for i in group]
        jobs.append(
            (first.examples, first.split, first.task, learners, first.ratio, params, seed, first.sweep)
        )
    done = map_as_done(_run_group, jobs, workers_for(len(jobs), settings) if parallel else 1)
    for j, outcomes in done:
        yield from zip(order[j], outcomes)


def _run_group(
    examples: ExampleSet,
    split: _Split,
    task: Task,
    learners: list[str],
    ratio: int | None,
    params: dict[str, dict],
    seed: int,
    sweep: bool,
) -> list[Outcome]:
    """`_run` of each learner in turn on the same split, a LinearSVC they share fitted once
    (`baselines.reused_fits`: the outcomes are those of separate runs)."""
    with reused_fits():
        return [
            _run(examples, split, task, learner, ratio, params.get(learner, {}), seed, sweep)
            for learner in learners
        ]


def _run(
    examples: ExampleSet,
    split: _Split,
    task: Task,
    learner: str,
    ratio: int | None,
    params: dict,
    seed: int,
    sweep: bool = False,
) -> Outcome:
    """Train one learner on the split (its training examples undersampled to `ratio`) and score every pose of
    the fold's test rooms as `afford map` does."""
    if sweep and learner == "undersample":  # in the imbalance test the plain SVM trains at the test's ratio
        params = {**params, "ratio": None if ratio is None else float(ratio)}
    start = time.perf_counter()
    model = train_on_rooms(
        examples,
        split.fit_rooms,
        split.validation_rooms,
        task,
        learner,
        params,
        seed,
        ratio,
        own_threshold=sweep,
    )
    seconds = time.perf_counter() - start
    scored = [
        room_scores(model, examples.room(name), task.layout, task.settings) for name in split.test_rooms
    ]
    at = metrics(
        np.concatenate([r.scores for r in scored]),
        np.concatenate([r.labels for r in scored]),
        model.threshold,
    )
    training = model.training
    return Outcome(
        task.affordance,
        learner,
        split.fold,
        ratio,
        at["precision"],
        at["recall"],
        at["f1"],
        seconds,
        training["negatives"] / max(1, training["positives"]),
        sweep,
        {**model.parameters.get("report", {}), "validation_rooms": split.validation_rooms},
    )


def write_outputs(evaluation: Evaluation, out: str | Path) -> list[Path]:
    """results.json, results.md and the two figures; returns the paths written."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "results.json", out / "results.md", out / "imbalance.png", out / "ssvm_iterations.png"]
    paths[0].write_text(json.dumps(evaluation.to_json(), indent=1) + "\n")
    paths[1].write_text(results_markdown(evaluation))
    from ..mapping.plots import plot_imbalance, plot_ssvm_iterations

    plot_imbalance(evaluation, paths[2])
    plot_ssvm_iterations(evaluation, paths[3])
    return paths


PAPER_RESULTS = Path(__file__).parents[1] / "data" / "paper_results.json"  # the paper's table (DESIGN.md)


def results_markdown(evaluation: Evaluation) -> str:
    rows = evaluation.table()
    affordances = list(dict.fromkeys(r["affordance"] for r in rows))
    learners = list(dict.fromkeys(r["learner"] for r in rows))
    cell = {(r["affordance"], r["learner"]): r for r in rows}
    k = len(evaluation.folds)
    lines = [
        f"# Learners compared ({k}-fold over {sum(map(len, evaluation.folds))} rooms)",
        "",
        "Pose-level precision / recall / F1 on the held-out rooms, mean over folds (F1 ± its standard "
        "deviation",
        "over folds), and seconds to train once.",
        "",
        "| learner | " + " | ".join(affordances) + " |",
        "|---|" + "---|" * len(affordances),
    ]
    for learner in learners:
        values = []
        for affordance in affordances:
            r = cell.get((affordance, learner))
            values.append(
                ""
                if r is None
                else f"{r['precision']:.2f} / {r['recall']:.2f} / **{r['f1']:.2f}** ± {r['f1_std']:.2f} "
                f"({r['train_seconds']:.0f} s)"
            )
        lines.append(f"| {learner} | " + " | ".join(values) + " |")
    lines += [
        "",
        "Class counts (all rooms): "
        + "; ".join(
            f"{a} {c['positives']:,} / {c['negatives']:,} (1:{c['ratio']:,.0f})"
            for a, c in evaluation.class_counts.items()
        ),
        "",
    ]
    lines += [
        "## Beside the paper (its 12 real rooms)",
        "",
        "| affordance | paper: best SVM baseline F1 | paper: structured SVM P / R / F1 | ours: best learner "
        "F1 | ours: ssvm P / R / F1 |",
        "|---|---|---|---|---|",
    ]
    paper_rows = json.loads(PAPER_RESULTS.read_text())["affordances"]
    for affordance in affordances:
        ours = [r for r in rows if r["affordance"] == affordance]
        best = max(ours, key=lambda r: r["f1"])
        ssvm = cell.get((affordance, "ssvm"))
        paper = paper_rows.get(affordance, {})
        paper = (paper.get("best_baseline", "-"), paper.get("structured_svm", "-"))
        ssvm_text = (
            "-" if ssvm is None else f"{ssvm['precision']:.2f} / {ssvm['recall']:.2f} / {ssvm['f1']:.2f}"
        )
        lines.append(
            f"| {affordance} | {paper[0]} | {paper[1]} | {best['f1']:.2f} ({best['learner']}) | {ssvm_text} |"
        )
    sweep = evaluation.sweep()
    if sweep:
        lines += ["", "## Imbalance test (fold 1): F1 against the training set's negatives per positive", ""]
        for affordance in affordances:
            runs = [o for o in sweep if o.affordance == affordance]
            ratios = sorted({o.ratio for o in runs if o.ratio is not None}) + [None]
            lines += [
                f"**{affordance}**",
                "",
                "| learner | " + " | ".join("all" if r is None else f"1:{r}" for r in ratios) + " |",
                "|---|" + "---:|" * len(ratios),
            ]
            for learner in learners:
                by_ratio = {o.ratio: o.f1 for o in runs if o.learner == learner}
                lines.append(
                    f"| {learner} | "
                    + " | ".join(f"{by_ratio[r]:.2f}" if r in by_ratio else "" for r in ratios)
                    + " |"
                )
            lines.append("")
    return "\n".join(lines).rstrip() + "\n"
