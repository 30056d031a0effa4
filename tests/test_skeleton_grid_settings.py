"""Skeleton files, their discovery, the pose grid, and the settings."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from affordcore.geometry.features import FeatureLayout
from affordcore.geometry.grid import PoseGrid
from affordcore.geometry.skeleton import (
    BUILTIN_DIR,
    JOINTS,
    SkeletonError,
    all_skeletons,
    get_skeleton,
    load_skeleton,
    skeleton_files,
)
from affordcore.learn.model import load_model, shipped_models
from affordcore.settings import Settings

PACKAGE = Path(__file__).resolve().parents[1] / "affordcore"


def _bone(skeleton, a: str, b: str) -> float:
    return float(np.linalg.norm(skeleton.joints[JOINTS.index(a)] - skeleton.joints[JOINTS.index(b)]))


def test_shipped_skeletons_are_plausible_adults():
    skeletons = all_skeletons()
    assert len(skeletons) >= 3
    for skeleton in skeletons:
        assert skeleton.joints.shape == (15, 3)
        assert np.allclose(skeleton.joints[JOINTS.index("TORSO")], 0)
        feet = skeleton.torso_height + skeleton.joints[[JOINTS.index("L_FOOT"), JOINTS.index("R_FOOT")], 2]
        assert np.all((feet > -0.05) & (feet < 0.15)), f"{skeleton.affordance}: feet at {feet} m"
        head = skeleton.torso_height + skeleton.joints[JOINTS.index("HEAD"), 2]
        assert 1.0 < head < 1.9, f"{skeleton.affordance}: head at {head:.2f} m"
        for side in "LR":
            assert 0.2 < _bone(skeleton, f"{side}_SHOULDER", f"{side}_ELBOW") < 0.4
            assert 0.3 < _bone(skeleton, f"{side}_HIP", f"{side}_KNEE") < 0.55
            assert 0.3 < _bone(skeleton, f"{side}_KNEE", f"{side}_FOOT") < 0.55
        # left is +y in the skeleton frame
        assert (
            skeleton.joints[JOINTS.index("L_SHOULDER"), 1]
            > 0
            > skeleton.joints[JOINTS.index("R_SHOULDER"), 1]
        )


def test_no_affordance_names_are_hard_coded_in_the_code():
    names = [path.stem for path in BUILTIN_DIR.glob("*.json")]
    pattern = re.compile("|".join(re.escape(name) for name in names))
    offenders = [str(p) for p in PACKAGE.rglob("*.py") if pattern.search(p.read_text())]
    assert not offenders, f"affordance names listed in code: {offenders}"


def test_a_new_affordance_is_just_a_new_file(tmp_path):
    source = json.loads((BUILTIN_DIR / "standing-working.json").read_text())
    source["affordance"] = "leaning"
    source["torso_height"] = 1.07
    (tmp_path / "leaning.json").write_text(json.dumps(source))
    assert "leaning" in skeleton_files([tmp_path])
    assert get_skeleton("leaning", [tmp_path]).torso_height == 1.07
    # A user file overrides the built-in one of the same name.
    source["affordance"] = "standing-working"
    source["torso_height"] = 1.2
    (tmp_path / "standing-working.json").write_text(json.dumps(source))
    assert get_skeleton("standing-working", [tmp_path]).torso_height == 1.2
    assert get_skeleton("standing-working").torso_height != 1.2


def test_unknown_affordance_lists_the_known_ones():
    with pytest.raises(SkeletonError, match="unknown affordance 'flying'.*sitting"):
        get_skeleton("flying")


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda d: d.update(format="other/1"), "'format'"),
        (lambda d: d["joints"].pop("HEAD"), "exactly the 15 joints"),
        (lambda d: d["joints"].update(TORSO=[0.1, 0, 0]), "TORSO"),
        (lambda d: d["joints"].update(HEAD=[0, "a", 1]), "numbers"),
        (lambda d: d.update(torso_height=-1), "torso_height"),
        (lambda d: d.update(torso_height=0.3), "under the floor"),
    ],
)
def test_bad_skeleton_files_are_named_errors(tmp_path, change, message):
    document = json.loads((BUILTIN_DIR / "sitting-working.json").read_text())
    change(document)
    path = tmp_path / "broken.json"
    path.write_text(json.dumps(document))
    with pytest.raises(SkeletonError, match=message) as error:
        load_skeleton(path)
    assert "broken.json" in str(error.value)


def test_missing_skeleton_folder_is_an_error(tmp_path):
    with pytest.raises(SkeletonError, match="does not exist"):
        skeleton_files([tmp_path / "nope"])


def test_pose_grid_of_a_10m_room_is_the_design_size():
    grid = PoseGrid.over_footprint((0.0, 0.0, 10.0, 10.0), torso_height=0.75, voxel_resolution=0.1)
    assert grid.shape == (3, 63, 100, 100) and grid.size == 1_890_000
    np.testing.assert_allclose(grid.z, [0.65, 0.75, 0.85])
    np.testing.assert_allclose(grid.theta, np.arange(63) * 0.1)
    np.testing.assert_allclose(grid.x[[0, -1]], [0.05, 9.95])


def test_pose_index_order_is_z_theta_x_y():
    grid = PoseGrid.over_footprint((0.0, 0.0, 0.5, 0.3), torso_height=1.0, voxel_resolution=0.1)
    nz, nt, nx, ny = grid.shape
    index = ((2 * nt + 5) * nx + 3) * ny + 1
    np.testing.assert_allclose(
        grid.poses(np.array([index]))[0], [grid.x[3], grid.y[1], grid.z[2], grid.theta[5]]
    )


def test_pose_grid_rejects_uneven_steps():
    with pytest.raises(ValueError, match="common step"):
        PoseGrid(np.array([0.05, 0.15, 0.35]), np.array([0.05]), np.array([1.0]), np.array([0.0]))


def test_settings_come_from_the_environment(monkeypatch):
    monkeypatch.setenv("AFFORD_VOXEL__RESOLUTION", "0.05")
    monkeypatch.setenv("AFFORD_GRAVITY__UP_CANDIDATES", '["+z"]')
    monkeypatch.setenv("AFFORD_FEATURES__DISTANCE_CAP", "0.5")
    monkeypatch.setenv("AFFORD_NORMALS__STEEP_FACING", "floor")
    settings = Settings()
    assert settings.voxel.resolution == 0.05 and settings.gravity.up_candidates == ["+z"]
    assert settings.features.distance_cap == 0.5 and settings.normals.steep_facing == "floor"
    layout = FeatureLayout.from_settings(settings)
    assert (layout.distance_cap, layout.steep_facing) == (0.5, "floor")
    assert layout.fingerprint != FeatureLayout(voxel_resolution=0.05, cell_size=0.25).fingerprint
    monkeypatch.setenv("AFFORD_FEATURES__DISTANCE_CAP", "none")  # the paper's untruncated distance
    assert Settings().features.distance_cap is None


def test_settings_refuse_a_grid_off_the_voxel_lattice(monkeypatch):
    monkeypatch.setenv("AFFORD_VOXEL__RESOLUTION", "0.03")
    with pytest.raises(ValueError, match="whole multiple"):
        Settings()


def test_builtin_skeleton_dir_is_inside_the_package():
    assert BUILTIN_DIR.is_dir() and shutil.os.path.commonpath([BUILTIN_DIR, PACKAGE]) == str(PACKAGE)


def test_model_files_name_built_in_skeletons_from_the_package_and_user_ones_by_their_path(tmp_path):
    built_in = get_skeleton("standing-working")
    assert Path(built_in.source).is_absolute()  # what `afford skeletons` shows stays the file on this machine
    assert built_in.portable_source == "affordcore/data/skeletons/standing-working.json"
    document = json.loads((BUILTIN_DIR / "standing-working.json").read_text())
    (tmp_path / "standing-working.json").write_text(json.dumps(document))
    user = get_skeleton("standing-working", [tmp_path])
    assert user.portable_source == user.source == str(tmp_path / "standing-working.json")
    # and the shipped models hold no path of the checkout that trained them
    for path in shipped_models().values():
        source = load_model(path).skeleton["source"]
        assert source == f"affordcore/data/skeletons/{path.name.removesuffix('.model.json')}.json"
