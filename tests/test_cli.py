"""The `afford` command line: its contract (JSON on stdout), its errors, and its start-up cost."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from affordcore.geometry.features import FeatureLayout
from affordcore.geometry.grid import PoseGrid
from affordcore.geometry.skeleton import all_skeletons, get_skeleton
from affordcore.settings import Settings


def afford(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "affordcli", *args], capture_output=True, text=True, timeout=300, env=env
    )


def test_importing_the_cli_loads_no_heavy_library():
    probe = (
        "import sys, affordcli.app; print([m for m in "
        "('open3d', 'scipy', 'matplotlib', 'sklearn', 'zenoh', 'rerun') if m in sys.modules])"
    )
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]"


def test_help_lists_the_subcommands():
    result = afford("--help")
    assert result.returncode == 0
    for command in ("features", "align", "demo", "config", "skeletons"):
        assert command in result.stdout


def test_version_is_the_installed_package_s():
    from importlib.metadata import version

    result = afford("--version")
    assert result.returncode == 0 and result.stdout.strip() == f"affordmap {version('affordmap')}"


def test_features_json_contract(small_room):
    result = afford("features", small_room, "--affordance", "sitting-working", "--json")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)  # stdout holds exactly one JSON object
    assert set(report) == {"poses", "features", "seconds", "peak_rss_mb"}
    skeleton = get_skeleton("sitting-working")
    expected = PoseGrid.over_footprint(
        (-0.08, -0.08, 2.47, 1.96), skeleton.torso_height, 0.1, reach_above=skeleton.torso_reach_above
    )
    # three torso levels one voxel apart, and sitting-working's two above them (bar stools' places)
    assert report["poses"] == expected.size == 26 * 21 * 5 * 63
    assert report["features"] == FeatureLayout.from_settings(Settings()).n_features == 222
    assert report["seconds"] > 0 and report["peak_rss_mb"] > 50


def test_features_can_write_the_matrix(small_room, tmp_path, monkeypatch):
    out = tmp_path / "features.npy"
    env = {**__import__("os").environ, "AFFORD_FEATURES__CELL_SIZE": "0.5", "AFFORD_GRID__N_THETA": "2"}
    result = afford("features", small_room, "-a", "standing-working", "--out", str(out), "--quiet", env=env)
    assert result.returncode == 0, result.stderr
    matrix = np.load(out, mmap_mode="r")
    assert matrix.shape == (26 * 21 * 3 * 2, 30 + 3 * 8)
    assert np.isfinite(matrix).all() and matrix[:, :15].max() > 0.5  # distances were written, not zeros


@pytest.mark.parametrize(
    "args, message",
    [
        (["features", "/nonexistent/room.ply", "-a", "sitting-working"], "no such file"),
        (["features", "{room}", "-a", "flying"], "unknown affordance 'flying'"),
        (["features", "{room}", "-a", "sitting-working", "--gravity", "1,2"], "three numbers"),
        (["align", "{bad}"], "unknown cloud format"),
        (["map", "{room}", "--out", "{bad}"], "is a file; give a folder"),
    ],
)
def test_bad_input_is_one_clear_line_and_exit_2(small_room, tmp_path, args, message):
    bad = tmp_path / "room.las"
    bad.write_text("x")
    args = [a.format(room=small_room, bad=bad) for a in args]
    result = afford(*args)
    assert result.returncode == 2
    assert message in result.stderr and "Traceback" not in result.stderr


def test_no_floor_is_an_error_not_a_frame(tmp_path):
    rng = np.random.default_rng(0)
    sphere = rng.normal(size=(3000, 3))
    sphere /= np.linalg.norm(sphere, axis=1, keepdims=True)
    path = tmp_path / "ball.npy"
    np.save(path, sphere)
    result = afford("align", str(path))
    assert result.returncode == 2 and "no floor found" in result.stderr


def test_align_reports_the_frame_it_found(small_room, tmp_path):
    from affordcore.geometry.scene import load_cloud

    cloud = load_cloud(small_room)
    y_up = cloud.points @ np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], float).T + [0, 0.8, 0]
    path = tmp_path / "y-up.npy"
    np.save(path, y_up)
    out = tmp_path / "aligned.ply"
    result = afford("align", str(path), "--json", "--out", str(out))
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert report["up_axis"] == "+y" and abs(report["floor_offset"] - 0.8) < 0.02
    aligned = load_cloud(out).points
    np.testing.assert_allclose(
        np.sort(aligned[:, 2])[[0, -1]], np.sort(cloud.points[:, 2])[[0, -1]], atol=0.02
    )


def test_config_prints_every_default_with_its_variable():
    result = afford("config")
    assert result.returncode == 0
    assert "AFFORD_VOXEL__RESOLUTION=0.1" in result.stdout
    assert "AFFORD_GRID__N_THETA=63" in result.stdout


def test_config_current_shows_environment_overrides():
    env = {**__import__("os").environ, "AFFORD_GRID__N_THETA": "12"}
    result = afford("config", "--current", env=env)
    assert json.loads(result.stdout)["grid"]["n_theta"] == 12


def test_skeletons_list_names_every_affordance():
    result = afford("skeletons", "list")
    assert result.returncode == 0
    for skeleton in all_skeletons():
        assert skeleton.affordance in result.stdout


@pytest.mark.parametrize(
    "args, message",
    [
        # the --out error comes first, though the input does not exist: checked before any work
        (["synth", "--rooms", "1", "--out", "{file}"], "--out {file} is a file; give a folder"),
        (["evaluate", "--data", "/nonexistent", "--out", "{file}"], "--out {file} is a file; give a folder"),
        (
            ["train", "--data", "/nonexistent", "-a", "sitting-working", "--out", "{file}/model.json"],
            "--out {file}/model.json: {file} is a file, not a folder",
        ),
        (["features", "/nonexistent.ply", "-a", "sitting-working", "--out", "{folder}"], "is a folder"),
        (["align", "/nonexistent.ply", "--out", "{folder}/aligned.txt"], "written as .ply, .pcd, .npy"),
        (["align", "/nonexistent.ply", "--out", "{file}/aligned.ply"], "{file} is a file, not a folder"),
        (["skeletons", "show", "--out", "{folder}"], "--out {folder} is a folder; give a file name"),
        (["models", "rebuild", "--out", "{file}"], "--out {file} is a file; give a folder"),
    ],
)
def test_out_is_checked_before_the_work(tmp_path, args, message):
    file, folder = tmp_path / "taken.txt", tmp_path / "folder"
    file.write_text("x")
    folder.mkdir()
    result = afford(*[a.format(file=file, folder=folder) for a in args])
    assert result.returncode == 2, result.stdout + result.stderr
    assert result.stderr.startswith("error: --out "), result.stderr
    assert message.format(file=file, folder=folder) in result.stderr
    assert result.stderr.count("\n") == 1, result.stderr  # one line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["folder", "taken.txt"]  # nothing written
    assert not list(folder.iterdir())


def test_rebuild_refuses_real_rooms_it_cannot_find_before_generating_anything(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    for real, message in (
        (tmp_path / "nowhere", f"--real {tmp_path / 'nowhere'}: no such folder"),
        (empty, f"--real: no labelled room with its cloud in {empty}"),
    ):
        result = afford("models", "rebuild", "--out", str(tmp_path / "models"), "--real", str(real))
        assert result.returncode == 2 and message in result.stderr, result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty"]  # no models, no rooms


# Imported at the start of the afford process (sitecustomize): making any folder under one named "locked"
# is refused as a read-only folder refuses it. A mode would not do: root (CI, containers) writes anyway.
LOCKED_FOLDER = """
import errno, os, pathlib
make = pathlib.Path.mkdir
def refuse(self, *args, **kwargs):
    if "locked" in self.parts:
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(self))
    return make(self, *args, **kwargs)
