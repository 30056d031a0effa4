"""`afford`: the one command-line app. Heavy imports live inside the commands so `afford --help` is instant."""

from __future__ import annotations

import json
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Optional

import typer

app = typer.Typer(
    help="affordmap: where people can sit, relax, work and stand in a 3D room, from its point cloud.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
skeletons_app = typer.Typer(help="The virtual skeletons, one per affordance type.", no_args_is_help=True)
app.add_typer(skeletons_app, name="skeletons")
models_app = typer.Typer(help="The shipped default models, one per affordance type.", no_args_is_help=True)
app.add_typer(models_app, name="models")

GRAVITY_HELP = "auto (find the floor), none (already z-up, floor at 0), or X,Y,Z: gravity's direction in the cloud's frame"


class UserError(Exception):
    """Bad input: reported as one line on stderr with exit code 2, never a traceback."""


@contextmanager
def _user_errors():
    from pydantic import ValidationError

    try:
        yield
    except ValidationError as error:
        _fail(f"invalid settings: {error.errors()[0].get('msg', error)} (check the AFFORD_* environment variables)")
    except (UserError, ValueError, OSError, MemoryError) as error:
        _fail(str(error))


def _fail(message: str) -> None:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(2)


def _progress(quiet: bool):
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    return Progress(
        TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
        console=Console(stderr=True), transient=True, disable=quiet,
    )


def _peak_rss_mb() -> float:
    import resource

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 1024 if sys.platform != "darwin" else peak / 2**20


def _stream_features(scene, skeleton, settings, progress, out_path: Path | None = None) -> tuple[int, int, float]:
    """Compute (and optionally write) every pose's features; returns (poses, features, seconds)."""
    from .features import iter_features

    grid = scene.pose_grid(skeleton, settings)
    layout = scene.layout
    matrix = _open_matrix(out_path, grid.size, layout.n_features) if out_path else None
    task = progress.add_task(f"features {skeleton.affordance}", total=grid.size)
    start = time.perf_counter()
    for chunk in iter_features(scene.fields, skeleton, grid, layout, settings.features.chunk_mb, reuse_buffer=True):
        if matrix is not None:
            matrix[chunk.start:chunk.stop] = chunk.values
        progress.advance(task, chunk.stop - chunk.start)
    seconds = time.perf_counter() - start
    progress.remove_task(task)
    if matrix is not None:
        matrix.flush()
    return grid.size, layout.n_features, seconds


def _open_matrix(path: Path, rows: int, columns: int):
    import shutil

    import numpy as np

    needed = rows * columns * 4
    free = shutil.disk_usage(path.parent.resolve()).free
    if needed > free:
        raise UserError(f"{path}: the feature matrix needs {needed / 2**30:.1f} GiB and the disk has {free / 2**30:.1f} GiB free")
    return np.lib.format.open_memmap(path, mode="w+", dtype=np.float32, shape=(rows, columns))


@app.command()
def features(
    cloud: Path = typer.Argument(..., help="point cloud: .ply .pcd .xyz .pts .txt .npy .bin"),
    affordance: str = typer.Option(..., "--affordance", "-a", help="affordance type (see `afford skeletons list`)"),
    as_json: bool = typer.Option(False, "--json", help="print one JSON object: poses, features, seconds, peak_rss_mb"),
    gravity: str = typer.Option("auto", help=GRAVITY_HELP),
    out: Optional[Path] = typer.Option(None, "--out", help="also write the (poses x features) float32 matrix as .npy"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
) -> None:
    """Compute every grid pose's features for one affordance (distance, collision, normal cube)."""
    with _user_errors():
        from .pipeline import parse_gravity, prepare_scene
        from .scene import load_cloud
        from .settings import Settings
        from .skeleton import get_skeleton

        start = time.perf_counter()
        settings = Settings()
        skeleton = get_skeleton(affordance, settings.skeleton_dirs)
        scene = prepare_scene(load_cloud(cloud), settings, parse_gravity(gravity))
        prepared = time.perf_counter() - start
        with _progress(quiet) as progress:
            poses, n_features, feature_seconds = _stream_features(scene, skeleton, settings, progress, out)
        total = time.perf_counter() - start
        report = {"poses": poses, "features": n_features, "seconds": round(total, 3), "peak_rss_mb": round(_peak_rss_mb(), 1)}
        if as_json:
            typer.echo(json.dumps(report))
            return
        typer.echo(f"{cloud}: {len(scene.cloud)} points; {scene.alignment.describe()}")
        typer.echo(
            f"{affordance}: {poses} poses x {n_features} features in {total:.2f} s "
            f"(load, align, fields {prepared:.2f} s; features {feature_seconds:.2f} s, {poses / feature_seconds:,.0f} poses/s); "
            f"peak memory {report['peak_rss_mb']:.0f} MB"
        )
        if out:
            typer.echo(f"feature matrix written to {out}")


@app.command()
def align(
    cloud: Path = typer.Argument(..., help="point cloud file"),
    gravity: str = typer.Option("auto", help=GRAVITY_HELP),
    out: Optional[Path] = typer.Option(None, "--out", help="write the aligned cloud (.ply, .pcd or .npy)"),
    as_json: bool = typer.Option(False, "--json", help="print the alignment as JSON"),
) -> None:
    """Bring a cloud into the world frame (z up, floor at z = 0) and say what was done."""
    with _user_errors():
        from .gravity import align_to_gravity
        from .pipeline import parse_gravity
        from .scene import load_cloud, save_cloud
        from .settings import Settings

        loaded = load_cloud(cloud)
        alignment = align_to_gravity(loaded.points, parse_gravity(gravity), Settings().gravity)
        if out:
            save_cloud(out, loaded.transformed(alignment.world_from_input))
        if as_json:
            typer.echo(json.dumps({"cloud": str(cloud), "points": len(loaded), "dropped_nonfinite": loaded.dropped_nonfinite,
                                   **alignment.as_dict()}))
            return
        typer.echo(f"{cloud}: {len(loaded)} points" + (f" ({'; '.join(loaded.notes)})" if loaded.notes else ""))
        typer.echo(alignment.describe())
        for candidate in alignment.candidates:
            typer.echo(f"  candidate up {candidate.axis}: {'chosen' if candidate.valid and candidate.axis == alignment.up_axis else candidate.reason}"
                       f" (horizontal-surface score {candidate.score:.3f})")
        if out:
            typer.echo(f"aligned cloud written to {out}")


@app.command("map")
def map_command(
    cloud: Path = typer.Argument(..., help="the room's point cloud (.ply, .pcd, .xyz, .pts, .txt, .npy, .bin)"),
    out: Path = typer.Option(..., "--out", help="folder for <affordance>.json, <affordance>.png and the recording"),
    model: Optional[list[Path]] = typer.Option(None, "--model", help="a model file (repeatable); default: the shipped models"),
    affordance: Optional[list[str]] = typer.Option(None, "--affordance", "-a", help="only this affordance (repeatable)"),
    gravity: str = typer.Option("auto", "--gravity", help=GRAVITY_HELP),
    rrd: Optional[Path] = typer.Option(None, "--rrd", help="the Rerun recording (default: OUT/map.rrd)"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
) -> None:
    """Map where people can sit, relax, work and stand in a room: skeleton map, confidence map, positives."""
    with _user_errors():
        _map_room(cloud, out, model or [], affordance or [], gravity, rrd or out / "map.rrd", quiet)


def _map_room(cloud_path: Path, out: Path, model_files: list[Path], affordances: list[str], gravity: str, rrd: Path,
              quiet: bool) -> list[Path]:
    from .outputs import choose_models, summary_line, thin_huge_cloud, write_map_outputs
    from .pipeline import map_affordances, parse_gravity, prepare_scene
    from .scene import load_cloud
    from .settings import Settings

    settings = Settings()
    start = time.perf_counter()
    cloud, warning = thin_huge_cloud(load_cloud(cloud_path), settings.map)
    if warning:
        typer.echo(f"warning: {warning}", err=True)
    scene = prepare_scene(cloud, settings, parse_gravity(gravity))
    models = choose_models(model_files, affordances, scene.layout)
    typer.echo(f"{cloud_path}: {len(scene.cloud):,} points; {scene.alignment.describe()}")
    with _progress(quiet) as progress:
        task = progress.add_task("affordance maps", total=len(models))
        maps = map_affordances(scene.fields, scene.layout, models, settings, on_map=lambda *_: progress.advance(task))
    for amap in maps.values():
        typer.echo(summary_line(amap))
    written = write_map_outputs(scene, maps, models, out, rrd)
    typer.echo(f"{time.perf_counter() - start:.1f} s, peak memory {_peak_rss_mb():.0f} MB")
    typer.echo("outputs: " + ", ".join(str(path) for path in written))
    return written


@app.command()
def demo(
    out: Path = typer.Option(Path("afford-demo"), "--out", help="folder for the outputs"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
) -> None:
    """Map the built-in example room with the shipped models and say where the outputs are."""
    with _user_errors():
        from .example import example_room
        from .scene import save_cloud

        out.mkdir(parents=True, exist_ok=True)
        cloud_path = out / "example-room.ply"
        save_cloud(cloud_path, example_room())
        _map_room(cloud_path, out, [], [], "auto", out / "map.rrd", quiet)
        typer.echo(f"open the recording with: rerun {out / 'map.rrd'}")


SERVICES = ("assembler", "features", "inference")
CONNECT_HELP = "zenoh endpoint of the router, e.g. tcp/192.168.1.10:7447 (repeatable)"
ROBOT_HELP = "the robot's name: its keys are afford/@v1/<robot>/..."


@app.command()
def router(
    listen: list[str] = typer.Option(["tcp/127.0.0.1:7447"], "--listen", help="endpoint to listen on (repeatable), e.g. tcp/0.0.0.0:7447"),
) -> None:
    """Run a Zenoh router for tests and single-host use (on a robot network: the eclipse/zenoh image)."""
    with _user_errors():
        from services.clients import run_router

        run_router(listen)


@app.command()
def serve(
    service: str = typer.Argument(..., help="assembler (scans to a map), features (map to voxel fields) or inference (fields to affordance maps)"),
    connect: list[str] = typer.Option(..., "--connect", help=CONNECT_HELP),
    robot: str = typer.Option(..., "--robot", help=ROBOT_HELP),
    rrd: Optional[Path] = typer.Option(None, "--rrd", help="the service's Rerun recording (default: <service>.rrd here)"),
    viewer: Optional[str] = typer.Option(None, "--viewer", help="also stream the recording to a Rerun viewer, e.g. rerun+http://127.0.0.1:9876/proxy"),
    listen: Optional[list[str]] = typer.Option(None, "--listen", help="also listen on this endpoint (repeatable)"),
    model: Optional[list[Path]] = typer.Option(None, "--model", help="inference: a model file (repeatable); default: the shipped models"),
) -> None:
    """Run one service until SIGINT/SIGTERM. Settings (AFFORD_ASSEMBLER__*, AFFORD_SERVICE__*, ...) from the environment."""
    if service not in SERVICES:
        _fail(f"unknown service {service!r}; choose one of {', '.join(SERVICES)}")
    with _user_errors():
        from services.node import Node

        from .features import FeatureLayout
        from .outputs import choose_models, shipped_models
        from .settings import Settings

        settings = Settings()
        if service != "assembler":
            import os

            os.nice(settings.service.downstream_nice)
        models = []
        if service == "inference":
            models = choose_models(model or [], [], FeatureLayout.from_settings(settings.features, settings.voxel))
        affordances = [m.affordance for m in models] or list(shipped_models())
        node = Node(service, robot, connect, settings, rrd, viewer, affordances, listen)
        if service == "assembler":
            from services.assembler import AssemblerService

            AssemblerService(node).run()
        elif service == "features":
            from services.features import FeaturesService

            FeaturesService(node).run()
        else:
            from services.inference import InferenceService

            InferenceService(node, models).run()


@app.command()
def publish(
    source: Path = typer.Argument(..., help="a cloud file, or a folder of depth frames (7-Scenes layout) or of scan-NNNNNN.bin LiDAR scans"),
    connect: list[str] = typer.Option(..., "--connect", help=CONNECT_HELP),
    robot: str = typer.Option(..., "--robot", help=ROBOT_HELP),
    as_map: bool = typer.Option(False, "--as-map", help="a cloud file is a finished room: align it and publish it on map/cloud"),
    rate: float = typer.Option(10.0, "--rate", min=0, help="frames per second of a folder (0: as fast as the network takes them)"),
    sensor: str = typer.Option("", "--sensor", help="the sensor's key chunk: scan/<sensor> (default camera or lidar)"),
    first: int = typer.Option(0, "--first", min=0, help="first frame of a folder"),
    frames: int = typer.Option(0, "--frames", min=0, help="at most this many frames (0: all)"),
    step: int = typer.Option(1, "--step", min=1, help="every n-th frame"),
    gravity: str = typer.Option("auto", "--gravity", help="--as-map: " + GRAVITY_HELP),
    wait: float = typer.Option(30.0, "--wait", help="seconds to wait for a subscriber (the service) before giving up"),
    imu: bool = typer.Option(True, "--imu/--no-imu", help="a folder with gravity-direction.txt and poses: send the gravity direction an IMU would read with each frame"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
) -> None:
    """Publish a finished map, a single scan, or a recorded sequence of frames at a given rate."""
    with _user_errors():
        from services.clients import NoSubscriber, load_as_map, publish_map, publish_sequence, sequence_messages
        from services.node import Keys, open_session

        from .settings import Settings

        keys = Keys(robot)
        settings = Settings()
        if source.is_dir():
            from .sequence import read_sequence

            sequence = read_sequence(source)
            indices = list(range(first, len(sequence.frames), step))[: frames or None]
            if not indices:
                raise UserError(f"{source}: no frames from {first} (it has {len(sequence.frames)})")
            session = open_session(connect, settings.service.mode)
            try:
                with _progress(quiet) as progress:
                    task = progress.add_task(f"{sequence.kind} frames to {keys.scan(sensor or 'camera')}", total=len(indices))
                    sent = publish_sequence(session, keys, sequence_messages(sequence, indices, imu),
                                            sensor or ("camera" if sequence.kind == "depth" else "lidar"), rate, wait,
                                            on_frame=lambda _: progress.advance(task))
            except NoSubscriber as error:
                raise UserError(str(error)) from None
            finally:
                session.close()
            typer.echo(f"published {sent} {sequence.kind} frames of {source} (afford watch --frames {sent} waits for the maps of all of them)")
            return
        if as_map:
            cloud = load_as_map(source, gravity, settings)
            session = open_session(connect, settings.service.mode)
            try:
                publish_map(session, Keys(robot), cloud, wait)
            except NoSubscriber as error:
                raise UserError(str(error)) from None
            finally:
                session.close()
            typer.echo(f"published {source} as the map of robot {robot} ({len(cloud.data) // cloud.point_stride:,} points)")
            return
        from .messages import Scan, pack_points
        from .scene import load_cloud

        scan = Scan(frame_id=sensor or "sensor")
        pack_points(scan, load_cloud(source).points)
        session = open_session(connect, settings.service.mode)
        try:
            publish_sequence(session, keys, [(0, scan)], sensor or "sensor", 0, wait)
        except NoSubscriber as error:
            raise UserError(str(error)) from None
        finally:
            session.close()
        typer.echo(f"published {source} as one scan of robot {robot} (--as-map publishes a finished room instead)")


@app.command()
def watch(
    connect: list[str] = typer.Option(..., "--connect", help=CONNECT_HELP),
    robot: str = typer.Option(..., "--robot", help=ROBOT_HELP),
    timeout: float = typer.Option(300.0, "--timeout", min=0, help="give up (exit 1) after this many seconds"),
    out: Optional[Path] = typer.Option(None, "--out", help="write each affordance map here as <affordance>.json (the format of afford map)"),
    affordance: Optional[list[str]] = typer.Option(None, "--affordance", "-a", help="wait for this affordance (repeatable); default: every shipped model's"),
    frames: int = typer.Option(0, "--frames", min=0, help="only maps built from at least this many scans (what afford publish printed)"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="print only the maps' summary"),
) -> None:
    """Print what the services of a robot publish; exit 0 once every affordance's map has arrived."""
    with _user_errors():
        from services.clients import MapWatcher
        from services.clients import watch as watch_keys
        from services.node import Keys, open_session

        from .outputs import shipped_models
        from .settings import Settings

        wanted = affordance or list(shipped_models())
        watcher = MapWatcher(Keys(robot), wanted, frames, out, echo=(lambda line: None) if quiet else typer.echo)
        session = open_session(connect, Settings().service.mode)
        try:
            arrived = watch_keys(session, Keys(robot), watcher, timeout)
        finally:
            session.close()
        for name in sorted(watcher.received):
            document = watcher.received[name]
            typer.echo(f"{name:<18} {len(document['skeletons']):>3} places" + (f" -> {out / (name + '.json')}" if out else ""))
        if not arrived:
            _fail_with(1, f"timed out after {timeout:.0f} s waiting for {', '.join(watcher.missing)}")


def _fail_with(code: int, message: str) -> None:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(code)


@app.command()
def synth(
    rooms: int = typer.Option(..., "--rooms", min=1, help="how many rooms"),
    seed: int = typer.Option(0, "--seed", help="same seed, same files"),
    out: Path = typer.Option(..., "--out", help="folder for <room>.ply, <room>.labels.json and the summary"),
    kinds: str = typer.Option("living,office,workshop", "--kinds", help="comma-separated: living, office, workshop, mixed"),
    scanner: str = typer.Option("depth", "--scanner", help="depth (virtual Kinect, fused views) or uniform (surface samples)"),
    sequences: bool = typer.Option(False, "--sequences", help="also write a sensor sequence per room with ground-truth poses"),
    sensor: str = typer.Option("depth", "--sensor", help="what sequences hold: depth frames (7-Scenes layout) or lidar scans"),
    frames: int = typer.Option(300, "--frames", min=1, help="frames per sequence"),
    workers: int = typer.Option(1, "--workers", min=1, help="rooms generated in parallel processes"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
) -> None:
    """Generate labelled rooms: procedural furniture, a virtual depth scanner, exact labels, class counts."""
    with _user_errors():
        from .synth.dataset import SynthOptions, synthesize, summary_table

        options = SynthOptions(rooms, seed, tuple(k.strip() for k in kinds.split(",") if k.strip()), scanner,
                               sequences, sensor, frames)
        with _progress(quiet) as progress:
            task = progress.add_task("rooms", total=rooms)
            summary = synthesize(options, out, workers, on_room_done=lambda report: progress.advance(task))
        typer.echo(summary_table(summary), nl=False)
        typer.echo(f"written to {out}/ (summary.json, summary.md, {rooms} rooms)")


@app.command()
def train(
    data: Path = typer.Option(..., "--data", help="folder of <room>.ply + <room>.labels.json (afford synth writes one)"),
    affordance: str = typer.Option(..., "--affordance", "-a", help="affordance type"),
    learner: str = typer.Option("ssvm", "--learner", help="ssvm, undersample, focused, zsvm, dcm or linear-tuned"),
    out: Path = typer.Option(..., "--out", help="model file to write (JSON)"),
    C: Optional[float] = typer.Option(None, "--C", help="regularisation trade-off (learner's default when omitted)"),
    seed: int = typer.Option(0, "--seed", help="seeds the room split and resampling"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
) -> None:
    """Train one affordance's classifier on a data set (rooms split into training and validation by room)."""
    with _user_errors():
        from .learn.examples import data_set_rooms
        from .learn.train import train as train_model
        from .settings import Settings

        rooms = data_set_rooms(data)
        with _progress(quiet) as progress:
            task = progress.add_task("rooms", total=len(rooms))
            model = train_model(data, affordance, learner, Settings(), {} if C is None else {"C": C}, seed,
                                on_room=lambda name: progress.advance(task))
        model.save(out)
        v = model.validation
        typer.echo(f"{affordance} / {learner}: validation rooms {', '.join(v['rooms'])}: precision {v['precision']:.3f}, "
                   f"recall {v['recall']:.3f}, f1 {v['f1']:.3f} ({v['positives']} positive poses)")
        typer.echo(f"model written to {out}")


@app.command()
def evaluate(
    data: Path = typer.Option(..., "--data", help="folder of <room>.ply + <room>.labels.json"),
    folds: int = typer.Option(3, "--folds", min=2, help="k of the k-fold split over rooms"),
    learners: str = typer.Option(",".join(("ssvm", "undersample", "focused", "zsvm", "dcm", "linear-tuned")), "--learners",
                                 help="comma-separated learners"),
    affordances: Optional[str] = typer.Option(None, "--affordances", help="comma-separated affordances (default: every built-in skeleton)"),
    ratios: str = typer.Option("1,2,4,8,16,32,64,128,256,512,1024,2048,all", "--ratios",
                               help="imbalance test: negatives per positive to train at, 'all' for every negative; 'none' skips the test"),
    out: Path = typer.Option(..., "--out", help="folder for results.json, results.md and the plots"),
    seed: int = typer.Option(0, "--seed", help="seeds the folds, the validation split and resampling"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
) -> None:
    """Compare learners by k-fold over rooms: the paper's table, its imbalance test, the SSVM's iterations."""
    with _user_errors():
        from .learn.evaluate import evaluate as run_evaluation, write_outputs
        from .settings import Settings
        from .skeleton import skeleton_files

        settings = Settings()
        chosen = _names(learners)
        kinds = _names(affordances) if affordances else sorted(skeleton_files(settings.skeleton_dirs))
        sweep = () if ratios.strip() == "none" else tuple(None if r == "all" else _ratio(r) for r in _names(ratios))
        sweep_runs = sum(1 for r in sweep for name in chosen if r is not None or name == "undersample")  # others reuse fold 1
        steps = len(kinds) * (folds * len(chosen) + sweep_runs)
        with _progress(quiet) as progress:
            task = progress.add_task("evaluate", total=steps)

            def step(message: str) -> None:
                progress.update(task, description=message)
                if ": features of " not in message:
                    progress.advance(task)

            evaluation = run_evaluation(data, kinds, chosen, folds, settings, seed, sweep, on_step=step)
        paths = write_outputs(evaluation, out)
        typer.echo(paths[1].read_text().split("\n## Imbalance")[0])
        typer.echo("written: " + ", ".join(str(p) for p in paths))


def _names(text: str) -> list[str]:
    return [part.strip() for part in text.split(",") if part.strip()]


def _ratio(text: str) -> int:
    if not text.isdigit() or int(text) < 1:
        raise UserError(f"--ratios: {text!r} is not a whole number of negatives per positive (or 'all')")
    return int(text)


@app.command()
def config(
    current: bool = typer.Option(False, "--current", help="print the effective settings (defaults + AFFORD_* overrides) as JSON"),
) -> None:
    """Print every setting's default and the environment variable that overrides it."""
    with _user_errors():
        from .settings import Settings, describe_defaults

        if current:
            typer.echo(Settings().model_dump_json(indent=2))
            return
        for variable, default, description in describe_defaults():
            typer.echo(f"{variable}={default}    # {description}" if description else f"{variable}={default}")


@models_app.command("list")
def models_list() -> None:
    """Every shipped model: learner, training data and validation metrics."""
    with _user_errors():
        from .learn.model import load_model
        from .outputs import shipped_models

        for name, path in shipped_models().items():
            model = load_model(path)
            v = model.validation
            typer.echo(f"{name:<18} {model.learner:<13} {model.id}  validation P/R/F1 {v.get('precision', 0):.2f}/"
                       f"{v.get('recall', 0):.2f}/{v.get('f1', 0):.2f} on {', '.join(v.get('rooms', []))}")


@models_app.command("rebuild")
def models_rebuild(
    learner: str = typer.Option("ssvm", "--learner", help="one learner for every affordance"),
    evaluation: Optional[Path] = typer.Option(None, "--evaluation", help="an afford evaluate results.json: each affordance gets its best learner"),
    rooms: int = typer.Option(12, "--rooms", min=2, help="generated rooms to train on"),
    seed: int = typer.Option(1, "--seed", help="same seed, same models"),
    out: Optional[Path] = typer.Option(None, "--out", help="folder for the model files (default: the package's own)"),
    workers: int = typer.Option(2, "--workers", min=1, help="rooms generated in parallel"),
) -> None:
    """Retrain the default models from generated rooms, reproducibly."""
    with _user_errors():
        from .learn.defaults import rebuild_default_models, winners
        from .outputs import MODELS_DIR

        chosen = winners(evaluation) if evaluation else learner
        written = rebuild_default_models(out or MODELS_DIR, chosen, rooms, seed, workers, on_step=typer.echo)
        typer.echo("written: " + ", ".join(str(p) for p in written))


@skeletons_app.command("list")
def skeletons_list() -> None:
    """List the affordance types (one skeleton file each)."""
    with _user_errors():
        from .settings import Settings
        from .skeleton import all_skeletons

        for skeleton in all_skeletons(Settings().skeleton_dirs):
            typer.echo(f"{skeleton.affordance:<20} torso {skeleton.torso_height:.2f} m  {skeleton.source}")
            if skeleton.description:
                typer.echo(f"{'':<20} {skeleton.description}")


@skeletons_app.command("derive")
def skeletons_derive(
    data: Optional[Path] = typer.Option(None, "--data", help="MSR DailyActivity3D skeletons (.npz); default: ../shared/data/skeletons/..."),
    out: Optional[Path] = typer.Option(None, "--out", help="folder for <affordance>.json; default: the package's skeleton folder"),
    png: Optional[Path] = typer.Option(None, "--png", help="also draw the models and their clusters (PNG)"),
) -> None:
    """Derive the skeleton files from real Kinect skeletons: filter, canonicalise, K-means, medoid, adult scale."""
    with _user_errors():
        from .skeleton import BUILTIN_DIR
        from .skeleton_models import default_data_path, derive, plot_skeletons, write_skeleton

        data = data or default_data_path()
        if not data.is_file():
            raise UserError(f"{data}: skeleton data set not found (pass --data, see ../shared/data/README.md)")
        result = derive(data)
        groups = list(result.filters["loaded"])
        typer.echo(f"{'frames':<22}" + "".join(f"{g:>18}" for g in groups))
        for name, row in result.filters.items():
            label = name if name in ("loaded", "kept") else f"- {name}"
            typer.echo(f"{label:<22}" + "".join(f"{row[g]:>18,}" for g in groups))
        scale = result.scale
        typer.echo(f"scale: standing head-to-foot span {scale['median_span']:.3f} m (median) -> {scale['target_span']:.3f} m "
                   f"(x{scale['factor']:.3f}; per subject x{scale['subject_min']:.3f} to x{scale['subject_max']:.3f}); "
                   f"body: median bone lengths of {scale['body_frames']} standing frames")
        for skeleton in result.skeletons:
            info = result.clusters[skeleton.affordance]
            turns = info["forearm_turns"]
            typer.echo(f"{skeleton.affordance}: {info['frames']} frames, K={info['k']} "
                       f"(silhouette {info['silhouettes'][info['k']]:.3f}), sizes {info['sizes']}, chose cluster "
                       f"{info['chosen']} ({info['sizes'][info['chosen']]} frames), medoid {info['medoid']}, "
                       f"torso {skeleton.torso_height:.3f} m"
                       + (f", forearms turned {turns[0]:.0f} and {turns[1]:.0f} degrees" if turns else ""))
        for skeleton in result.skeletons:
            typer.echo(f"wrote {write_skeleton(skeleton, out or BUILTIN_DIR)}")
        if png:
            typer.echo(f"wrote {plot_skeletons(result.skeletons, png, result.members)}")


@skeletons_app.command("show")
def skeletons_show(
    out: Path = typer.Option(Path("skeletons.png"), "--out", help="PNG to write"),
    affordance: Optional[list[str]] = typer.Option(None, "--affordance", "-a", help="only these (repeatable); default: all"),
) -> None:
    """Draw the skeletons (front and side views on the floor) as one PNG."""
    with _user_errors():
        from .settings import Settings
        from .skeleton import all_skeletons, get_skeleton
        from .skeleton_models import plot_skeletons

        folders = Settings().skeleton_dirs
        skeletons = [get_skeleton(name, folders) for name in affordance] if affordance else all_skeletons(folders)
        typer.echo(f"wrote {plot_skeletons(skeletons, out)}")


if __name__ == "__main__":
    app()
