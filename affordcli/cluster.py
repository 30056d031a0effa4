"""Jobs on a Ray cluster when `cluster.address` names one (AFFORD_CLUSTER__ADDRESS; the `[cluster]` extra).

The library runs its independent jobs (a room generated and scanned, a room's fields, a room's examples, one
training of the k-fold evaluation) through `affordcore.parallel.map_in_processes`, local processes by default;
here they are handed to Ray instead (`parallel.jobs_run_by`), so the library itself never imports Ray. Each
job is a Ray task that reserves `cluster.cpus_per_job` CPUs; the library's code travels with the job
(`runtime_env` py_modules), the data set and the room cache do not: they must be at the same path on every
node (docs/deploy.md).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
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


@contextmanager
def local_ray_cluster(
    node_cpus: tuple[int, ...] = (1, 1), timeout: float = 180.0, grace: float = 3.0
) -> Iterator[str]:
    """A Ray head and worker nodes on this machine, `node_cpus` CPUs each (the head first), for tests and
    benchmarks: yields the head's address; on leaving, each node's `ray start --block` and what it started
    (a process group of their own) get SIGTERM, then SIGKILL for what outlives `grace` seconds (Ray's own
    stop waits up to 16 s a node for work that a throwaway cluster does not need finished), and its
    temporary folder goes."""
    import os
    import shutil
    import signal
    import socket
    import subprocess
    import sys
    import tempfile
    import time

    ray = str(Path(sys.executable).with_name("ray"))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        address = f"127.0.0.1:{s.getsockname()[1]}"
    temp = tempfile.mkdtemp(prefix="ray-", dir="/tmp")  # short: Ray's socket paths live under it
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0"}

    def start(*arguments: str) -> subprocess.Popen:
        command = [ray, "start", "--block", "--disable-usage-stats", *arguments]
        output = subprocess.DEVNULL
        return subprocess.Popen(command, env=env, start_new_session=True, stdout=output, stderr=output)

    def wait_for(nodes: int) -> None:
        deadline = time.monotonic() + timeout
        while _active_nodes(ray, address) < nodes:
            if time.monotonic() > deadline:
                raise TimeoutError(f"{nodes} Ray node(s) did not come up at {address} in {timeout:.0f} s")
            time.sleep(2)

    started = []
    try:
        port = address.split(":")[1]
        head = ["--head", f"--port={port}", "--include-dashboard=false", f"--temp-dir={temp}"]
        started.append(start(*head, f"--num-cpus={node_cpus[0]}"))
        wait_for(1)
        for cpus in node_cpus[1:]:
            started.append(start(f"--address={address}", f"--num-cpus={cpus}"))
        wait_for(len(node_cpus))
        yield address
    finally:
        for process in reversed(started):
            os.killpg(process.pid, signal.SIGTERM)
        deadline = time.monotonic() + grace
        for process in reversed(started):
            try:
                process.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
            try:
                os.killpg(process.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            process.wait(20)
        shutil.rmtree(temp, ignore_errors=True)


def _active_nodes(ray: str, address: str) -> int:
    import subprocess

    status = subprocess.run([ray, "status", "--address", address], capture_output=True, text=True)
    if status.returncode != 0 or "Active:" not in status.stdout:
        return 0
    return status.stdout.split("Active:")[1].split("Pending:")[0].count("node_")
