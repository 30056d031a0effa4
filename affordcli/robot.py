"""Robot commands: the services over Zenoh (`serve`, `router`) and the clients that feed and watch them
(`publish`, `watch`)."""

from __future__ import annotations

from pathlib import Path

import typer

from services.registry import SERVICES

from .common import (
    CONNECT_HELP,
    GRAVITY_HELP,
    ROBOT_HELP,
    ZENOH_CONFIG_HELP,
    UserError,
    fail,
    progress,
    user_errors,
)

app = typer.Typer()
PANEL = "Robot"


@app.command(rich_help_panel=PANEL)
def router(
    listen: list[str] | None = typer.Option(
        None,
        "--listen",
        help="endpoint to listen on (repeatable), e.g. tcp/0.0.0.0:7447; default: the --zenoh-config's, "
        "or tcp/127.0.0.1:7447",
    ),
    zenoh_config: Path | None = typer.Option(None, "--zenoh-config", help=ZENOH_CONFIG_HELP),
) -> None:
    """Run a Zenoh router for tests and single-host use (on a robot network: the eclipse/zenoh image)."""
    with user_errors():
        from services.clients import run_router

        config = zenoh_config or _settings().service.zenoh_config
        run_router(listen or ([] if config else ["tcp/127.0.0.1:7447"]), zenoh_config=config)


@app.command(rich_help_panel=PANEL)
def certs(
    out: Path = typer.Argument(..., help="folder for the site's CA, certificates, keys and zenoh configs"),
    sensor: list[str] = typer.Option(
        ["robot"],
        "--sensor",
        help="a client that may publish scans: NAME@ROBOT on ROBOT's scan/** only, a plain NAME on every "
        "robot's (repeatable)",
    ),
    mapper: list[str] = typer.Option(
        [],
        "--mapper",
        help="a client that may publish a finished room on map/cloud: NAME@ROBOT on ROBOT's only "
        "(repeatable)",
    ),
    robot: list[str] = typer.Option(
        [],
        "--robot",
        help="a robot whose services get identities of their own, assembler@ROBOT etc., that write only its "
        "keys (repeatable; a robot a --sensor or --mapper names gets them too)",
    ),
    viewer: list[str] = typer.Option(
        ["viewer"], "--viewer", help="a read-only client, e.g. for afford watch (repeatable)"
    ),
    operator: list[str] = typer.Option(
        ["operator"],
        "--operator",
        help="a client that may reset a robot's map and state (afford reset): NAME@ROBOT that robot's only, "
        "a plain NAME every robot's; no other identity may (repeatable)",
    ),
    router_host: list[str] = typer.Option(
        ["localhost", "127.0.0.1"],
        "--router-host",
        help="a name or address clients reach the router at: its certificate names it (repeatable)",
    ),
    connect: str = typer.Option(
        "tls/localhost:7447", "--connect", help="the router endpoint the clients' configs connect to"
    ),
    listen: str = typer.Option("tls/0.0.0.0:7447", "--listen", help="the endpoint the router listens on"),
    mount: Path | None = typer.Option(
        None, "--mount", help="where OUT is found at run time, e.g. /certs in a container; default: OUT"
    ),
    days: int = typer.Option(825, "--days", min=1, help="certificates stay valid this many days"),
) -> None:
    """Make a secured site for a test network: a CA (kept when OUT has one), a certificate per identity, the
    router's config (mutual TLS, access control) and one client config per identity (docs/security.md)."""
    with user_errors():
        from services.security import Site, write_site

        site = Site(sensor, mapper, viewer, operator, router_host, connect, listen, robots=robot)
        write_site(site, out, mount, days)
        typer.echo(
            f"site in {out}: router.json5 for afford router, <name>.json5 for each of "
            f"{', '.join(site.clients())} (--zenoh-config); keep ca.key off the robots"
        )


