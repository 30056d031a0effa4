"""`afford map` and `afford demo`: the three outputs from a cloud, in the world frame, and clear errors."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from affordcore.example import example_room
from affordcore.geometry.features import FeatureLayout
from affordcore.geometry.scene import Cloud, load_cloud, save_cloud, thin_huge_cloud
from affordcore.labels import Label, LabelSet, match_places, save_labels
from affordcore.learn.model import load_model, shipped_models
from affordcore.mapping.recording import recorded_entities
from affordcore.settings import MapSettings, Settings

AFFORDANCES = ("sitting-relaxing", "sitting-working", "standing-working")


def afford(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "affordcli", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, **(env or {})},
    )


@pytest.fixture(scope="module")
def example(tmp_path_factory):
    path = tmp_path_factory.mktemp("room") / "example.ply"
    save_cloud(path, example_room())
    return path


@pytest.fixture(scope="module")
def mapped(example, tmp_path_factory):
    out = tmp_path_factory.mktemp("map")
    result = afford("map", example, "--out", out, "--quiet")
    assert result.returncode == 0, result.stderr
    return out, result


def test_every_affordance_has_a_model_for_the_running_layout():
    layout = FeatureLayout.from_settings(Settings())
    assert set(shipped_models()) == set(AFFORDANCES)
    for path in shipped_models().values():
        load_model(path, layout)  # raises if the shipped model no longer matches the code


def test_map_writes_json_png_and_a_verified_recording(mapped):
    out, result = mapped
    assert "no sensor positions (--origins): unknown space is not told from free" in result.stdout
    for affordance in AFFORDANCES:
        document = json.loads((out / f"{affordance}.json").read_text())
        assert document["affordance"] == affordance and document["model"].startswith(affordance + "/")
        assert np.array(document["world_from_input"]).shape == (4, 4)
        grid = document["grid"]
        # three torso levels, and sitting-working's two above them for bar stools and high chairs
        levels = 5 if affordance == "sitting-working" else 3
        assert grid["step"] == pytest.approx(0.1) and grid["n_theta"] == 63 and len(grid["z"]) == levels
        scores = [p["score"] for p in document["positives"]]
        assert all(s > document["threshold"] - 1e-4 for s in scores) and scores == sorted(
            scores, reverse=True
        )
        # the shipped models' places are those a person can use with at least the model's own cut (chosen on
        # its validation rooms, written in its file), the likeliest first
        probabilities = [skeleton["probability"] for skeleton in document["skeletons"]]
        cut = load_model(shipped_models()[affordance]).places.cut
        assert (
            document["place_probability"] == cut and document["place_threshold"] is None and 0.2 <= cut <= 0.5
        )
        assert all(p >= cut for p in probabilities) and probabilities == sorted(probabilities, reverse=True)
        assert all(np.array(skeleton["joints"]).shape == (15, 3) for skeleton in document["skeletons"])
        assert (out / f"{affordance}.png").stat().st_size > 20_000
    verify = subprocess.run(
        [sys.executable, "-m", "rerun", "rrd", "verify", str(out / "map.rrd")], capture_output=True, text=True
    )
    assert verify.returncode == 0, verify.stderr
    entities = recorded_entities(out / "map.rrd")
    assert "/world/cloud" in entities
    for affordance in AFFORDANCES:
        assert {f"/world/{affordance}/confidence", f"/world/{affordance}/skeletons"} <= entities
        # one keypoint entity per skeleton of the JSON map, no more (tests/test_recording.py reads them)
        count = len(json.loads((out / f"{affordance}.json").read_text())["skeletons"])
        assert {f"/world/{affordance}/skeletons/{rank}" for rank in range(count)} <= entities
        assert f"/world/{affordance}/skeletons/{count}" not in entities


def test_json_only_maps_are_the_same_maps_and_load_neither_matplotlib_nor_rerun(example, mapped, tmp_path):
    """`--no-png --no-rrd`, for a robot that wants the JSON alone: the same JSON files as a full run, nothing
    else written, and the command's own process never imports matplotlib or rerun."""
    script = (
        "import sys; from pathlib import Path; from affordcli.room import map_room\n"
        f"map_room(Path({str(example)!r}), Path({str(tmp_path)!r}), [], [], 'auto', None, True, png=False)\n"
        "print(sorted(m for m in ('matplotlib', 'rerun') if m in sys.modules))\n"
    )
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip().splitlines()[-1] == "[]", run.stdout
    assert sorted(path.name for path in tmp_path.iterdir()) == [f"{name}.json" for name in AFFORDANCES]
    out, _ = mapped
    for name in AFFORDANCES:
        assert json.loads((tmp_path / f"{name}.json").read_text()) == json.loads(
            (out / f"{name}.json").read_text()
        )
    cli = afford("map", example, "--out", tmp_path / "cli", "--no-png", "--no-rrd", "-q")
    assert cli.returncode == 0 and sorted(p.suffix for p in (tmp_path / "cli").iterdir()) == [".json"] * 3
    both = afford("map", example, "--out", tmp_path / "both", "--no-rrd", "--rrd", tmp_path / "x.rrd")
    assert both.returncode == 2 and "--no-rrd" in both.stderr


