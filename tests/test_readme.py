"""The README's "Running the services" walk-through, run as written (only the port, the shared data's folder,
the viewer and a timeout substituted), on a computer as busy as a robot's: one CPU hog per core. The
assembler skips most of a 30 Hz stream there; the watch must still finish on the maps that cover the last
scan, and the recordings must be whole once the services are stopped."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import SHARED_DATA, needs_shared

from services.launch import cpu_hogs, free_port

README = Path(__file__).resolve().parents[1] / "README.md"
AFFORDANCES = ("sitting-relaxing", "sitting-working", "standing-working")


def readme_block(section: str) -> str:
    """The first ```bash block under the README heading `section`."""
    text = README.read_text()
    start = text.index(f"## {section}\n")
    block = re.search(r"```bash\n(.*?)```", text[start:], re.DOTALL)
    assert block, f"no bash block under {section!r} in README.md"
    return block.group(1)


def as_test_script(block: str, port: int, timeout: int) -> str:
    """The walk-through with what must differ on a test machine substituted, and nothing else."""
    venv_bin = Path(sys.executable).parent
    substitutions = [
        ("source .venv/bin/activate", f'export PATH="{venv_bin}:$PATH"'),
        ("127.0.0.1:7447", f"127.0.0.1:{port}"),
        ("../shared/data/", f"{SHARED_DATA}/"),
        ("afford watch ", f"afford watch --timeout {timeout} "),
        ("\nrerun ", "\nrerun rrd verify "),  # the viewer's files must be whole recordings
    ]
    for old, new in substitutions:
        assert old in block, f"the README walk-through no longer has {old!r}: update this test with it"
        block = block.replace(old, new)
    # a failing step leaves no service behind: the background job is stopped as a Ctrl-C would
    return "set -euo pipefail\ntrap 'for job in $(jobs -p); do kill -INT $job; done; wait' EXIT\n" + block


@pytest.mark.slow
@needs_shared
def test_the_readme_walk_through_runs_as_written_with_every_core_busy(tmp_path):
    script = as_test_script(readme_block("Running the services"), free_port(), timeout=150)
    with cpu_hogs(os.cpu_count() or 2):
        run = subprocess.Popen(
            ["bash", "-c", script],
            cwd=tmp_path,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,  # its own process group: a timeout stops the services too
        )
        try:
            stdout, stderr = run.communicate(timeout=400)
        except subprocess.TimeoutExpired:
            os.killpg(run.pid, signal.SIGKILL)
            stdout, stderr = run.communicate()
    assert run.returncode == 0, f"stdout:\n{stdout[-4000:]}\nstderr:\n{stderr[-4000:]}"
    published = re.search(r"published (\d+) depth frames", stdout)
    assert published and int(published.group(1)) == 100  # frames 0..297, every third
    for name in AFFORDANCES:
        document = json.loads((tmp_path / "maps" / f"{name}.json").read_text())
        assert document["affordance"] == name
    log = (tmp_path / "recordings" / "assembler.log").read_text()
    taken = re.search(r"stopped: (\d+) inputs taken, (\d+) rejected, (\d+) skipped", log)
    assert taken, log[-2000:]
    assert sum(int(v) for v in taken.groups()) == 100  # every scan accounted for, taken or not
