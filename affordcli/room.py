"""Room commands: map a room (`map`, `demo`), and look at the steps on the way (`align`, `features`)."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import typer

from .common import GRAVITY_HELP, UserError, output_file, output_folder, peak_rss_mb, progress, user_errors

app = typer.Typer()
PANEL = "Room"
CLOUD_HELP = "point cloud: .ply .pcd .xyz .pts .txt .npy .bin"


@app.command("map", rich_help_panel=PANEL)
def map_command(
    cloud: Path = typer.Argument(..., help=CLOUD_HELP),
    out: Path = typer.Option(
        ..., "--out", help="folder for <affordance>.json, <affordance>.png and the recording"
    ),
    model: list[Path] | None = typer.Option(
        None, "--model", help="a model file (repeatable); default: the shipped models"
    ),
    affordance: list[str] | None = typer.Option(
        None, "--affordance", "-a", help="only this affordance (repeatable)"
    ),
    gravity: str = typer.Option("auto", "--gravity", help=GRAVITY_HELP),
    rrd: Path | None = typer.Option(None, "--rrd", help="the Rerun recording (default: OUT/map.rrd)"),
    no_png: bool = typer.Option(False, "--no-png", help="no plan-view PNGs (matplotlib is not loaded)"),
    no_rrd: bool = typer.Option(False, "--no-rrd", help="no Rerun recording (rerun is not loaded)"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
    timings: bool = typer.Option(False, "--timings", help="say on stderr how long each stage took"),
    origins: Path | None = typer.Option(
        None,
        "--origins",
        help="where the sensor stood, x y z per row in the cloud's frame (.npy or text); default: "
        "<cloud stem>.origins.npy beside the cloud when there is one. Tells free space from unknown",
    ),
    labels: Path | None = typer.Option(
        None,
        "--labels",
        help="the room's labelled places (affordance-labels/1, in the cloud's frame): drawn on the PNGs, "
        "and each map says how many it found and how many skeletons match none",
    ),
    next_views: int = typer.Option(
        0,
        "--next-views",
        min=0,
        max=20,
        help="with the sensor positions, up to this many camera poses per map from which a robot would "
        "settle most of what the map is unsure of (in the JSON, on the PNG; AFFORD_NEXT_VIEWS__* for the "
        "camera)",
    ),
) -> None:
    """Map where people can sit, relax, work and stand in a room: skeleton map, confidence map, positives."""
    with user_errors():
        if no_rrd and rrd is not None:
            raise UserError("--rrd names a recording and --no-rrd asks for none: give one of them")
        map_room(
            cloud,
            out,
            model or [],
            affordance or [],
            gravity,
            None if no_rrd else rrd or out / "map.rrd",
            quiet,
            timings,
            origins,
            labels,
            png=not no_png,
            next_views=next_views,
        )


def map_room(
    cloud_path: Path,
    out: Path,
    model_files: list[Path],
    affordances: list[str],
    gravity: str,
    rrd: Path | None,
    quiet: bool,
    timings: bool = False,
    origins: Path | None = None,
    labels_file: Path | None = None,
    png: bool = True,
    next_views: int = 0,
) -> list[Path]:
    """load -> align -> fields -> score -> map -> write, each one call into the library (the maps in worker
    processes and the files in a writer process started first, `outputs.map_and_write`), on one BLAS thread
    per process: its matrices are thin (points x 3), and OpenBLAS's second thread spin-waits between calls,
    which doubled the CPU of the floor search and took the core the writer and the workers share."""
    from contextlib import nullcontext

    from threadpoolctl import threadpool_limits

    from affordcore.geometry.features import FeatureLayout
    from affordcore.labels import load_labels
    from affordcore.learn.model import choose_models
    from affordcore.mapping.outputs import OutputWriter, map_and_write, summary_line
    from affordcore.mapping.pipeline import parse_gravity, prepare_scene
    from affordcore.mapping.workers import mapping_workers
    from affordcore.settings import Settings

    output_folder(out)
    settings = Settings()
    settings.next_views.count = next_views or settings.next_views.count
    start = time.perf_counter()
    seconds: dict[str, float] = {}
    models = choose_models(model_files, affordances, FeatureLayout.from_settings(settings))
    labels = load_labels(labels_file) if labels_file else None  # a bad file fails before the cloud is read
    workers = mapping_workers(len(models))
    # the writer imports matplotlib and rerun on the other core while this process loads the room; it and
    # the workers are forked inside the BLAS limit, and keep it
    with (
        threadpool_limits(1, user_api="blas"),
        OutputWriter(png, rrd is not None) if workers > 1 else nullcontext() as writer,
    ):
        loading = time.perf_counter()
        cloud = _loaded(cloud_path, origins)
        seconds["load the cloud"] = time.perf_counter() - loading
        if next_views and cloud.origins is None:
            raise UserError(
                f"--next-views needs the sensor positions (--origins, or {cloud_path.stem}.origins.npy "
                "beside the cloud): without them unknown space cannot be told from free"
            )
        affordance_names = [model.affordance for model in models]
        record = (lambda world: writer.start_scene(world, affordance_names, out, rrd)) if writer else None
        scene = prepare_scene(cloud, settings, parse_gravity(gravity), seconds, on_world=record)
        _warn(scene.warnings)
        labels = labels.moved(scene.alignment.world_from_input) if labels else None
        typer.echo(
            f"{cloud_path}: {len(scene.cloud):,} points; {scene.alignment.describe()}; {_seen_from(cloud)}"
        )
        mapping = time.perf_counter()
        with progress(quiet) as bar:
            task = bar.add_task("affordance maps", total=len(models))
            maps, written = map_and_write(
                scene,
                models,
                settings,
                out,
                rrd,
                workers,
                lambda *_: bar.advance(task),
                seconds,
                writer,
                labels,
                png,
            )
        seconds["maps and outputs (wall)"] = time.perf_counter() - mapping
    for amap in maps.values():
        typer.echo(summary_line(amap) + (_against(labels, amap) if labels else "") + _views(amap))
    if timings:
        for stage, value in seconds.items():
            typer.echo(f"timing: {stage}: {value:.3f} s", err=True)
    memory = f"peak memory {peak_rss_mb():.0f} MB"
    if workers > 1:  # each forked worker's peak counts the pages it shares with this process
        memory += (
            f" (worker processes: {workers + 1} x at most {_children_peak_mb():.0f} MB)"  # and the writer
        )
    typer.echo(f"{time.perf_counter() - start:.1f} s, {memory}")
    typer.echo("outputs: " + ", ".join(str(path) for path in written))
    return written


def _views(amap) -> str:
    """The best suggested view, where there are any."""
    if not amap.next_views:
        return ""
    best = amap.next_views[0]
    return (
        f"; {len(amap.next_views)} next views, the best at ({best.x:.2f}, {best.y:.2f}) facing "
        f"{math.degrees(best.heading):.0f} deg, {best.gain:.2f} bits"
    )


def _against(labels, amap) -> str:
    """How the map's skeletons meet the room's labels of its affordance (DESIGN.md's place tolerances)."""
    from affordcore.labels import match_places

    match = match_places(labels, amap.affordance, amap.skeletons[:, [0, 1, 3]])
    return f"; labels: {int(match.found.sum())} of {len(match.found)} found, {int(match.false.sum())} false"


def _children_peak_mb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024


def _loaded(path: Path, origins: Path | None = None):
    """The cloud at `path` (with the sensor positions in `origins`, when given); what loading did to it
    (points that are not finite, dropped) goes to stderr."""
    from affordcore.geometry.scene import load_cloud, load_origins

    cloud = load_cloud(path)
    if origins is not None:
        cloud.origins = load_origins(origins)
    _warn(cloud.notes)
    return cloud


def _seen_from(cloud) -> str:
    """What the map knows of the space the sensor saw through, in words."""
    if cloud.origins is None:
        return "no sensor positions (--origins): unknown space is not told from free"
    return f"sensor positions: {len(cloud.origins)}, free space told from unknown"


def _warn(warnings: list[str]) -> None:
    for warning in warnings:
        typer.echo(f"warning: {warning}", err=True)


CLOUD_SUFFIXES = (".ply", ".pcd", ".npy")  # what save_cloud writes


@app.command(rich_help_panel=PANEL)
def demo(
    out: Path = typer.Option(Path("afford-demo"), "--out", help="folder for the outputs"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
) -> None:
    """Map the built-in example room with the shipped models and say where the outputs are."""
    with user_errors():
        from affordcore.example import example_room
        from affordcore.geometry.scene import save_cloud

        output_folder(out)
        cloud_path = out / "example-room.ply"
        save_cloud(cloud_path, example_room())
        map_room(cloud_path, out, [], [], "auto", out / "map.rrd", quiet)
        typer.echo(f"open the recording with: rerun {out / 'map.rrd'}")


@app.command(rich_help_panel=PANEL)
def align(
    cloud: Path = typer.Argument(..., help=CLOUD_HELP),
    gravity: str = typer.Option("auto", help=GRAVITY_HELP),
    out: Path | None = typer.Option(None, "--out", help="write the aligned cloud (.ply, .pcd or .npy)"),
    as_json: bool = typer.Option(False, "--json", help="print the alignment as JSON"),
) -> None:
    """Bring a cloud into the world frame (z up, floor at z = 0) and say what was done."""
    with user_errors():
        from affordcore.geometry.scene import save_cloud
        from affordcore.mapping.pipeline import parse_gravity, to_world
        from affordcore.settings import Settings

        if out:
            if out.suffix.lower() not in CLOUD_SUFFIXES:
                raise UserError(f"--out {out}: the aligned cloud is written as {', '.join(CLOUD_SUFFIXES)}")
            output_file(out)
        loaded = _loaded(cloud)
        world = to_world(loaded, Settings(), parse_gravity(gravity))
        alignment = world.alignment
        _warn(world.warnings)
        if out:
            save_cloud(out, world.cloud)
        if as_json:
            typer.echo(
                json.dumps(
                    {
                        "cloud": str(cloud),
                        "points": len(loaded),
                        "dropped_nonfinite": loaded.dropped_nonfinite,
                        **alignment.as_dict(),
                    }
                )
            )
            return
        typer.echo(f"{cloud}: {len(loaded)} points")
        typer.echo(alignment.describe())
        for candidate in alignment.candidates:
            chosen = candidate.valid and candidate.axis == alignment.up_axis
            score = f" (floor evidence {candidate.score:.3f})" if candidate.score == candidate.score else ""
            typer.echo(f"  candidate up {candidate.axis}: {'chosen' if chosen else candidate.reason}{score}")
        if out:
            typer.echo(f"aligned cloud written to {out}")


@app.command(rich_help_panel=PANEL)
def features(
    cloud: Path = typer.Argument(..., help=CLOUD_HELP),
    affordance: str = typer.Option(
        ..., "--affordance", "-a", help="affordance type (see `afford skeletons list`)"
    ),
    as_json: bool = typer.Option(
        False, "--json", help="print one JSON object: poses, features, seconds, peak_rss_mb"
    ),
    gravity: str = typer.Option("auto", help=GRAVITY_HELP),
    out: Path | None = typer.Option(
        None, "--out", help="also write the (poses x features) float32 matrix as .npy"
    ),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
) -> None:
    """Compute every grid pose's features for one affordance (distance, collision, normal cube)."""
    with user_errors():
        from affordcore.geometry.skeleton import get_skeleton
        from affordcore.mapping.pipeline import parse_gravity, prepare_scene, stream_features
        from affordcore.settings import Settings

        if out:
            output_file(out)
        start = time.perf_counter()
        settings = Settings()
        skeleton = get_skeleton(affordance, settings.skeleton_dirs)
        scene = prepare_scene(_loaded(cloud), settings, parse_gravity(gravity))
        _warn(scene.warnings)
        prepared = time.perf_counter()
        with progress(quiet) as bar:
            task = bar.add_task(f"features {affordance}", total=scene.pose_grid(skeleton, settings).size)
            poses, n_features = stream_features(
                scene, skeleton, settings, out, on_rows=lambda n: bar.advance(task, n)
            )
        done = time.perf_counter()
        total, feature_seconds = done - start, done - prepared
        report = {
            "poses": poses,
            "features": n_features,
            "seconds": round(total, 3),
            "peak_rss_mb": round(peak_rss_mb(), 1),
        }
        if as_json:
            typer.echo(json.dumps(report))
            return
        typer.echo(f"{cloud}: {len(scene.cloud)} points; {scene.alignment.describe()}")
        typer.echo(
            f"{affordance}: {poses} poses x {n_features} features in {total:.2f} s (load, align, fields "
            f"{prepared - start:.2f} s; features {feature_seconds:.2f} s, {poses / feature_seconds:,.0f} "
            "poses/s); "
            f"peak memory {report['peak_rss_mb']:.0f} MB"
        )
        if out:
            typer.echo(f"feature matrix written to {out}")