def test_the_example_sofa_is_found(mapped):
    """The built-in room's sofa (x 0.05-0.95, y 1.2-3.4, facing +x) must hold sitting-relaxing skeletons."""
    out, _ = mapped
    skeletons = json.loads((out / "sitting-relaxing.json").read_text())["skeletons"]
    on_sofa = [s for s in skeletons if 0.2 < s["x"] < 1.0 and 1.3 < s["y"] < 3.3 and np.cos(s["theta"]) > 0.7]
    assert len(on_sofa) >= 2


def test_labels_are_scored_and_drawn(example, mapped, tmp_path):
    """`--labels`: each map's line says how many labelled places its skeletons found and how many skeletons
    match none (as `match_places` counts them in the world frame), and the PNG shows the labels."""
    labels = LabelSet(
        "example",
        "example.ply",
        "z-up, metres, floor at z = 0",
        (
            Label("sitting-relaxing", 0.0, start=(0.5, 1.6), end=(0.5, 3.0)),  # the sofa's seat line
            Label("sitting-relaxing", 0.0, at=(4.0, 4.0)),  # where nobody sits: never found
        ),
    )
    path = save_labels(tmp_path / "example.labels.json", labels)
    out = tmp_path / "out"
    result = afford("map", example, "--out", out, "-a", "sitting-relaxing", "--quiet", "--labels", path)
    assert result.returncode == 0, result.stderr
    document = json.loads((out / "sitting-relaxing.json").read_text())
    skeletons = np.array([[s["x"], s["y"], s["theta"]] for s in document["skeletons"]]).reshape(-1, 3)
    match = match_places(labels.moved(np.array(document["world_from_input"])), "sitting-relaxing", skeletons)
    assert match.found.tolist() == [True, False]  # the sofa, not the phantom
    line = next(line for line in result.stdout.splitlines() if line.startswith("sitting-relaxing"))
    assert line.endswith(f"; labels: 1 of 2 found, {int(match.false.sum())} false"), line
    unlabelled, _ = mapped  # the same map without labels: the same JSON, another picture
    assert (out / "sitting-relaxing.json").read_bytes() == (unlabelled / "sitting-relaxing.json").read_bytes()
    assert (out / "sitting-relaxing.png").read_bytes() != (unlabelled / "sitting-relaxing.png").read_bytes()
    drawn = {
        f"/{view}/sitting-relaxing/labels/{part}"
        for view in ("world", "plan")
        for part in ("places", "facing")
    }
    assert drawn <= recorded_entities(out / "map.rrd")
    assert not drawn & recorded_entities(unlabelled / "map.rrd")