@app.command(rich_help_panel=PANEL)
def serve(
    service: str = typer.Argument(
        ..., help="; ".join(f"{spec.name} ({spec.summary})" for spec in SERVICES.values())
    ),
    connect: list[str] = typer.Option(..., "--connect", help=CONNECT_HELP),
    robot: str | None = typer.Option(None, "--robot", help=ROBOT_HELP + " (or --robots)"),
    robots: list[str] | None = typer.Option(
        None,
        "--robots",
        help="inference: serve many robots as one worker of a sharded group (repeatable): a robot name, * "
        "(every robot) or a pattern such as lab-$* (docs/deploy.md)",
    ),
    worker: str | None = typer.Option(
        None, "--worker", help="with --robots: this worker's id, unique on the site (default: <host>-<pid>)"
    ),
    shard_by: str = typer.Option(
        "affordance",
        "--shard-by",
        help="with --robots: one owner per robot's affordance (affordance) or per robot (robot)",
    ),
    rrd: Path | None = typer.Option(
        None, "--rrd", help="the service's Rerun recording (default: <service>.rrd here)"
    ),
    viewer: str | None = typer.Option(
        None,
        "--viewer",
        help="also stream the recording to a Rerun viewer, e.g. rerun+http://127.0.0.1:9876/proxy",
    ),
    listen: list[str] | None = typer.Option(
        None, "--listen", help="also listen on this endpoint (repeatable)"
    ),
    model: list[Path] | None = typer.Option(
        None, "--model", help="inference: a model file (repeatable); default: the shipped models"
    ),
    state: Path | None = typer.Option(
        None,
        "--state",
        help="assembler: keep the map in this folder (checkpoint and journal) and reload it on start; "
        "default: AFFORD_SERVICE__STATE",
    ),
    zenoh_config: Path | None = typer.Option(None, "--zenoh-config", help=ZENOH_CONFIG_HELP),
) -> None:
    """Run one service until SIGINT/SIGTERM. Settings (AFFORD_ASSEMBLER__*, AFFORD_SERVICE__*, ...) from the
    environment."""
    with user_errors():
        from services.registry import run_service

        if (robot is None) == (not robots):
            raise UserError("give either --robot NAME (one robot) or --robots PATTERN (a sharded worker)")
        if not robots and (worker or shard_by != "affordance"):
            raise UserError("--worker and --shard-by are for a sharded worker (--robots)")
        run_service(
            service,
            robot,
            connect,
            rrd,
            viewer,
            listen,
            model or [],
            state=state,
            zenoh_config=zenoh_config,
            robots=robots,
            worker=worker,
            shard_by=shard_by,
        )


@app.command("ros-bridge", rich_help_panel=PANEL)
def ros_bridge(
    connect: list[str] = typer.Option(..., "--connect", help=CONNECT_HELP),
    robot: str = typer.Option(..., "--robot", help=ROBOT_HELP),
    zenoh_config: Path | None = typer.Option(None, "--zenoh-config", help=ZENOH_CONFIG_HELP),
) -> None:
    """Bridge a ROS 2 robot on plain DDS to the services (its clouds, Imu, odometry and tf in; the maps and
    afford's world in tf out) as a ROS 2 node on the robot's rclpy; AFFORD_ROS__* name the topics."""
    with user_errors():
        try:
            import rclpy  # noqa: F401
        except ImportError as error:
            raise UserError(
                "afford ros-bridge runs a ROS 2 node: it needs rclpy (source the robot's ROS 2 setup.bash, "
                f"or pip install ros-kilted-rclpy and its message packages; {error})"
            ) from None
        from services.dds import run_dds_bridge

        settings = _settings(zenoh_config)
        run_dds_bridge(robot, connect, settings.ros, settings.service.zenoh_config)


