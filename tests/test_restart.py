"""Nothing accepted is lost: every service killed with SIGKILL mid-stream and started again.

The assembler journals each frame before its pose goes out, so every frame whose pose anyone saw is in the
map after a restart (with `--state`); restarted features and inference fetch the latest map and fields with a
get and catch up without new input; the next frames join the restored map, and the maps that come out hold
exactly the frames taken. A recording cut off by the kill is repaired by `rerun rrd merge`, and the restarted
service writes a new recording beside it."""

from __future__ import annotations

import json
import re
import subprocess
import sys

import pytest
from conftest import eventually, rrd_verify

from services.launch import Stack
from services.transport import Keys

pytestmark = pytest.mark.slow
AFFORD = [sys.executable, "-m", "affordcli"]
AFFORDANCES = ("sitting-relaxing", "sitting-working", "standing-working")
SERVICES = ("assembler", "features", "inference")
# Frames published before the kill: the walk's map goes out every 0.5 s (~5 frames) once its floor is in
# view, and the kill waits for 10 frames and a map, so 40 frames leave several chances before the last.
FIRST_RUN = 40


def _publish(stack: Stack, folder, first: int, frames: int) -> subprocess.Popen:
    return subprocess.Popen(
        [*AFFORD, "publish", str(folder), "--connect", stack.endpoint, "--robot", stack.robot, "-q"]
        + ["--rate", "10", "--step", "3", "--first", str(first), "--frames", str(frames)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def _watch(stack: Stack, frames: int, out) -> dict:
    """The three maps built from at least `frames` scans (afford watch --frames), as their documents."""
    watched = subprocess.run(
        [*AFFORD, "watch", "--connect", stack.endpoint, "--robot", stack.robot, "--quiet"]
        + ["--frames", str(frames), "--timeout", "240", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert watched.returncode == 0, watched.stdout + watched.stderr + stack.logs()
    return {name: json.loads((out / f"{name}.json").read_text()) for name in AFFORDANCES}


def _finished(publisher: subprocess.Popen) -> str:
    """What a publisher said, if it has exited (for a failure's message)."""
    return publisher.communicate()[0] if publisher.poll() is not None else "still running"


def _frames_of(stack: Stack) -> set[int]:
    """The scan counts the watched maps say they were built from (the map message's `frames`)."""
    session = stack.session()
    try:
        from affordwire import messages

        counts = set()
        for reply in session.get(Keys(stack.robot).affordance("*"), timeout=5.0):
            if reply.ok is not None:
                counts.add(messages.parse(messages.AffordanceMapMessage, reply.ok.payload.to_bytes()).frames)
        return counts
    finally:
        session.close()


def test_killed_services_restart_and_lose_no_accepted_frame(generated_sequence, tmp_path):
    env = {
        "AFFORD_SERVICE__STATE": str(tmp_path / "state"),
        "AFFORD_SERVICE__MAX_LAG": "600",  # every frame taken: the count below is the proof
        "AFFORD_ASSEMBLER__CHECKPOINT_PERIOD": "1",
        "AFFORD_ASSEMBLER__PUBLISH_PERIOD": "0.5",  # a map soon after the floor is in view
        "AFFORD_ASSEMBLER__BUSY_PUBLISH_PERIOD": "0.5",  # ... even with scans waiting
    }
    stack = Stack(tmp_path / "run", env=env).start()
    try:
        session = stack.session()
        poses, clouds = [], []
        keys = Keys(stack.robot)
        subscribers = [
            session.declare_subscriber(keys.pose, poses.append),
            session.declare_subscriber(keys.cloud, clouds.append),
        ]
        publisher = _publish(stack, generated_sequence, first=0, frames=FIRST_RUN)
        # once a map has gone out (the floor is in view), mid-stream: frames after the kill reach nobody
        assert eventually(lambda: clouds and 10 <= len(poses) < FIRST_RUN, timeout=120, poll=0.05), (
            f"{len(poses)} poses, {len(clouds)} clouds; publish: {_finished(publisher)}" + stack.logs()
        )
        stack.kill("assembler")
        publisher.communicate(timeout=120)
        seen = len(poses)  # every frame whose pose went out was journaled first
        for subscriber in subscribers:
            subscriber.undeclare()
        session.close()

        stack.restart("assembler")
        restored = int(re.findall(r"restored (\d+) frames", (stack.folder / "assembler.log").read_text())[-1])
        print(f"poses seen before the kill: {seen}; frames restored: {restored}")
        assert seen <= restored < FIRST_RUN
        for service in ("features", "inference"):
            stack.kill(service)
            stack.restart(service)
        _watch(stack, restored, tmp_path / "caught-up")  # from the restored map, with no new input
        assert _frames_of(stack) == {restored}

        second = _publish(stack, generated_sequence, first=102, frames=6)
        output, _ = second.communicate(timeout=120)
        assert second.returncode == 0, output
        _watch(stack, restored + 6, tmp_path / "after")
        assert _frames_of(stack) == {restored + 6}  # the restored frames and every new one
    finally:
        codes = stack.stop()
    assert codes == {name: 0 for name in (*SERVICES, "router")}, stack.logs()

    run = stack.folder
    for service in SERVICES:  # the killed run's recording is kept; the restarted service wrote a new one
        killed, restarted = run / f"{service}.rrd", run / f"{service}-1.rrd"
        assert killed.exists() and restarted.exists()
        repaired = run / f"{service}-repaired.rrd"
        merge = subprocess.run(
            [sys.executable, "-m", "rerun", "rrd", "merge", str(killed), "-o", str(repaired)],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert merge.returncode == 0, merge.stderr
        for rrd in (repaired, restarted):
            verify = rrd_verify(rrd)
            assert verify.returncode == 0, f"{rrd}: {verify.stderr}"
