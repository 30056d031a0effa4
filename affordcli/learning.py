"""Learning commands: generate labelled rooms (`synth`), train one model (`train`), compare the learners
(`evaluate`), and the shipped models (`models list | rebuild`)."""

from __future__ import annotations

from pathlib import Path

import typer

from affordcore.learn.learners import LEARNERS

from .common import (
    UserError,
    advance_work,
    names,
    output_file,
    output_folder,
    progress,
    require_extra,
    user_errors,
    work_progress,
)

app = typer.Typer()
models_app = typer.Typer(help="The shipped default models, one per affordance type.", no_args_is_help=True)
app.add_typer(models_app, name="models", rich_help_panel="Learning")
PANEL = "Learning"
DATA_HELP = "folder of <room>.ply + <room>.labels.json (afford synth writes one)"


@app.command(rich_help_panel=PANEL)
def synth(
    rooms: int = typer.Option(..., "--rooms", min=1, help="how many rooms"),
    seed: int = typer.Option(0, "--seed", help="same seed, same files"),
    out: Path = typer.Option(..., "--out", help="folder for <room>.ply, <room>.labels.json and the summary"),
    kinds: str = typer.Option(
        "living,office,workshop", "--kinds", help="comma-separated: living, office, workshop, mixed"
    ),
    scanner: str = typer.Option(
        "depth", "--scanner", help="depth (virtual sensors, --styles) or uniform (surface samples)"
    ),
    styles: str = typer.Option(
        "fused,mesh,laser,frames,walk,sweep",
        "--styles",
        help="comma-separated scan styles dealt to rooms in turn: fused (fused depth frames), mesh (a "
        "reconstruction's vertices), laser (360-degree laser stations), frames (1-3 raw depth frames), walk "
        "(depth frames registered by the assembler), sweep (3-6 raw frames panned across the room from its "
        "edge)",
    ),
    sequences: bool = typer.Option(
        False, "--sequences", help="also write a sensor sequence per room with ground-truth poses"
    ),
    sensor: str = typer.Option(
        "depth", "--sensor", help="what sequences hold: depth frames (7-Scenes layout) or lidar scans"
    ),
    frames: int = typer.Option(300, "--frames", min=1, help="frames per sequence"),
    few_views: float = typer.Option(
        0.5,
        "--few-views",
        min=0.0,
        max=1.0,
        help="share of rooms scanned from a few viewpoints, as real rooms are",
    ),
    furniture: str = typer.Option(
        "base",
        "--furniture",
        help="base, or extended: base's pieces and round tables ringed by chairs, low reclined loveseats, "
        "ottomans (every room drawn differently from base's)",
    ),
    workers: int = typer.Option(
        0, "--workers", min=0, help="rooms generated in parallel processes (0: one per core)"
    ),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
) -> None:
    """Generate labelled rooms: procedural furniture, virtual sensors scanning them the ways real rooms
    arrive, exact labels, class counts. Resumable: run it again and it makes only the rooms not yet made
    with these options."""
    with user_errors():
        from affordcore.settings import Settings
        from affordcore.synth.batch import synthesize
        from affordcore.synth.dataset import SynthOptions, summary_table

        from .cluster import cluster_jobs

        options = SynthOptions(
            rooms,
            seed,
            tuple(names(kinds)),
            scanner,
            sequences,
            sensor,
            frames,
            few_views,
            tuple(names(styles)),
            furniture,
        )
        output_folder(out)  # after the options are checked: a refused command leaves no folder behind
        with cluster_jobs(Settings()), progress(quiet) as bar:
            task = bar.add_task("rooms", total=rooms)
            summary = synthesize(options, out, workers, on_room_done=lambda report: bar.advance(task))
        typer.echo(summary_table(summary), nl=False)
        typer.echo(f"written to {out}/ (summary.json, summary.md, {rooms} rooms)")