@app.command(rich_help_panel=PANEL)
def publish(
    source: Path = typer.Argument(
        ...,
        help="a cloud file; a folder of depth frames (7-Scenes layout), of scan-NNNNNN.bin LiDAR scans or of "
        "PLY/PCD scans (in name order); or a ROS 2 recording: a rosbag2 folder (sqlite3 or MCAP) or an .mcap "
        "file",
    ),
    connect: list[str] = typer.Option(..., "--connect", help=CONNECT_HELP),
    robot: str = typer.Option(..., "--robot", help=ROBOT_HELP),
    as_map: bool = typer.Option(
        False, "--as-map", help="a cloud file is a finished room: align it and publish it on map/cloud"
    ),
    rate: float = typer.Option(
        10.0, "--rate", min=0, help="frames per second of a folder (0: as fast as the network takes them)"
    ),
    sensor: str = typer.Option(
        "", "--sensor", help="the sensor's key chunk: scan/<sensor> (default camera or lidar)"
    ),
    first: int = typer.Option(0, "--first", min=0, help="first frame of a folder"),
    frames: int = typer.Option(0, "--frames", min=0, help="at most this many frames (0: all)"),
    step: int = typer.Option(1, "--step", min=1, help="every n-th frame"),
    gravity: str = typer.Option("auto", "--gravity", help="--as-map: " + GRAVITY_HELP),
    wait: float = typer.Option(
        30.0, "--wait", help="seconds to wait for a subscriber (the service) before giving up"
    ),
    imu: bool = typer.Option(
        True,
        "--imu/--no-imu",
        help="a folder with gravity-direction.txt and poses: send the gravity direction an IMU "
        "would read with each frame; a recording: the gravity of its Imu topic",
    ),
    odometry: bool = typer.Option(
        True,
        "--odometry/--no-odometry",
        help="a folder whose frames have <stem>.odometry.txt, or a recording with an Odometry topic: send "
        "the robot's own odometry as each frame's pose guess",
    ),
    topic: str = typer.Option("", "--topic", help="a recording's PointCloud2 topic (default: its only one)"),
    imu_topic: str = typer.Option(
        "", "--imu-topic", help="a recording's Imu topic giving each scan its gravity (default: its only one)"
    ),
    odometry_topic: str = typer.Option(
        "",
        "--odometry-topic",
        help="a recording's nav_msgs/Odometry topic giving each scan its pose guess (default: its only one); "
        "the sensor's mounting on the robot from the recording's /tf_static (or AFFORD_ROS__BASE_FROM_CLOUD)",
    ),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
    zenoh_config: Path | None = typer.Option(None, "--zenoh-config", help=ZENOH_CONFIG_HELP),
) -> None:
    """Publish a finished map, a single scan, or a recorded sequence of frames at a given rate."""
    with user_errors():
        from services.clients import (
            NoSubscriber,
            connected,
            folder_frames,
            load_as_map,
            publish_map,
            publish_sequence,
            scan_message,
        )
        from services.transport import Keys

        keys, settings = Keys(robot), _settings(zenoh_config)
        session_of = settings.service.mode, settings.service.zenoh_config
        from services.ros import is_recording

        if (topic or imu_topic or odometry_topic) and not is_recording(source):
            raise UserError(
                f"--topic, --imu-topic and --odometry-topic are for ROS 2 recordings; {source} is not one"
            )
        try:
            if is_recording(source):
                from services.ros import recording_frames

                stats, scans, count = recording_frames(
                    source,
                    topic,
                    imu_topic,
                    imu,
                    first,
                    frames,
                    step,
                    settings.ros,
                    settings.limits,
                    odometry_topic=odometry_topic,
                    odometry=odometry,
                )
                sensor = sensor or "lidar"
                with connected(connect, *session_of) as session, progress(quiet) as bar:
                    task = bar.add_task(f"{stats.topic} to {keys.scan(sensor)}", total=count)
                    sent = publish_sequence(
                        session, keys, scans, sensor, rate, wait, on_frame=lambda _: bar.advance(task)
                    )
                for note in stats.notes():
                    typer.echo(f"warning: {note}", err=True)
                typer.echo(
                    f"published {stats.describe(sent, source)} "
                    f"(afford watch --frames {sent} waits for the maps that cover all of them)"
                )
            elif source.is_dir():
                sequence, messages, count = folder_frames(source, first, frames, step, imu, odometry)
                sensor = sensor or ("camera" if sequence.kind == "depth" else "lidar")
                with connected(connect, *session_of) as session, progress(quiet) as bar:
                    task = bar.add_task(f"{sequence.kind} frames to {keys.scan(sensor)}", total=count)
                    sent = publish_sequence(
                        session, keys, messages, sensor, rate, wait, on_frame=lambda _: bar.advance(task)
                    )
                guessed = " with the robot's odometry" if odometry and sequence.has_odometry() else ""
                typer.echo(
                    f"published {sent} {sequence.kind} frames of {source}{guessed} "
                    f"(afford watch --frames {sent} waits for the maps that cover all of them)"
                )
            elif as_map:
                cloud, warnings = load_as_map(source, gravity, settings)
                for warning in warnings:
                    typer.echo(f"warning: {warning}", err=True)
                with connected(connect, *session_of) as session:
                    publish_map(session, keys, cloud, wait)
                typer.echo(
                    f"published {source} as the map of robot {robot} "
                    f"({len(cloud.data) // cloud.point_stride:,} points), stamped "
                    f"{cloud.timestamp.seconds}.{cloud.timestamp.nanos:09d} (afford watch --since that "
                    "waits for its maps)"
                )
            else:
                scan = scan_message(source, sensor or "sensor")
                with connected(connect, *session_of) as session:
                    publish_sequence(session, keys, [(0, scan)], sensor or "sensor", 0, wait)
                typer.echo(
                    f"published {source} as one scan of robot {robot} (--as-map publishes a finished room "
                    "instead)"
                )
        except NoSubscriber as error:
            raise UserError(str(error)) from None


