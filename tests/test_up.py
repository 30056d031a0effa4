"""`afford up` (router + the three services in the foreground) and `afford status` (the health check), run as
a person runs them: subprocesses on a free loopback port, stopped by a signal."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import psutil
import pytest
from conftest import eventually, rrd_verify

from services.launch import free_port
from services.registry import SERVICES

pytestmark = pytest.mark.slow
START = 60.0  # seconds the stack may take to get ready on a loaded machine


def afford(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "affordcli", *args], capture_output=True, text=True, timeout=timeout
    )


def status(endpoint: str, *args: str) -> subprocess.CompletedProcess:
    return afford("status", "--connect", endpoint, "--timeout", "3", *args)


def start_up(
    tmp_path, robot: str = "robot1", site=None
) -> tuple[subprocess.Popen, str, list[psutil.Process]]:
    """`afford up` on a free port, once `afford status` says every service is ready; its children."""
    endpoint = f"{'tls/localhost' if site else 'tcp/127.0.0.1'}:{free_port()}"
    secured = ["--site", str(site)] if site else []
    viewer = ["--zenoh-config", str(site / "viewer.json5")] if site else []
    up = subprocess.Popen(
        [sys.executable, "-m", "affordcli", "up", "--listen", endpoint, "--robot", robot, *secured],
        cwd=tmp_path,  # the default --rrd-dir, ./recordings
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    ready = eventually(
        lambda: up.poll() is not None or status(endpoint, "--robot", robot, *viewer).returncode == 0,
        timeout=START,
    )
    if not ready or up.poll() is not None:
        up.kill()
        out, err = up.communicate(timeout=30)
        pytest.fail(f"afford up not ready within {START:.0f} s (exit {up.returncode}):\n{out}\n{err}")
    children = psutil.Process(up.pid).children(recursive=True)
    return up, endpoint, children


def left_running(children: list[psutil.Process]) -> list[str]:
    """The children still running (a reaped child is gone; one left behind is adopted and keeps running)."""
    alive = []
    for child in children:
        try:
            if child.is_running() and child.status() != psutil.STATUS_ZOMBIE:
                alive.append(" ".join(child.cmdline())[:120])
        except psutil.NoSuchProcess:
            pass
    return alive


def test_up_runs_the_stack_and_stops_it_cleanly_on_ctrl_c(tmp_path):
    started = time.monotonic()
    up, endpoint, children = start_up(tmp_path)
    ready_after = time.monotonic() - started
    # the router and one process per service; inference's mapping workers are theirs (children() is recursive)
    direct = psutil.Process(up.pid).children()
    assert len(direct) == 1 + len(SERVICES), [c.cmdline() for c in direct]

    answer = status(endpoint, "--robot", "robot1")
    assert answer.returncode == 0, answer.stdout + answer.stderr
    lines = answer.stdout.splitlines()
    assert [line.split()[0] for line in lines] == list(SERVICES)
    assert all(line.split()[1] in ("READY", "BUSY") for line in lines), answer.stdout
    # another robot's services are not there: unhealthy, exit 1
    other = status(endpoint, "--robot", "robot9", "--service", "features")
    assert other.returncode == 1 and "features" in other.stdout and "no answer" in other.stdout

    up.send_signal(signal.SIGINT)
    out, err = up.communicate(timeout=60)
    assert up.returncode == 0, f"{out}\n{err}"
    assert "ready: router on " + endpoint in out and f"--connect {endpoint} --robot robot1" in out
    for service in SERVICES:
        # each service's own lines, prefixed with its name, including its clean stop
        assert any(line.startswith(f"{service:<9} | stopped:") for line in out.splitlines()), out
        recording = tmp_path / "recordings" / f"{service}.rrd"
        assert recording.is_file(), f"{recording} missing; {out}"
        verified = rrd_verify(recording)
        assert verified.returncode == 0, f"{recording}: {verified.stdout}{verified.stderr}"
    assert not left_running(children)
    print(f"afford up ready after {ready_after:.1f} s")


def test_up_stops_the_rest_and_exits_1_when_a_service_dies(tmp_path):
    up, endpoint, children = start_up(tmp_path, robot="robot2")
    inference = next(c for c in children if "'inference'" in " ".join(c.cmdline()))
    inference.kill()  # a crash: SIGKILL
    out, err = up.communicate(timeout=60)
    assert up.returncode == 1, f"{out}\n{err}"
    assert "inference exited with code -9" in err and "stopped the rest" in err, err
    assert not left_running(children)
    for service in ("assembler", "features"):  # the others still closed their recordings
        assert rrd_verify(tmp_path / "recordings" / f"{service}.rrd").returncode == 0


def test_up_ends_on_sigterm_too_and_refuses_a_bad_robot_name(tmp_path):
    bad = afford("up", "--robot", "a/b", "--rrd-dir", str(tmp_path / "rec"))
    assert bad.returncode == 2 and bad.stderr.startswith("error: robot name 'a/b'"), bad.stderr
    up, _, children = start_up(tmp_path, robot="robot3")
    up.send_signal(signal.SIGTERM)
    out, err = up.communicate(timeout=60)
    assert up.returncode == 0, f"{out}\n{err}"
    assert not left_running(children)


def test_up_runs_a_secured_site_and_each_service_can_check_its_own_health(tmp_path):
    """What compose's health checks do: `afford status` as the service's own identity, through the router's
    mutual TLS and access control; without a certificate the router refuses it."""
    site = tmp_path / "site"
    made = afford("certs", str(site))
    assert made.returncode == 0, made.stderr
    up, endpoint, children = start_up(tmp_path, robot="robot4", site=site)
    try:
        for service in SERVICES:
            own = status(
                endpoint,
                "--robot",
                "robot4",
                "--service",
                service,
                "--zenoh-config",
                str(site / f"{service}.json5"),
            )
            assert own.returncode == 0 and own.stdout.split()[:2] == [service, "READY"], (
                own.stdout + own.stderr
            )
        plain = status(endpoint.replace("tls/", "tcp/"), "--robot", "robot4")
        assert plain.returncode == 1, plain.stdout
    finally:
        up.send_signal(signal.SIGINT)
        out, err = up.communicate(timeout=60)
    assert up.returncode == 0, f"{out}\n{err}"
    assert f"--zenoh-config {site / 'robot.json5'}" in out  # where to publish, as the sensor
    assert not left_running(children)


def test_status_without_a_router_is_unhealthy():
    result = afford("status", "--connect", f"tcp/127.0.0.1:{free_port()}", "--robot", "r", "--timeout", "1")
    assert result.returncode == 1 and result.stderr.startswith("error: no router at "), result.stderr
    unknown = afford("status", "--robot", "r", "--service", "mapper")
    assert unknown.returncode == 2 and "--service mapper: choose among" in unknown.stderr


def test_up_on_a_port_already_taken_is_one_line(tmp_path):
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = afford("up", "--listen", f"tcp/127.0.0.1:{port}", "--rrd-dir", str(tmp_path / "rec"))
    assert result.returncode == 2, result.stdout + result.stderr
    assert result.stderr.startswith(f"error: --listen tcp/127.0.0.1:{port}: cannot listen there")
    assert result.stdout == "" and not (tmp_path / "rec").exists()  # nothing was started


def test_a_service_that_dies_while_starting_is_named_with_its_exit_code(tmp_path):
    """What `afford up` prints whether a service dies before or after the stack is ready: name and code."""
    from services.launch import Stack

    stack = Stack(tmp_path, services=("inference",))
    stack.processes["inference"] = subprocess.Popen([sys.executable, "-c", "raise SystemExit(3)"])
    stack.processes["inference"].wait()
    with pytest.raises(RuntimeError, match=r"^inference exited with code 3 while starting \(ready: \[\]\)"):
        stack.wait_ready(timeout=5)
