"""The whole stack on one host (`up`: a router and the three services in the foreground) and the services'
health (`status`: what each answers on its status key; the compose health check)."""

from __future__ import annotations

from pathlib import Path

import typer

from .common import (
    CONNECT_HELP,
    ROBOT_HELP,
    ZENOH_CONFIG_HELP,
    UserError,
    fail,
    output_folder,
    require_extra,
    user_errors,
)

app = typer.Typer()
PANEL = "Robot"
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
SECURED_ENDPOINT = "tls/localhost:7447"


@app.command(rich_help_panel=PANEL)
def up(
    robot: str = typer.Option("robot1", "--robot", help=ROBOT_HELP),
    listen: str | None = typer.Option(
        None,
        "--listen",
        "--connect",
        help=f"the router's endpoint, where clients connect; default {DEFAULT_ENDPOINT}, with --site "
        f"{SECURED_ENDPOINT} (a wildcard address such as tcp/0.0.0.0:7447 also takes other hosts)",
    ),
    rrd_dir: Path = typer.Option(
        Path("recordings"),
        "--rrd-dir",
        help="folder for each service's recording (<service>.rrd) and each process's log (<name>.log)",
    ),
    site: Path | None = typer.Option(
        None,
        "--site",
        help="a secured site (the folder afford certs wrote): every process runs as its identity there, the "
        "router with its TLS and access control",
    ),
    state: Path | None = typer.Option(
        None, "--state", help="assembler: keep the map in this folder and reload it on the next start"
    ),
    wait: float = typer.Option(
        120.0, "--wait", min=1, help="seconds the services may take to get ready before giving up"
    ),
) -> None:
    """Run a router and the three services on this host until Ctrl-C or SIGTERM (each service closes its
    recording); if one of them dies, stop the rest and exit 1."""
    with user_errors():
        require_extra("services")
        from services.launch import Stack
        from services.registry import SERVICES
        from services.transport import Keys

        Keys(robot)  # a bad robot name is one line, not three crashed services
        if site is not None:
            _check_site(site, [*SERVICES, "router", "viewer"])
        if state is not None and state.exists() and not state.is_dir():
            raise UserError(f"--state {state} is a file; give a folder")
        endpoint = listen or (SECURED_ENDPOINT if site else DEFAULT_ENDPOINT)
        if site is not None and not endpoint.startswith("tls/"):
            raise UserError(f"--listen {endpoint}: a secured site's router takes TLS only (tls/HOST:PORT)")
        _check_free(endpoint)
        output_folder(rrd_dir, "--rrd-dir")
        stack = Stack(
            rrd_dir,
            robot,
            site=site,
            listen=endpoint,
            state=state,
            echo=_printer(["router", *SERVICES]),
            own_group=True,  # a Ctrl-C reaches only us; we stop the services first, then the router
        )
    _run(stack, wait)


def _printer(names: list[str]):
    """echo(name, line) for the children's output: each line once, whole, prefixed with its process."""
    import sys
    import threading

    width = max(map(len, names))
    lock = threading.Lock()

    def echo(name: str, line: str) -> None:
        own = f"[{name}] "
        text = line[len(own) :] if line.startswith(own) else line  # services already name themselves
        with lock:
            sys.stdout.write(f"{name:<{width}} | {text}\n")
            sys.stdout.flush()

    echo.lock = lock
    return echo


def _run(stack, wait: float) -> None:
    """Start the stack, say where to connect, supervise until a signal or a death, stop it in order."""
    import signal
    import threading

    from services.launch import deaths

    stopping = threading.Event()
    signals = {signal.SIGINT: "Ctrl-C", signal.SIGTERM: "SIGTERM"}
    received: list[str] = []

    def on_signal(number, _frame) -> None:
        received.append(signals.get(number, str(number)))
        stopping.set()

    previous = {number: signal.signal(number, on_signal) for number in signals}
    problem = None
    try:
        try:
            ready = stack.start(wait, cancel=stopping) and not stopping.is_set()
        except RuntimeError as error:  # a child exited while starting, or the time ran out
            ready, problem = False, str(error).split("; logs:")[0]
        if ready:
            _say_where(stack)
            while not stopping.wait(0.5):
                dead = stack.exited()
                if dead:
                    problem = deaths(dead)
                    break
    finally:
        with stack.echo.lock:
            typer.echo(
                f"stopping ({received[0]}): the services, then the router"
                if received and not problem
                else "stopping the rest",
                err=True,
            )
        codes = stack.stop()
        for number, handler in previous.items():
            signal.signal(number, handler)
    unclean = {name: code for name, code in codes.items() if code not in (0, -signal.SIGTERM)}
    if problem:
        fail(f"{problem}; stopped the rest (logs in {stack.folder})", code=1)
    if unclean:
        fail(
            "did not stop cleanly: "
            + ", ".join(f"{name} exit code {code}" for name, code in unclean.items()),
            code=1,
        )
    typer.echo(f"stopped; recordings in {stack.folder}/ (each service's 'stopped' line names its file)")


