"""A router and the three services as child processes on one host: what the end-to-end test, the latency
benchmark and a person trying the services on a laptop need. On robots, run each `afford serve` on its own
(or docker/compose.yaml)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

SERVICES = ("assembler", "features", "inference")


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def afford_command() -> list[str]:
    """`afford` of the running interpreter (works without the venv's bin on PATH)."""
    return [sys.executable, "-c", "from affordcore.cli import app; app()"]


class Stack:
    """Router + services on free loopback ports; each writes `<folder>/<service>.rrd` and `<service>.log`.

    `start()` returns once every service has declared its liveliness token; `stop()` sends SIGTERM (the
    services close their recordings) and returns the exit codes."""

    def __init__(self, folder: Path, robot: str = "robot1", env: dict[str, str] | None = None, services=SERVICES):
        self.folder, self.robot, self.services = Path(folder), robot, tuple(services)
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
        self.processes: dict[str, subprocess.Popen] = {}

    def _spawn(self, name: str, args: list[str]) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        log = open(self.folder / f"{name}.log", "w")
        self.processes[name] = subprocess.Popen(afford_command() + args, stdout=log, stderr=subprocess.STDOUT, env=self.env)

    def start(self, timeout: float = 60.0) -> "Stack":
        self._spawn("router", ["router", "--listen", self.endpoint])
        for service in self.services:
            self._spawn(service, ["serve", service, "--connect", self.endpoint, "--robot", self.robot,
                                  "--rrd", str(self.folder / f"{service}.rrd")])
        self.wait_ready(timeout)
        return self

    def wait_ready(self, timeout: float) -> None:
        """Until every service's liveliness token is seen through the router."""
        from .node import Keys, open_session

        keys = Keys(self.robot)
        session = open_session([self.endpoint])
        deadline = time.monotonic() + timeout
        try:
            while True:
                alive = {str(reply.ok.key_expr).rsplit("/", 1)[-1]
                         for reply in session.liveliness().get(keys.key("status", "*"), timeout=2.0) if reply.ok is not None}
                if set(self.services) <= alive:
                    return
                dead = {name: p.returncode for name, p in self.processes.items() if p.poll() is not None}
                if dead or time.monotonic() > deadline:
                    raise RuntimeError(f"services not ready (alive: {sorted(alive)}, exited: {dead}); logs: {self.logs()}")
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
        return "\n".join(f"--- {path.name}\n{path.read_text()[-3000:]}" for path in sorted(self.folder.glob("*.log")))

    def __enter__(self) -> "Stack":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
