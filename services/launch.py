"""A router and the registered services as child processes on one host: what the end-to-end test, the latency
benchmark and a person trying the services on a laptop need. Each child makes the call `afford router` and
`afford serve` make (`run_router`, `run_service`). On robots, run each `afford serve` on its own (or
docker/compose.yaml). `afford up` runs a Stack in the foreground; `afford status` asks what `query_status`
asks."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path

from .registry import SERVICES


@contextmanager
def cpu_hogs(count: int):
    """`count` processes that each keep a core busy for as long as the block runs: the other work a robot's
    computer always has, for the tests and benchmarks that measure the services under load."""
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(count)]
    try:
        yield hogs
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()


def deaths(exited: dict[str, int]) -> str:
    """Children that exited ({name: exit code}, `Stack.exited`), in words: "inference exited with code -9"."""
    return "; ".join(f"{name} exited with code {code}" for name, code in exited.items())


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def query_status(session, robot: str, timeout: float = 2.0) -> dict:
    """{service: its Status message now}, from a get on afford/@v1/<robot>/status/* (each service answers with
    its state at that moment); a service that does not answer within `timeout` seconds is absent."""
    from affordwire import messages

    from .transport import Keys

    return {
        str(reply.ok.key_expr).rsplit("/", 1)[-1]: messages.parse(
            messages.Status, reply.ok.payload.to_bytes()
        )
        for reply in session.get(Keys(robot).key("status", "*"), timeout=timeout)
        if reply.ok is not None
    }


def loopback(endpoint: str) -> str:
    """The endpoint a client on this host connects to for a router listening on `endpoint` (a wildcard
    address, 0.0.0.0 or [::], is reached on loopback)."""
    return endpoint.replace("/0.0.0.0:", "/127.0.0.1:").replace("/[::]:", "/[::1]:")


def python_call(target: str, *args, **kwargs) -> list[str]:
    """The command line of a child process that calls `module:function(*args, **kwargs)` with this interpreter
    (arguments as their repr: strings, numbers, lists)."""
    module, function = target.split(":")
    call = ", ".join([*map(repr, args), *(f"{key}={value!r}" for key, value in kwargs.items())])
    return [sys.executable, "-c", f"from {module} import {function}; {function}({call})"]


class Stack:
    """Router + services on free loopback ports; each writes `<folder>/<service>.rrd` and `<service>.log`.

    `start()` returns once every service has declared its liveliness token; `stop()` sends SIGTERM (the
    services close their recordings) and returns the exit codes; `kill` and `restart` one service, as a crash
    and a supervisor would. With `site` (a folder `afford certs` wrote) every process uses its identity's
    config there: mutual TLS through the router, under its access control, and the stack's own session
    is `identity`'s.

    `listen` (default: a free loopback port) is where the router listens, `state` the assembler's state
    folder; with `echo`, each child's output goes line by line to `echo(name, line)` as well as to its log;
    `own_group` starts each child in its own process group, so a Ctrl-C at a terminal reaches only the
    parent, which then stops them in order (`stop`)."""

    def __init__(
        self,
        folder: Path,
        robot: str = "robot1",
        env: dict[str, str] | None = None,
        services=tuple(SERVICES),
        site: Path | None = None,
        identity: str = "viewer",
        listen: str | None = None,
        state: Path | None = None,
        echo: Callable[[str, str], None] | None = None,
        own_group: bool = False,
    ):
        self.folder, self.robot, self.services = Path(folder), robot, tuple(services)
        self.site, self.identity = site, identity
        self.listen = listen or f"{'tls/localhost' if site else 'tcp/127.0.0.1'}:{free_port()}"
        self.endpoint = loopback(self.listen)  # where the services and the stack's sessions connect
        self.state, self.echo, self.own_group = state, echo, own_group
        self.env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
        self.processes: dict[str, subprocess.Popen] = {}
        self._readers: list[threading.Thread] = []

    def config(self, identity: str) -> str | None:
        """The zenoh config file of `identity` in the site, if the stack is secured: the robot's own
        (`<identity>@<robot>.json5`, limited to its keys) when the site made one, else the site-wide one."""
        if not self.site:
            return None
        own = self.site / f"{identity}@{self.robot}.json5"
        return str(own if own.is_file() else self.site / f"{identity}.json5")

    def _spawn(self, name: str, command: list[str]) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        group = {"process_group": 0} if self.own_group else {}
        if self.echo is None:
            with open(self.folder / f"{name}.log", "a") as log:  # the child keeps its own descriptor
                self.processes[name] = subprocess.Popen(
                    command, stdout=log, stderr=subprocess.STDOUT, env=self.env, **group
                )
            return
        process = subprocess.Popen(
            command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=self.env, text=True, **group
        )
        self.processes[name] = process
        reader = threading.Thread(target=self._forward, args=(name, process), daemon=True)
        reader.start()
        self._readers.append(reader)

    def _forward(self, name: str, process: subprocess.Popen) -> None:
        """A child's output, line by line, to its log and to `echo` (until the child closes it)."""
        with open(self.folder / f"{name}.log", "a") as log:
            for line in process.stdout:
                log.write(line)
                log.flush()
                self.echo(name, line.rstrip("\n"))

    def _spawn_service(self, service: str) -> None:
        self._spawn(
            service,
            python_call(
                "services.registry:run_service",
                service,
                self.robot,
                [self.endpoint],
                rrd=str(self.folder / f"{service}.rrd"),
                zenoh_config=self.config(service),
                **({"state": str(self.state)} if self.state and service == "assembler" else {}),
            ),
        )

    def start(
        self, timeout: float = 60.0, cancel: threading.Event | None = None, router: bool = True
    ) -> Stack:
        """Start the router and the services and wait until every service is ready (or `cancel` is set);
        `router=False`: the services join the router already at `listen` (another robot's on one site)."""
        if router:
            self._spawn(
                "router",
                python_call("services.clients:run_router", [self.listen], zenoh_config=self.config("router")),
            )
        for service in self.services:
            self._spawn_service(service)
        self.wait_ready(timeout, cancel)
        return self

    def session(self, wait: float = 30.0, identity: str | None = None):
        """A new zenoh session through the stack's router (close it when done), as `identity` in a secured
        stack (default: the stack's own)."""
        from .transport import open_session

        config = self.config(identity or self.identity)
        return open_session([self.endpoint], wait=wait, base=Path(config) if config else None)

    def kill(self, service: str, timeout: float = 30.0) -> int:
        """SIGKILL one service, as a crash would (no checkpoint, no recording footer), and wait until the
        router has seen its liveliness token go."""
        process = self.processes[service]
        process.kill()
        code = process.wait(timeout)
        deadline = time.monotonic() + timeout
        while service in self.alive() and time.monotonic() < deadline:
            time.sleep(0.2)
        return code

    def restart(self, service: str, timeout: float = 60.0) -> None:
        """Start a service again (its log goes on; its recording is a new file beside the old one)."""
        self._spawn_service(service)
        self.wait_ready(timeout)

    def alive(self) -> set[str]:
        """The services whose liveliness token the router holds now."""
        from .transport import Keys

        session = self.session()
        try:
            return {
                str(reply.ok.key_expr).rsplit("/", 1)[-1]
                for reply in session.liveliness().get(Keys(self.robot).key("status", "*"), timeout=2.0)
                if reply.ok is not None
            }
        finally:
            session.close()

    def ready(self, wait: float = 30.0) -> set[str]:
        """The services that answer a get on their status with a state past STARTING (a restarted assembler
        has reloaded its map by then)."""
        from affordwire import messages

        session = self.session(wait)
        try:
            states = query_status(session, self.robot)
        finally:
            session.close()
        return {name for name, status in states.items() if status.state != messages.Status.STARTING}

    def exited(self) -> dict[str, int]:
        """The children that are no longer running, with their exit codes."""
        return {name: p.returncode for name, p in self.processes.items() if p.poll() is not None}

    def wait_ready(self, timeout: float, cancel: threading.Event | None = None) -> bool:
        """Until every service answers through the router, past starting (True), or `cancel` is set (False).
        Raises RuntimeError when a child exits or the time runs out first."""
        from zenoh import ZError

        deadline = time.monotonic() + timeout
        alive: set[str] = set()
        while True:
            if cancel is not None and cancel.is_set():
                return False
            dead = self.exited()
            if not dead:
                try:
                    alive = self.ready(wait=2.0)
                except ZError:  # the router does not take connections (yet): look again, unless it died
                    alive = set()
                if set(self.services) <= alive:
                    return True
                dead = self.exited()
            if dead:  # named as the supervisor names a death after the start, so either reads the same
                raise RuntimeError(
                    f"{deaths(dead)} while starting (ready: {sorted(alive)}); logs: {self.logs()}"
                )
            if time.monotonic() > deadline:
                raise RuntimeError(f"services not ready (ready: {sorted(alive)}); logs: {self.logs()}")
            time.sleep(0.3)

    def stop(self, timeout: float = 30.0) -> dict[str, int]:
        """SIGTERM the services (together), then the router once they are gone; returns each process's exit
        code (those still running after `timeout` seconds are killed: -9)."""
        codes = {}
        for group in (self.services, ("router",)):
            running = {name: self.processes[name] for name in group if name in self.processes}
            for process in running.values():
                if process.poll() is None:
                    process.send_signal(signal.SIGTERM)
            for name, process in running.items():
                try:
                    codes[name] = process.wait(timeout)
                except subprocess.TimeoutExpired:
                    process.kill()
                    process.wait()
                    codes[name] = -9
        for reader in self._readers:  # the children's last lines (a service's "stopped: ...") are out
            reader.join(timeout=5)
        return codes

    def logs(self) -> str:
        return "\n".join(
            f"--- {path.name}\n{path.read_text()[-3000:]}" for path in sorted(self.folder.glob("*.log"))
        )

    def __enter__(self) -> Stack:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
