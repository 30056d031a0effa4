"""Jobs on a Ray cluster when `cluster.address` names one (AFFORD_CLUSTER__ADDRESS; the `[cluster]` extra).

The library runs its independent jobs (a room generated and scanned, a room's fields, a room's examples, one
training of the k-fold evaluation) through `affordcore.parallel.map_in_processes`, local processes by default;
here they are handed to Ray instead (`parallel.jobs_run_by`), so the library itself never imports Ray. Each
job is a Ray task that reserves `cluster.cpus_per_job` CPUs; the library's code travels with the job
(`runtime_env` py_modules), the data set and the room cache do not: they must be at the same path on every
node (docs/deploy.md).
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Collection, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from affordcore.settings import Settings


@contextmanager
def cluster_jobs(settings: Settings) -> Iterator[None]:
    """Within the block, the library's parallel jobs run on the Ray cluster at `cluster.address` (nothing
    changes without one)."""
    if not settings.cluster.address:
        yield
        return
    from .common import require_extra

    require_extra("cluster")
    import ray

    import affordcore
    from affordcore.parallel import jobs_run_by

    package = Path(affordcore.__file__).parent
    ray.init(
        address=settings.cluster.address,
        runtime_env={"py_modules": [str(package)]},
        logging_level="WARNING",
        log_to_driver=False,
    )
    cpus = settings.cluster.cpus_per_job

    def run(function: Callable, jobs: list[tuple]) -> Iterator:
        task = ray.remote(function).options(num_cpus=cpus, max_retries=0)
        pending = [task.remote(*job) for job in jobs]
        for ref in pending:  # in order, each as soon as it and those before it are done
            yield ray.get(ref)

    try:
        with jobs_run_by(run):
            yield
    finally:
        ray.shutdown()


class RayNodeExited(RuntimeError):
    """A node of `local_ray_cluster` whose `ray start --block` exited before the cluster was up."""


@contextmanager
def local_ray_cluster(
    node_cpus: tuple[int, ...] = (1, 1), timeout: float = 180.0, grace: float = 3.0
) -> Iterator[str]:
    """A Ray head and worker nodes on this machine, `node_cpus` CPUs each (the head first), for tests and
    benchmarks: yields the head's address. Each node's `ray start --block` writes its output to a log in the
    cluster's temporary folder. A node that exits before the cluster is up raises `RayNodeExited` at once, a
    cluster not up within `timeout` seconds (the head, then all nodes) `TimeoutError`, each quoting the end
    of the logs; a head that exits at start is started once more on a fresh port. On leaving, each node's
    `ray start --block` and what it started (a process group of their own) get SIGTERM, then SIGKILL for
    what outlives `grace` seconds (Ray's own stop waits up to 16 s a node for work that a throwaway cluster
    does not need finished), and its temporary folder goes."""
    temp = tempfile.mkdtemp(prefix="ray-", dir="/tmp")  # short: Ray's socket paths live under it
    nodes = _Nodes(_ray_command(), Path(temp), timeout)
    try:
        address = nodes.start_head(node_cpus[0])
        for number, cpus in enumerate(node_cpus[1:], 1):
            nodes.start(f"worker {number}", f"--address={address}", f"--num-cpus={cpus}")
        nodes.wait_for(address, len(node_cpus))
        yield address
    finally:
        nodes.stop(grace)
        shutil.rmtree(temp, ignore_errors=True)


def _ray_command() -> str:
    """The `ray` command beside this interpreter (the `[cluster]` extra)."""
    return str(Path(sys.executable).with_name("ray"))


@dataclass
class _Node:
    name: str
    process: subprocess.Popen
    log: Path

    def tail(self) -> str:
        return _tail(f"the {self.name}'s output", self.log.read_text(errors="replace"))


class _Nodes:
    """The `ray start --block` processes of a local cluster, each writing to its own log in `temp`."""

    def __init__(self, ray: str, temp: Path, timeout: float):
        self.ray, self.temp, self.timeout = ray, temp, timeout
        self.env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0"}
        self.started: list[_Node] = []
        self.head_ports: list[int] = []

    def start(self, name: str, *arguments: str) -> _Node:
        command = [self.ray, "start", "--block", "--disable-usage-stats", *arguments]
        log = self.temp / f"{name.replace(' ', '-')}.log"
        with log.open("wb") as output:  # the node writes through its own copy of the descriptor
            process = subprocess.Popen(
                command, env=self.env, start_new_session=True, stdout=output, stderr=subprocess.STDOUT
            )
        self.started.append(_Node(name, process, log))
        return self.started[-1]

    def start_head(self, cpus: int) -> str:
        """The address of a head that came up."""
        try:
            return self._head("head", cpus)
        except RayNodeExited:  # its port can be taken between its choice here and Ray's binding it
            return self._head("second head", cpus)

    def _head(self, name: str, cpus: int) -> str:
        port = _free_port(avoiding=self.head_ports)
        self.head_ports.append(port)
        head = ["--head", f"--port={port}", "--include-dashboard=false", f"--temp-dir={self.temp}"]
        node = self.start(name, *head, f"--num-cpus={cpus}")
        try:
            self.wait_for(f"127.0.0.1:{port}", 1)
        except RayNodeExited:
            self.started.remove(node)  # a head started after it must not be blamed for its exit
            _signal_group(node.process, signal.SIGKILL)  # and whatever it started must not outlive it
            raise
        return f"127.0.0.1:{port}"

    def wait_for(self, address: str, count: int) -> None:
        """Returns once `ray status` counts `count` active nodes at `address`; raises as soon as a node's
        process has exited, or once the timeout is over."""
        deadline = time.monotonic() + self.timeout
        while True:
            active, status = _active_nodes(self.ray, address, deadline)
            if active >= count:
                return
            for node in self.started:
                if node.process.poll() is not None:
                    code = node.process.returncode
                    raise RayNodeExited(
                        f"Ray {node.name} exited with code {code} before the cluster at {address} was up\n"
                        + node.tail()
                    )
            if time.monotonic() > deadline:
                raise TimeoutError(self._timed_out(address, count, active, status))
            time.sleep(2)

    def _timed_out(self, address: str, count: int, active: int, status: str) -> str:
        heading = f"{count} Ray node(s) did not come up at {address} in {self.timeout:.0f} s"
        heading += f" ({active} active, none of their processes exited)"
        return "\n".join([heading, _tail("`ray status`", status), *(node.tail() for node in self.started)])

    def stop(self, grace: float) -> None:
        """SIGTERM to each node's process group, then SIGKILL to what outlives `grace` seconds."""
        for node in reversed(self.started):
            _signal_group(node.process, signal.SIGTERM)
        deadline = time.monotonic() + grace
        for node in reversed(self.started):
            try:
                node.process.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
            _signal_group(node.process, signal.SIGKILL)  # what the node started can outlive it
            node.process.wait(20)