pathlib.Path.mkdir = refuse
"""


def test_an_out_that_cannot_be_written_is_one_line(tmp_path):
    import os

    (tmp_path / "site").mkdir()
    (tmp_path / "site" / "sitecustomize.py").write_text(LOCKED_FOLDER)
    path = os.pathsep.join(filter(None, [str(tmp_path / "site"), os.environ.get("PYTHONPATH")]))
    out = tmp_path / "locked" / "rooms"
    result = afford("synth", "--rooms", "1", "--out", str(out), env={**os.environ, "PYTHONPATH": path})
    assert result.returncode == 2, result.stderr
    assert result.stderr == f"error: --out {out} cannot be made: Permission denied\n"
    result = afford("synth", "--rooms", "1", "--out", "/sys/afford-rooms")
    assert result.returncode == 2, result.stderr
    assert result.stderr == "error: --out /sys/afford-rooms cannot be made: Operation not permitted\n"


@pytest.mark.slow
def test_points_that_are_not_finite_are_counted_on_stderr(small_room, tmp_path):
    from affordcore.geometry.scene import load_cloud

    points = load_cloud(small_room).points
    bad = np.full((len(points) // 10, 3), np.nan)
    bad[::7] = [np.inf, 0.0, 1.0]  # inf counts too
    path = tmp_path / "holes.npy"
    np.save(path, np.concatenate([points, bad])[np.random.default_rng(1).permutation(len(points) + len(bad))])
    warning = (
        f"warning: dropped {len(bad):,} of {len(points) + len(bad):,} points that are not finite (NaN or inf)"
    )
    mapped = afford("map", str(path), "--out", str(tmp_path / "maps"), "-a", "sitting-working", "--quiet")
    assert mapped.returncode == 0, mapped.stderr
    assert warning in mapped.stderr.splitlines(), mapped.stderr
    assert f"{len(points):,} points" in mapped.stdout
    aligned = afford("align", str(path), "--json")
    assert aligned.returncode == 0 and warning in aligned.stderr.splitlines(), aligned.stderr
    assert json.loads(aligned.stdout)["dropped_nonfinite"] == len(bad)  # stdout stays one JSON object
    features = afford("features", str(path), "-a", "sitting-working", "--json", "--quiet")
    assert features.returncode == 0 and warning in features.stderr.splitlines(), features.stderr
    json.loads(features.stdout)
    clean = afford("align", small_room)
    assert "not finite" not in clean.stderr
