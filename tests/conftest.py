"""Shared test helpers.

Real sensor data lives beside the project in ``<root>/shared/data`` (the project is ``<root>/main``). It is
read in place, never copied, and tests that need it skip cleanly when it is absent.
"""

from __future__ import annotations

import fcntl
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"

needs_shared = pytest.mark.skipif(
    not SHARED_DATA.is_dir(), reason=f"shared real data not available at {SHARED_DATA}"
)


@pytest.fixture(scope="session", autouse=True)
def room_cache(tmp_path_factory) -> Iterator[Path]:
    """Training and evaluation cache rooms on disk (`learn.cache_dir`): in tests, in a folder of the session,
    never the user's cache; subprocesses inherit it."""
    folder = tmp_path_factory.mktemp("room-cache")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("AFFORD_LEARN__CACHE_DIR", str(folder))
        yield folder


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The shared data folder; skips the test when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared real data not available at {SHARED_DATA}")
    return SHARED_DATA


def imbalanced_gaussian(n: int, d: int, ratio: int, shift: float, seed: int):
    """n examples in d dimensions, about one positive per `ratio` negatives (at least three), positives
    shifted by `shift` in every feature: the Gaussian set-up of DESIGN.md's learner figures."""
    rng = np.random.default_rng(seed)
    y = np.where(rng.random(n) < 1 / (ratio + 1), 1, -1)
    y[:3] = 1
    X = rng.normal(size=(n, d)).astype(np.float32)
    X[y > 0] += shift
    return X, y


def skeleton_document() -> dict:
    """A model file's `skeleton` (15 joints, a torso height): what every model file must carry."""
    joints = np.random.default_rng(15).normal(scale=0.3, size=(15, 3))
    return {"joints": joints.tolist(), "torso_height": 0.6, "source": "test"}


def rrd_verify(path) -> subprocess.CompletedProcess:
    """`rerun rrd verify` on a recording, with this interpreter's rerun (returncode 0: it verifies)."""
    return subprocess.run(
        [sys.executable, "-m", "rerun", "rrd", "verify", str(path)],
        capture_output=True,
        text=True,
        timeout=120,
    )


def eventually(condition: Callable[[], bool], timeout: float = 10.0, poll: float = 0.2) -> bool:
    """Whether `condition` holds within `timeout` seconds, checked every `poll` seconds."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(poll)
    return True


def living_e2e_room():
    """The generated living room `generated_sequence` walks through (its ground truth: labels, furniture) and
    the random generator, in the state that goes on to scan it."""
    from affordcore.synth.rooms import generate_room

    rng = np.random.default_rng(3)
    return generate_room("living", rng, "living-e2e"), rng


@pytest.fixture(scope="session")
def generated_room():
    return living_e2e_room()[0]


@pytest.fixture(scope="session")
def generated_sequence(tmp_path_factory, worker_id) -> Path:
    """A generated living room seen by a virtual Kinect along a hand-held path (120 frames, published every
    third: 40 frames over 0.84 m of walk, enough to see the floor of a cluttered room). Written once per run:
    the xdist workers share it (the first to take the lock writes it, 12 s of rendering; no test writes to
    it)."""
    from affordcore.synth.dataset import write_sequence

    root = tmp_path_factory.getbasetemp()
    root = root if worker_id == "master" else root.parent  # the run's folder, above each worker's own
    folder, written = root / "living-e2e.sequence", root / "living-e2e.sequence.done"
    with open(root / "living-e2e.sequence.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not written.exists():
            room, rng = living_e2e_room()
            write_sequence(room, rng, folder, "depth", frames=120)
            written.touch()
    return folder


@pytest.fixture(scope="session")
def small_room(tmp_path_factory) -> str:
    """A 2.5 m x 2 m room (floor, two walls, a table) as a PLY file: a cloud the commands map in seconds."""
    from affordcore.example import box_surface_points
    from affordcore.geometry.scene import Cloud, save_cloud

    rng = np.random.default_rng(0)
    # Sizes off the 10 cm lattice, so the grid's extent does not hinge on rounding at a cell edge.
    boxes = [
        ((0, 0, 0), (2.47, 1.96, 0)),
        ((0, -0.08, 0), (2.47, 0, 2.3)),
        ((-0.08, 0, 0), (0, 1.96, 2.3)),
        ((1.0, 0.8, 0.7), (1.8, 1.5, 0.74)),
    ]
    points = np.concatenate(
        [box_surface_points(np.array(a, float), np.array(b, float), 800, rng) for a, b in boxes]
    )
    path = tmp_path_factory.mktemp("cloud") / "small-room.ply"
    save_cloud(path, Cloud(points))
    return str(path)


# -- order -------------------------------------------------------------------------------------------------


def pytest_collection_modifyitems(config, items) -> None:
    """Modules with the most slow tests first, otherwise as collected: in two workers (bootstrap.sh test hands
    out whole modules in this order) the long modules start at once and the short ones fill in behind them,
    instead of one long module running alone at the end."""
    slow: dict[str, int] = {}
    for item in items:
        slow[item.module.__name__] = slow.get(item.module.__name__, 0) + bool(item.get_closest_marker("slow"))
    items.sort(key=lambda item: -slow[item.module.__name__])  # a stable sort: in-module order is kept


# -- leaving ------------------------------------------------------------------------------------------------

_EXIT_STATUS = {"code": 0}


def pytest_sessionfinish(session, exitstatus) -> None:
    _EXIT_STATUS["code"] = int(exitstatus)


def pytest_unconfigure(config) -> None:
    """Leave even when a zenoh callback thread is still blocked in Rust: tests that close a session under a
    running service (a worker that dies, in tests/test_multihost.py) can leave one, and Python's exit would
    wait for it for ever after every result has been reported (seen once under heavy load)."""
    import os
    import threading

    lingering = [t for t in threading.enumerate() if t is not threading.main_thread() and not t.daemon]
    if lingering:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(_EXIT_STATUS["code"])
