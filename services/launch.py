"""A router and the registered services as child processes on one host: what the end-to-end test, the latency
benchmark and a person trying the services on a laptop need. Each child makes the call `afford router` and
`afford serve` make (`run_router`, `run_service`). On robots, run each `afford serve` on its own (or
docker/compose.yaml)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

from .registry import SERVICES


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


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
    is `identity`'s."""

    def __init__(
        self,
        folder: Path,
        robot: str = "robot1",
        env: dict[str, str] | None = None,
        services=tuple(SERVICES),
        site: Path | None = None,
        identity: str = "viewer",
    ):
        self.folder, self.robot, self.services = Path(folder), robot, tuple(services)
        self.site, self.identity = site, identity
        self.endpoint = f"{'tls/localhost' if site else 'tcp/127.0.0.1'}:{free_port()}"
        self.env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
        self.processes: dict[str, subprocess.Popen] = {}

    def config(self, identity: str) -> str | None:
        """The zenoh config file of `identity` in the site, if the stack is secured."""
        return str(self.site / f"{identity}.json5") if self.site else None

    def _spawn(self, name: str, command: list[str]) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        with open(self.folder / f"{name}.log", "a") as log:  # the child keeps its own descriptor
            self.processes[name] = subprocess.Popen(
                command, stdout=log, stderr=subprocess.STDOUT, env=self.env
            )

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
            ),
        )

    def start(self, timeout: float = 60.0) -> Stack:
        self._spawn(
            "router",
            python_call("services.clients:run_router", [self.endpoint], zenoh_config=self.config("router")),
        )
        for service in self.services:
            self._spawn_service(service)
        self.wait_ready(timeout)
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

    def ready(self) -> set[str]:
        """The services that answer a get on their status with a state past STARTING (a restarted assembler
        has reloaded its map by then)."""
        from affordwire import messages

        from .transport import Keys

        session = self.session()
        try:
            states = {
                str(reply.ok.key_expr).rsplit("/", 1)[-1]: messages.parse(
                    messages.Status, reply.ok.payload.to_bytes()
                ).state
                for reply in session.get(Keys(self.robot).key("status", "*"), timeout=2.0)
                if reply.ok is not None
            }
        finally:
            session.close()
        return {name for name, state in states.items() if state != messages.Status.STARTING}

    def wait_ready(self, timeout: float) -> None:
        """Until every service answers through the router, past starting."""
        deadline = time.monotonic() + timeout
        while True:
            alive = self.ready()
            if set(self.services) <= alive:
                return
            dead = {name: p.returncode for name, p in self.processes.items() if p.poll() is not None}
            if dead or time.monotonic() > deadline:
                raise RuntimeError(
                    f"services not ready (alive: {sorted(alive)}, exited: {dead}); logs: {self.logs()}"
                )
            time.sleep(0.3)

    def stop(self, timeout: float = 30.0) -> dict[str, int]:
        """SIGTERM the services, then the router; returns each process's exit code (killed ones: -9)."""
        codes = {}
        for name in (*self.services, "router"):
            process = self.processes.get(name)
            if process is None:
                continue
            if process.poll() is None:
                process.send_signal(signal.SIGTERM)
            try:
                codes[name] = process.wait(timeout)
            except subprocess.TimeoutExpired:
                process.kill()
                codes[name] = -9
        return codes

    def logs(self) -> str:
        return "\n".join(
            f"--- {path.name}\n{path.read_text()[-3000:]}" for path in sorted(self.folder.glob("*.log"))
        )

    def __enter__(self) -> Stack:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