def test_world_from_input_maps_the_input_cloud_to_the_world(example, tmp_path):
    tilted = load_cloud(example)
    angle = np.deg2rad(90)  # the room stored y-up, as many scanners write it
    rotation = np.array([[1, 0, 0], [0, np.cos(angle), -np.sin(angle)], [0, np.sin(angle), np.cos(angle)]])
    path = tmp_path / "y-up.ply"
    save_cloud(path, Cloud(tilted.points @ rotation.T + [0.3, 1.0, -0.2]))
    origins = tmp_path / "stations.txt"  # where the sensor stood, in the file's frame
    np.savetxt(origins, np.array([[2.0, 1.5, 1.5]]) @ rotation.T + [0.3, 1.0, -0.2])
    result = afford(
        "map", path, "--out", tmp_path / "out", "-a", "sitting-relaxing", "--quiet", "--origins", origins
    )
    assert result.returncode == 0, result.stderr
    assert "sensor positions: 1, free space told from unknown" in result.stdout
    document = json.loads((tmp_path / "out" / "sitting-relaxing.json").read_text())
    world_from_input = np.array(document["world_from_input"])
    points = load_cloud(path).points @ world_from_input[:3, :3].T + world_from_input[:3, 3]
    assert abs(np.percentile(points[:, 2], 1)) < 0.02  # the floor at z = 0
    assert np.percentile(points[:, 2], 99.9) > 2.0  # and up is up


@pytest.mark.parametrize(
    "case, message",
    [
        ("empty", "empty file"),
        ("no-floor", "floor"),
        ("other-layout", "feature layout"),
        ("unknown-affordance", "no shipped model for sitting-upside-down"),
        ("bad-origins", "stations.txt: sensor positions must be an (M, 3) array"),
        ("bad-labels", "room.labels.json"),
    ],
)
def test_bad_input_is_a_clear_error(case, message, example, tmp_path):
    args = [example]
    env = {}
    if case == "empty":
        (tmp_path / "empty.xyz").write_text("")
        args = [tmp_path / "empty.xyz"]
    elif case == "no-floor":
        rng = np.random.default_rng(0)
        sphere = rng.normal(size=(20000, 3))
        save_cloud(tmp_path / "ball.ply", Cloud(sphere / np.linalg.norm(sphere, axis=1, keepdims=True) + 3.0))
        args = [tmp_path / "ball.ply"]
    elif case == "other-layout":
        env = {"AFFORD_FEATURES__CELL_SIZE": "0.5"}
    elif case == "bad-origins":
        (tmp_path / "stations.txt").write_text("1.0 2.0\n")
        args += ["--origins", tmp_path / "stations.txt"]
    elif case == "bad-labels":
        (tmp_path / "room.labels.json").write_text('{"format": "affordance-labels/1"}')
        args += ["--labels", tmp_path / "room.labels.json"]
    else:
        args += ["-a", "sitting-upside-down"]
    result = afford("map", *args, "--out", tmp_path / "out", "--quiet", env=env)
    assert result.returncode == 2 and result.stderr.startswith("error: ") and message in result.stderr, (
        result.stderr
    )
    assert "Traceback" not in result.stderr


def test_a_huge_cloud_is_thinned_with_a_warning():
    cloud = example_room()
    thinned, warning = thin_huge_cloud(cloud, 40_000, MapSettings().thin_voxel)
    assert len(thinned) <= 40_000 and len(thinned) > 10_000 and "thinned" in warning
    same, none = thin_huge_cloud(cloud, MapSettings().max_points, MapSettings().thin_voxel)
    assert same is cloud and none is None
    # the thinned cloud keeps the room's extent
    np.testing.assert_allclose(thinned.points.min(axis=0), cloud.points.min(axis=0), atol=0.05)


@pytest.mark.slow
def test_demo_maps_the_example_room(tmp_path):
    result = afford("demo", "--out", tmp_path / "demo", "--quiet")
    assert result.returncode == 0, result.stderr
    assert all((tmp_path / "demo" / f"{a}.json").exists() for a in AFFORDANCES)
    assert "map.rrd" in result.stdout and "rerun " in result.stdout
    assert (
        tmp_path / "demo" / "example-room.ply"
    ).stat().st_size > 1_000_000 and "up = input +z" in result.stdout