@app.command(rich_help_panel=PANEL)
def train(
    data: Path = typer.Option(..., "--data", help=DATA_HELP),
    affordance: str = typer.Option(..., "--affordance", "-a", help="affordance type"),
    learner: str = typer.Option("ssvm", "--learner", help=", ".join(LEARNERS)),
    out: Path = typer.Option(..., "--out", help="model file to write (JSON)"),
    C: float | None = typer.Option(
        None,
        "--C",
        help="regularisation trade-off (learner's default when omitted; ssvm: this project's units, the "
        "slack weighs C n^2 = 2500 x SVMperf's -c)",
    ),
    c_svmperf: float | None = typer.Option(
        None, "--c-svmperf", help="ssvm only: C in SVMperf's -c units (C n^2 / 2500), the same at any n"
    ),
    seed: int = typer.Option(0, "--seed", help="seeds the room split and resampling"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
) -> None:
    """Train one affordance's classifier on a data set (rooms split into training and validation by room)."""
    with user_errors():
        from affordcore.learn.cache import RoomCache
        from affordcore.learn.examples import data_set_rooms
        from affordcore.learn.train import train as train_model
        from affordcore.settings import Settings

        from .cluster import cluster_jobs

        require_extra("learn")
        output_file(out)
        rooms = data_set_rooms(data)
        settings = Settings()
        with cluster_jobs(settings), progress(quiet) as bar:
            task = bar.add_task("rooms (fields, then examples)", total=2 * len(rooms))
            model = train_model(
                data,
                affordance,
                learner,
                settings,
                {
                    **({} if C is None else {"C": C}),
                    **({} if c_svmperf is None else {"c_svmperf": c_svmperf}),
                },
                seed,
                on_room=lambda name: bar.advance(task),
                cache=RoomCache.from_settings(settings),
            )
        model.save(out)
        v = model.validation
        typer.echo(
            f"{affordance} / {learner}: validation rooms {', '.join(v['rooms'])}: precision "
            f"{v['precision']:.3f}, recall {v['recall']:.3f}, f1 {v['f1']:.3f} ({v['positives']} positive "
            "poses)"
        )
        typer.echo(f"model written to {out}")


@app.command(rich_help_panel=PANEL)
def evaluate(
    data: Path = typer.Option(..., "--data", help=DATA_HELP),
    folds: int = typer.Option(3, "--folds", min=2, help="k of the k-fold split over rooms"),
    learners: str = typer.Option(",".join(LEARNERS), "--learners", help="comma-separated learners"),
    affordances: str | None = typer.Option(
        None, "--affordances", help="comma-separated affordances (default: every built-in skeleton)"
    ),
    ratios: str = typer.Option(
        "none",
        "--ratios",
        help="the imbalance test on fold 1: negatives per positive to train every learner at, 'all' for "
        "every negative (the paper's: 1,2,4,8,16,32,64,128,256,512,1024,2048,all, about 4 times the "
        "table's trainings); 'none' (the default) skips it",
    ),
    out: Path = typer.Option(..., "--out", help="folder for results.json, results.md and the plots"),
    seed: int = typer.Option(0, "--seed", help="seeds the folds, the validation split and resampling"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
) -> None:
    """Compare learners by k-fold over rooms: the paper's table, its imbalance test, the SSVM's iterations."""
    with user_errors():
        from affordcore.geometry.skeleton import skeleton_files
        from affordcore.learn.cache import RoomCache
        from affordcore.learn.evaluate import evaluate as run_evaluation
        from affordcore.learn.evaluate import evaluation_work, write_outputs
        from affordcore.parallel import workers_for
        from affordcore.settings import Settings

        from .cluster import cluster_jobs

        require_extra("learn")
        output_folder(out)
        settings = Settings()
        chosen = names(learners)
        kinds = names(affordances) if affordances else sorted(skeleton_files(settings.skeleton_dirs))
        sweep = (
            ()
            if ratios.strip() == "none"
            else tuple(None if r == "all" else _ratio(r) for r in names(ratios))
        )
        cache = RoomCache.from_settings(settings)
        work = evaluation_work(chosen, len(kinds), folds, len(sweep))
        # the bar counts the trainings at their weight (seconds on one thread here, `Learner.cost`): from the
        # start, the time left is the work over the processes that share it, then the pace measured
        pace = 1.0 / workers_for(10**6, settings)
        with cluster_jobs(settings), work_progress(quiet, pace) as bar:
            task = bar.add_task("evaluate", total=work)

            def step(message: str, weight: float) -> None:
                advance_work(bar, task, message, weight)

            evaluation = run_evaluation(
                data, kinds, chosen, folds, settings, seed, sweep, on_step=step, cache=cache
            )
        paths = write_outputs(evaluation, out)
        typer.echo(paths[1].read_text().split("\n## Imbalance")[0])
        typer.echo("written: " + ", ".join(str(p) for p in paths))


def _ratio(text: str) -> int:
    if not text.isdigit() or int(text) < 1:
        raise UserError(f"--ratios: {text!r} is not a whole number of negatives per positive (or 'all')")
    return int(text)


@models_app.command("list")
def models_list() -> None:
    """Every shipped model: learner, training data and validation metrics."""
    with user_errors():
        from affordcore.learn.model import load_model, shipped_models

        for name, path in shipped_models().items():
            model = load_model(path)
            v = model.validation
            places = (
                f"; places: recall {v['probability_place_recall']:.2f}, "
                f"{v['probability_false_per_room']:.1f} false per room (place model)"
                if "probability_place_recall" in v
                else f"; places: recall {v.get('place_recall', 0):.2f} (score cut)"
            )
            typer.echo(
                f"{name:<18} {model.learner:<13} {model.id}  validation P/R/F1 {v.get('precision', 0):.2f}/"
                f"{v.get('recall', 0):.2f}/{v.get('f1', 0):.2f} on {len(v.get('rooms', []))} rooms{places}"
            )


@models_app.command("rebuild")
def models_rebuild(
    learner: str = typer.Option(
        "cascade", "--learner", help="one learner for every affordance: " + ", ".join(LEARNERS)
    ),
    evaluation: Path | None = typer.Option(
        None, "--evaluation", help="an afford evaluate results.json: each affordance gets its best learner"
    ),
    rooms: int = typer.Option(
        500,
        "--rooms",
        min=97,
        help="generated rooms: the last 48 are held out for benchmarks/accuracy.py, the 48 before them "
        "choose the thresholds and fit the place models, the rest train",
    ),
    seed: int = typer.Option(1, "--seed", help="same seed, same models"),
    out: Path | None = typer.Option(
        None, "--out", help="folder for the model files (default: the package's own)"
    ),
    workers: int = typer.Option(2, "--workers", min=1, help="rooms generated in parallel"),
    real: list[Path] = typer.Option(
        [],
        "--real",
        help="a folder of real labelled rooms (<room>.labels.json, its <room>.ply beside it or in another "
        "--real folder) that calibrate the place models beside the generated validation rooms, weighing "
        "AFFORD_LEARN__REAL_SHARE of them; never trained on. Repeatable",
    ),
) -> None:
    """Retrain the default models from generated rooms, reproducibly: the shipped models' recipe."""
    with user_errors():
        from affordcore.learn.defaults import rebuild_default_models, winners
        from affordcore.learn.examples import labelled_rooms, missing_clouds
        from affordcore.learn.model import MODELS_DIR
        from affordcore.settings import Settings

        from .cluster import cluster_jobs

        require_extra("learn")
        for folder in real:
            if not folder.is_dir():
                raise UserError(f"--real {folder}: no such folder")
        real_rooms = labelled_rooms(real)
        if real and not real_rooms:
            raise UserError(f"--real: no labelled room with its cloud in {', '.join(map(str, real))}")
        output_folder(out or MODELS_DIR, "--out" if out else "--out (default: the package's model folder)")
        for name in missing_clouds(real):
            typer.echo(f"--real: {name} has labels but no cloud in any --real folder; left out", err=True)
        chosen = winners(evaluation) if evaluation else learner
        with cluster_jobs(Settings()):
            written = rebuild_default_models(
                out or MODELS_DIR, chosen, rooms, seed, workers, on_step=typer.echo, real=real_rooms
            )
        typer.echo("written: " + ", ".join(str(p) for p in written))
