"""Jobs on a Ray cluster: a head and a worker node started on this machine
(`affordcli.cluster.local_ray_cluster`), used through AFFORD_CLUSTER__ADDRESS, and torn down. Rooms
generated there are the same bytes as local ones, and the k-fold evaluation gives the same figures."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("ray")

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def cluster():
    """A Ray head (1 CPU) and a worker node (1 CPU) on this machine: the cluster's address."""
    from affordcli.cluster import local_ray_cluster

    with local_ray_cluster((1, 1)) as address:
        yield address


def _synth(out: Path, env: dict) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "affordcli", "synth", "--rooms", "4", "--seed", "3", "--out", str(out)]
    return subprocess.run(
        command + ["--scanner", "uniform", "--quiet"], capture_output=True, text=True, env=env, timeout=900
    )


def test_rooms_made_on_the_cluster_are_the_rooms_made_here(cluster, tmp_path):
    local = _synth(tmp_path / "local", dict(os.environ))
    assert local.returncode == 0, local.stderr
    remote = _synth(tmp_path / "ray", {**os.environ, "AFFORD_CLUSTER__ADDRESS": cluster})
    assert remote.returncode == 0, remote.stderr
    names = sorted(p.name for p in (tmp_path / "local").iterdir() if p.is_file())
    assert len(names) == 4 * 3 + 2
    for name in names:
        assert (tmp_path / "local" / name).read_bytes() == (tmp_path / "ray" / name).read_bytes(), name


def test_jobs_run_in_the_cluster_s_processes_and_the_evaluation_is_the_same(cluster, tmp_path):
    from affordcli.cluster import cluster_jobs
    from affordcore.learn.cache import RoomCache
    from affordcore.learn.evaluate import evaluate
    from affordcore.parallel import map_in_processes, where
    from affordcore.settings import ClusterSettings, FeatureSettings, GridSettings, Settings
    from affordcore.synth.batch import synthesize
    from affordcore.synth.dataset import SynthOptions

    data = tmp_path / "rooms"
    synthesize(SynthOptions(3, 11, ("workshop",), scanner="uniform"), data, workers=1)
    affordance = json.loads(next(data.glob("*.labels.json")).read_text())["labels"][0]["affordance"]
    settings = Settings(
        features=FeatureSettings(cell_size=0.5), grid=GridSettings(n_theta=8, theta_step=np.pi / 4)
    )
    on_ray = settings.model_copy(update={"cluster": ClusterSettings(address=cluster)})

    def run(s: Settings, cache: Path):
        return evaluate(data, [affordance], ["linear-tuned"], 3, s, ratios=(4,), cache=RoomCache(cache))

    here = run(settings, tmp_path / "cache-here")
    with cluster_jobs(on_ray):
        pids = {pid for _, pid in map_in_processes(where, [()] * 6, 1)}
        there = run(on_ray, tmp_path / "cache-ray")
    assert os.getpid() not in pids  # even one local worker's jobs went to the cluster's processes
    same = [
        [(o.learner, o.fold, o.ratio, o.precision, o.recall, o.f1) for o in e.outcomes] for e in (here, there)
    ]
    assert same[0] == same[1] and len(same[0]) == 4
    # the cluster computed its own copies of the rooms' fields and examples
    assert len(list((tmp_path / "cache-ray" / "fields").glob("*.npz"))) == 3
