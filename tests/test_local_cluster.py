"""`affordcli.cluster.local_ray_cluster` when its nodes do not come up, with a fake `ray` command (a shell
script, no Ray needed): the error says which node exited, with what code and what it printed, as soon as it
exits; a head that exits at start gets one more try on a fresh port; the nodes and the temporary folder
still go."""

from __future__ import annotations

import os
import re
import time
from pathlib import Path

import pytest

from affordcli import cluster


def _fake_ray(folder: Path, monkeypatch, cases: str) -> None:
    """`local_ray_cluster` runs `ray` as a shell script whose `case "$*"` branches are `cases`."""
    script = folder / "ray"
    script.write_text(f'#!/bin/sh\necho "fake ray $*"\ncase "$*" in\n{cases}\nesac\n')
    script.chmod(0o755)
    monkeypatch.setattr(cluster, "_ray_command", lambda: str(script))


def test_a_head_that_exits_is_tried_once_more_on_a_fresh_port_then_named_with_its_output(
    tmp_path, monkeypatch
):
    _fake_ray(tmp_path, monkeypatch, '  *) echo "Failed to start GCS: port taken" >&2; exit 3 ;;')
    start = time.monotonic()
    with pytest.raises(cluster.RayNodeExited) as raised:
        with cluster.local_ray_cluster((1, 1), timeout=120):
            pytest.fail("the cluster came up")
    assert time.monotonic() - start < 30  # each exit is seen at once, not after the timeout
    second, first = str(raised.value), str(raised.value.__context__)
    assert "Ray second head exited with code 3 before the cluster at 127.0.0.1:" in second
    assert "Ray head exited with code 3" in first
    assert "Failed to start GCS: port taken" in second
    ports = [re.search(r"--port=(\d+)", message).group(1) for message in (first, second)]
    assert ports[0] != ports[1]
    assert not Path(re.search(r"--temp-dir=(\S+)", second).group(1)).exists()


def test_a_worker_that_exits_is_named_and_the_head_is_stopped(tmp_path, monkeypatch):
    head = tmp_path / "head.pid"
    cases = f"""  *--head*) echo $$ > {head}; exec sleep 60 ;;
  status*) printf 'Active:\\n 1 node_a\\nPending:\\n' ;;
  *) echo "cannot reach the head" >&2; exit 4 ;;"""
    _fake_ray(tmp_path, monkeypatch, cases)
    with pytest.raises(cluster.RayNodeExited, match="Ray worker 1 exited with code 4") as raised:
        with cluster.local_ray_cluster((1, 1), timeout=120):
            pytest.fail("the cluster came up")
    assert "cannot reach the head" in str(raised.value)
    with pytest.raises(ProcessLookupError):
        os.kill(int(head.read_text()), 0)


def test_a_cluster_that_does_not_come_up_in_time_is_named_with_each_node_s_output(tmp_path, monkeypatch):
    cases = """  *--head*) echo "waiting for GCS"; exec sleep 60 ;;
  status*) echo "no cluster at that address yet" >&2; exit 1 ;;"""
    _fake_ray(tmp_path, monkeypatch, cases)
    with pytest.raises(TimeoutError, match="1 Ray node.s. did not come up at 127.0.0.1:") as raised:
        with cluster.local_ray_cluster((1, 1), timeout=1, grace=1):
            pytest.fail("the cluster came up")
    message = str(raised.value)
    assert "no cluster at that address yet" in message  # what `ray status` said
    assert "--- the end of the head's output ---" in message and "waiting for GCS" in message