def _free_port(avoiding: Collection[int]) -> int:
    """A port that nothing on 127.0.0.1 holds now, and none of `avoiding`."""
    while True:  # the system can hand out a port just let go of again
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        if port not in avoiding:
            return port


def _signal_group(process: subprocess.Popen, number: int) -> None:
    try:
        os.killpg(process.pid, number)
    except ProcessLookupError:  # no process of the group is left: a node that exited and was reaped
        pass


def _active_nodes(ray: str, address: str, deadline: float) -> tuple[int, str]:
    """How many nodes `ray status` counts active at `address`, and what it said."""
    command = [ray, "status", "--address", address]
    try:  # one that hangs must not hold the wait long past its deadline
        status = subprocess.run(
            command, capture_output=True, text=True, timeout=max(10.0, deadline - time.monotonic())
        )
    except subprocess.TimeoutExpired:
        return 0, "(it did not answer)"
    said = status.stdout + status.stderr
    if status.returncode != 0 or "Active:" not in status.stdout:
        return 0, said
    return status.stdout.split("Active:")[1].split("Pending:")[0].count("node_"), said


def _tail(what: str, text: str) -> str:
    """The last lines of `text` under a heading naming `what` they are."""
    lines = text.rstrip().splitlines()[-20:]  # enough for a traceback's end, short enough to read in CI
    return f"--- the end of {what} ---\n" + ("\n".join(lines) if lines else "(nothing)")