def _say_where(stack) -> None:
    robot, endpoint = stack.robot, stack.endpoint

    def config(identity: str) -> str:
        if not stack.site:
            return ""
        path = stack.site / f"{identity}.json5"
        return f" --zenoh-config {path if path.is_file() else stack.site / (identity.upper() + '.json5')}"

    recordings = " ".join(str(stack.folder / f"{service}.rrd") for service in stack.services)
    lines = [
        f"ready: router on {stack.listen}, services {', '.join(stack.services)} for robot {robot}; "
        f"recordings in {stack.folder}/",
        f"  publish: afford publish FOLDER_OR_CLOUD --connect {endpoint} --robot {robot}{config('robot')}",
        f"  watch:   afford watch --connect {endpoint} --robot {robot} --out maps/{config('viewer')}",
        f"  status:  afford status --connect {endpoint} --robot {robot}{config('viewer')}",
        f"  view:    rerun {recordings} (after the stop)",
        "Ctrl-C stops the services (each closes its recording), then the router.",
    ]
    with stack.echo.lock:
        for line in lines:
            typer.echo(line)


def _check_free(endpoint: str) -> None:
    """A router cannot listen where something else does (another router, say): say so before starting."""
    import socket

    protocol, _, address = endpoint.partition("/")
    host, _, port = address.rpartition(":")
    if protocol not in ("tcp", "tls") or not port.isdigit():
        return
    host = host.strip("[]")
    try:
        infos = socket.getaddrinfo(host, int(port), type=socket.SOCK_STREAM)
    except socket.gaierror as error:
        raise UserError(f"--listen {endpoint}: {host} does not resolve ({error.strerror})") from None
    family, _, _, _, sockaddr = infos[0]
    with socket.socket(family, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(sockaddr)
        except OSError as error:
            raise UserError(
                f"--listen {endpoint}: cannot listen there ({error.strerror}); is a router already running? "
                "(another port: --listen tcp/127.0.0.1:PORT)"
            ) from None


def _check_site(site: Path, identities: list[str]) -> None:
    if not site.is_dir():
        raise UserError(f"--site {site} is not a folder (make one with: afford certs {site})")
    missing = [f"{name}.json5" for name in identities if not (site / f"{name}.json5").is_file()]
    if missing:
        raise UserError(
            f"--site {site} has no {', '.join(missing)}: not a site afford certs wrote (afford certs {site})"
        )


@app.command(rich_help_panel=PANEL)
def status(
    connect: list[str] = typer.Option([DEFAULT_ENDPOINT], "--connect", help=CONNECT_HELP),
    robot: str = typer.Option(..., "--robot", help=ROBOT_HELP),
    service: list[str] | None = typer.Option(
        None, "--service", help="only this service (repeatable); default: every registered one"
    ),
    timeout: float = typer.Option(
        5.0, "--timeout", min=0.1, help="seconds to reach the router and hear the answers"
    ),
    zenoh_config: Path | None = typer.Option(None, "--zenoh-config", help=ZENOH_CONFIG_HELP),
) -> None:
    """Print each service's state; exit 0 when every one asked answers READY or BUSY, 1 otherwise (the
    compose health check)."""
    with user_errors():
        require_extra("services")
        import time

        from affordwire import messages
        from services.launch import query_status
        from services.registry import SERVICES
        from services.settings import ServiceSettings
        from services.transport import Keys, open_session

        Keys(robot)
        wanted = list(dict.fromkeys(service or SERVICES))
        unknown = [name for name in wanted if name not in SERVICES]
        if unknown:
            raise UserError(f"--service {', '.join(unknown)}: choose among {', '.join(SERVICES)}")
        settings = ServiceSettings().service
        config = zenoh_config or settings.zenoh_config
        if config is not None and not Path(config).is_file():
            raise UserError(f"--zenoh-config {config} does not exist")
        start = time.monotonic()
        try:
            session = open_session(list(connect), settings.mode, base=config, wait=timeout)
        except Exception as error:  # zenoh.ZError: no router there (or TLS refused)
            fail(f"no router at {', '.join(connect)} within {timeout:g} s: {error}", code=1)
        try:
            answers = query_status(session, robot, max(timeout - (time.monotonic() - start), 1.0))
        finally:
            session.close()
    healthy = (messages.Status.READY, messages.Status.BUSY)
    bad = []
    for name in wanted:
        answer = answers.get(name)
        if answer is None:
            typer.echo(f"{name:<10} {'-':<8} no answer within {timeout:g} s")
            bad.append(name)
            continue
        state = messages.Status.State.Name(answer.state)
        typer.echo(
            f"{name:<10} {state:<8} {answer.detail} ({answer.accepted} taken, {answer.rejected} rejected, "
            f"{answer.published} published; {answer.version})"
        )
        if answer.state not in healthy:
            bad.append(name)
    if bad:
        raise typer.Exit(1)