@app.command(rich_help_panel=PANEL)
def watch(
    connect: list[str] = typer.Option(..., "--connect", help=CONNECT_HELP),
    robot: str = typer.Option(..., "--robot", help=ROBOT_HELP),
    timeout: float = typer.Option(300.0, "--timeout", min=0, help="give up (exit 1) after this many seconds"),
    out: Path | None = typer.Option(
        None, "--out", help="write each affordance map here as <affordance>.json (the format of afford map)"
    ),
    affordance: list[str] | None = typer.Option(
        None,
        "--affordance",
        "-a",
        help="wait for this affordance (repeatable); default: every shipped model's",
    ),
    frames: int = typer.Option(
        0,
        "--frames",
        min=0,
        help="only maps that cover at least this many scans (what afford publish printed): scans the "
        "assembler fused or skipped to keep up",
    ),
    since: str | None = typer.Option(
        None,
        "--since",
        help="only maps of a cloud stamped at or after this time (seconds since the epoch, as afford publish "
        "--as-map prints it); default: the newest cloud the features service has",
    ),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="print only the maps' summary"),
    zenoh_config: Path | None = typer.Option(None, "--zenoh-config", help=ZENOH_CONFIG_HELP),
) -> None:
    """Print what the services of a robot publish; exit 0 once every affordance has a map of the newest cloud
    (never an older cloud's), exit 1 when the cloud waited for is refused (another client's refused cloud is
    shown, not taken as the answer) or on timeout."""
    with user_errors():
        from affordcore.learn.model import shipped_models
        from services.clients import MapWatcher, watch_maps
        from services.transport import Keys

        keys = Keys(robot)
        wanted = affordance or list(shipped_models())
        echo = (lambda line: None) if quiet else typer.echo
        watcher = MapWatcher(keys, wanted, frames, out, echo, since=_nanoseconds(since) if since else 0)
        service = _settings(zenoh_config).service
        arrived = watch_maps(connect, service.mode, keys, watcher, timeout, service.zenoh_config)
        if watcher.refused is not None:
            fail(
                f"the features service refused the cloud: {watcher.refused} (the cloud waited for: "
                f"{watcher.refused_cloud})",
                code=1,
            )
        if watcher.gave_up is not None:
            fail(watcher.gave_up, code=1)
        for name in sorted(watcher.received):
            document = watcher.received[name]
            typer.echo(
                f"{name:<18} {len(document['skeletons']):>3} places"
                + (f" -> {out / (name + '.json')}" if out else "")
            )
        if not arrived:
            fail(f"timed out after {timeout:.0f} s waiting for {watcher.waiting_for()}", code=1)


@app.command(rich_help_panel=PANEL)
def reset(
    connect: list[str] = typer.Option(..., "--connect", help=CONNECT_HELP),
    robot: str = typer.Option(..., "--robot", help=ROBOT_HELP),
    reason: str = typer.Option("", "--reason", help="why, in words: the services' logs and status say it"),
    operator: str = typer.Option(
        "operator", "--as", help="who asks, in words (the site's access control knows the identity)"
    ),
    timeout: float = typer.Option(30.0, "--timeout", min=0, help="give up (exit 1) after this many seconds"),
    zenoh_config: Path | None = typer.Option(None, "--zenoh-config", help=ZENOH_CONFIG_HELP),
) -> None:
    """Clear one robot's map and state: each service drops what waits, forgets its map (the assembler its
    trajectory and state folder too) and starts afresh with the next scan. Exit 0 once all three say they
    did; on a secured site only an operator identity (afford certs --operator) may."""
    with user_errors():
        from services.clients import NoSubscriber, connected, reset_robot
        from services.transport import Keys

        keys, service = Keys(robot), _settings(zenoh_config).service
        try:
            with connected(connect, service.mode, service.zenoh_config) as session:
                done, silent = reset_robot(session, keys, operator, reason, timeout)
        except NoSubscriber as error:
            raise UserError(str(error)) from None
        if silent:
            fail(
                f"reset robot {robot}: {', '.join(done) or 'no service'} reset, {', '.join(silent)} did not "
                f"say so within {timeout:.0f} s (on a secured site: is this identity an operator?)",
                code=1,
            )
        typer.echo(f"reset robot {robot}: {', '.join(done)} start afresh with the next scan")


def _nanoseconds(text: str) -> int:
    """Seconds since the epoch, exactly, as nanoseconds (a float would lose the last digits, and the watch
    compares stamps exactly)."""
    from decimal import Decimal, InvalidOperation

    try:
        value = Decimal(text)
    except InvalidOperation:
        raise UserError(
            f"--since must be seconds since the epoch, e.g. 1764000000.123456789, not {text!r}"
        ) from None
    if not value.is_finite() or value < 0:
        raise UserError(f"--since must be seconds since the epoch, not {text!r}")
    return int(value * 1_000_000_000)


def _settings(zenoh_config: Path | None = None):
    """The services' settings from the environment, with --zenoh-config over AFFORD_SERVICE__ZENOH_CONFIG."""
    from services.settings import ServiceSettings

    settings = ServiceSettings()
    if zenoh_config is not None:
        settings.service.zenoh_config = zenoh_config
    return settings
