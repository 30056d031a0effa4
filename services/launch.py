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
    services close their recordings) and returns the exit codes."""

    def __init__(
        self, folder: Path, robot: str = "robot1", env: dict[str, str] | None = None, services=tuple(SERVICES)
    ):
        self.folder, self.robot, self.services = Path(folder), robot, tuple(services)
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
        self.processes: dict[str, subprocess.Popen] = {}

    def _spawn(self, name: str, command: list[str]) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        with open(self.folder / f"{name}.log", "w") as log:  # the child keeps its own descriptor
            self.processes[name] = subprocess.Popen(
                command, stdout=log, stderr=subprocess.STDOUT, env=self.env
            )

    def start(self, timeout: float = 60.0) -> Stack:
        self._spawn("router", python_call("services.clients:run_router", [self.endpoint]))
        for service in self.services:
            self._spawn(
                service,
                python_call(
                    "services.registry:run_service",
                    service,
                    self.robot,
                    [self.endpoint],
                    rrd=str(self.folder / f"{service}.rrd"),
                ),
            )
        self.wait_ready(timeout)
        return self

    def wait_ready(self, timeout: float) -> None:
        """Until every service's liveliness token is seen through the router."""
        from .transport import Keys, open_session

        keys = Keys(self.robot)
        session = open_session([self.endpoint], wait=timeout)
        deadline = time.monotonic() + timeout
        try:
            while True:
                alive = {
                    str(reply.ok.key_expr).rsplit("/", 1)[-1]
                    for reply in session.liveliness().get(keys.key("status", "*"), timeout=2.0)
                    if reply.ok is not None
                }
                if set(self.services) <= alive:
                    return
                dead = {name: p.returncode for name, p in self.processes.items() if p.poll() is not None}
                if dead or time.monotonic() > deadline:
                    raise RuntimeError(
                        f"services not ready (alive: {sorted(alive)}, exited: {dead}); logs: {self.logs()}"
                    )
                time.sleep(0.3)
        finally:
            session.close()

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
