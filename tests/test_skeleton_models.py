"""Skeleton models derived from real Kinect skeletons: canonical frame, filters, and the shipped files.

The real-data tests read ../shared/data in place and skip without it; the rest use synthetic skeletons."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from affordcli.app import app
from affordcore.geometry.skeleton import BUILTIN_DIR, JOINTS, rotation_z
from affordcore.geometry.skeleton_models import (
    Frames,
    bone_lengths,
    canonicalise,
    derive,
    filter_masks,
    kinect_to_zup,
    leg_angles,
    load_frames,
    load_sources,
    reach,
    retarget,
    skeleton_json,
)

J = {name: i for i, name in enumerate(JOINTS)}
# README: seated thighs 55 to 78 degrees from vertical; 5 degrees of Kinect slack
SEATED_THIGH = (
    55 - 5,
    78 + 5,
)


def _skeleton(seated: bool) -> np.ndarray:
    """A symmetric synthetic adult in the skeleton frame (torso at the origin, facing +x, left +y)."""
    knee, foot = ([0.42, 0.1, -0.3], [0.5, 0.1, -0.7]) if seated else ([0.03, 0.1, -0.65], [0.0, 0.1, -1.05])
    joints = {
        "HEAD": [0.03, 0, 0.55],
        "NECK": [0.0, 0, 0.38],
        "TORSO": [0, 0, 0],
        "L_SHOULDER": [0, 0.19, 0.33],
        "L_ELBOW": [0.05, 0.22, 0.05],
        "L_HAND": [0.3, 0.15, -0.05],
        "L_HIP": [0, 0.1, -0.2],
        "L_KNEE": knee,
        "L_FOOT": foot,
    }
    for name in [n for n in joints if n.startswith("L_")]:
        joints["R_" + name[2:]] = [joints[name][0], -joints[name][1], joints[name][2]]
    return np.array([joints[name] for name in JOINTS], dtype=np.float64)


def _zup_to_kinect(joints: np.ndarray) -> np.ndarray:
    """The inverse of kinect_to_zup: Kinect camera frame, y up."""
    return np.stack([joints[..., 0], joints[..., 2], -joints[..., 1]], axis=-1)


def _frames(joints: np.ndarray, trial: str) -> Frames:
    n = len(joints)
    return Frames(
        joints,
        np.full(n, f"a09_s01_{trial}"),
        np.arange(n),
        np.full(n, "sit_still"),
        np.ones(n, int),
        np.full(n, trial),
        np.ones(n),
    )


@pytest.mark.parametrize("seated", [False, True])
def test_canonicalise_undoes_any_yaw_and_position_of_a_y_up_skeleton(seated):
    rng = np.random.default_rng(3)
    model = _skeleton(seated)
    yaw = rng.uniform(-np.pi, np.pi, 20)
    world = np.einsum("nij,kj->nki", rotation_z(yaw), model) + rng.uniform(-2, 2, (20, 1, 3))
    canonical = canonicalise(kinect_to_zup(_zup_to_kinect(world)))
    np.testing.assert_allclose(canonical, np.broadcast_to(model, canonical.shape), atol=1e-12)
    assert (canonical[:, [J["L_SHOULDER"], J["L_HIP"], J["L_HAND"]], 1] > 0).all()
    assert np.allclose(canonical[:, J["TORSO"]], 0)


def test_kinect_to_zup_is_a_proper_rotation():
    basis = kinect_to_zup(np.eye(3))
    assert np.isclose(np.linalg.det(basis), 1.0)
    np.testing.assert_allclose(kinect_to_zup(np.array([0.0, 1.0, 0.0])), [0, 0, 1])  # Kinect y up -> z up


def test_canonicalise_keeps_the_lean():
    leaning = (
        _skeleton(True)
        @ np.array([[np.cos(0.3), 0, -np.sin(0.3)], [0, 1, 0], [np.sin(0.3), 0, np.cos(0.3)]]).T
    )
    canonical = canonicalise(leaning[None])[0]
    np.testing.assert_allclose(canonical, leaning, atol=1e-12)


def test_filters_reject_swapped_knees_and_hips_and_broken_bones():
    trials = load_sources()["trials"]
    rng = np.random.default_rng(0)
    for seated, trial in [(True, "e01"), (False, "e02")]:
        joints = _skeleton(seated) + rng.normal(0, 0.005, (40, 15, 3))
        swapped, broken, missing = 5, 6, 7
        joints[swapped][[J["L_HIP"], J["L_KNEE"]]] = joints[swapped][[J["L_KNEE"], J["L_HIP"]]]
        joints[broken, J["R_HAND"]] += [0.3, 0, 0]  # forearm twice its length
        kinect = _zup_to_kinect(joints) + [0, 0, 2.5]
        kinect[missing, J["L_FOOT"]] = 0.0  # how Kinect reports a joint it lost
        masks = filter_masks(_frames(kinect_to_zup(kinect), trial), trials)
        passing = np.all(list(masks.values()), axis=0)
        assert set(np.flatnonzero(~passing)) == {swapped, broken, missing}
        assert not masks["leg angles"][swapped] and not masks["bone lengths"][broken]
        assert not masks["missing joints"][missing]


def test_filters_reject_knees_above_hips_when_seated():
    trials = load_sources()["trials"]
    # off the origin: (0, 0, 0) is "lost"
    joints = np.repeat(_skeleton(True)[None], 10, axis=0) + [
        1.0,
        2.0,
        0.5,
    ]
    joints[4, [J["L_KNEE"], J["R_KNEE"]], 2] = 0.4  # knees 0.1 m above the hips
    masks = filter_masks(_frames(joints, "e01"), trials)
    assert leg_angles(joints[4:5])["thigh"].min() > 90
    assert np.flatnonzero(~masks["leg angles"]).tolist() == [4]


def test_retarget_and_reach_keep_directions_and_bone_lengths():
    pose = _skeleton(False)
    lengths = bone_lengths(pose[None])[0] * 1.2
    body = retarget(pose, lengths)
    np.testing.assert_allclose(bone_lengths(body[None])[0][:-1], lengths[:-1])  # all but the hip-hip bone
    adapted, turns = reach(body, -0.1)
    np.testing.assert_allclose(bone_lengths(adapted[None]), bone_lengths(body[None]))
    hands = adapted[[J["L_HAND"], J["R_HAND"]]]
    np.testing.assert_allclose(hands[:, 2], -0.1)
    assert (hands[:, 0] > adapted[[J["L_ELBOW"], J["R_ELBOW"]], 0]).all()
    assert np.allclose(turns[0], turns[1]) and 0 < turns[0] < 90
    np.testing.assert_allclose(
        np.delete(adapted, [J["L_HAND"], J["R_HAND"]], 0), np.delete(body, [J["L_HAND"], J["R_HAND"]], 0)
    )
    with pytest.raises(ValueError, match="cannot reach"):
        reach(body, -0.9)


def test_show_draws_the_shipped_skeletons(tmp_path):
    result = CliRunner().invoke(app, ["skeletons", "show", "--out", str(tmp_path / "s.png")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "s.png").read_bytes()[:4] == b"\x89PNG"


def test_derive_without_the_data_is_a_clear_error(tmp_path):
    result = CliRunner().invoke(
        app, ["skeletons", "derive", "--data", str(tmp_path / "none.npz"), "--out", str(tmp_path)]
    )
    assert result.exit_code == 2 and "not found" in result.output


# --- real data ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def data_file(shared_data: Path) -> Path:
    return shared_data / load_sources()["data_file"]


@pytest.fixture(scope="module")
def derived(data_file):
    return derive(data_file)


def test_derivation_reproduces_the_shipped_files(derived):
    assert [s.affordance for s in derived.skeletons] == sorted(p.stem for p in BUILTIN_DIR.glob("*.json"))
    for skeleton in derived.skeletons:
        assert skeleton_json(skeleton) == (BUILTIN_DIR / f"{skeleton.affordance}.json").read_text(), (
            skeleton.affordance
        )


def test_cli_derive_is_deterministic(data_file, tmp_path):
    result = CliRunner().invoke(
        app,
        [
            "skeletons",
            "derive",
            "--data",
            str(data_file),
            "--out",
            str(tmp_path),
            "--png",
            str(tmp_path / "models.png"),
        ],
    )
    assert result.exit_code == 0, result.output
    assert "bone lengths" in result.output and "K=" in result.output
    for shipped in BUILTIN_DIR.glob("*.json"):
        assert (tmp_path / shipped.name).read_text() == shipped.read_text()
    assert (tmp_path / "models.png").stat().st_size > 10_000


def test_filter_and_cluster_report_is_consistent(derived):
    table = derived.filters
    for group, loaded in table["loaded"].items():
        removed = sum(row[group] for name, row in table.items() if name not in ("loaded", "kept"))
        assert loaded - removed == table["kept"][group] > 0
    for name, info in derived.clusters.items():
        assert sum(info["sizes"]) == info["frames"] == table["kept"][name]
        assert len(derived.members[name]) == info["sizes"][info["chosen"]]
    # README: median standing head-to-foot 1.35 m, short for an adult
    assert 1.1 < derived.scale["factor"] < 1.3


def test_kinect_left_ends_up_at_plus_y_facing_plus_x(data_file):
    """Handedness on real frames: seated people's knees point forward (+x) once their left is +y."""
    frames = load_frames(data_file, {"sit_still"}, {"e01"})
    canonical = canonicalise(kinect_to_zup(frames.joints))
    knees_forward = canonical[:, [J["L_KNEE"], J["R_KNEE"]], 0] - canonical[:, [J["L_HIP"], J["R_HIP"]], 0]
    assert np.median(knees_forward) > 0.2


def test_derived_models_are_plausible(derived):
    models = {s.affordance: s for s in derived.skeletons}
    for skeleton in models.values():
        feet = skeleton.torso_height + skeleton.joints[[J["L_FOOT"], J["R_FOOT"]], 2]
        assert 0.0 <= feet.min() <= 0.1, skeleton.affordance
        assert (skeleton.joints[:, 2] + skeleton.torso_height >= 0).all()
    standing = models["standing-working"]
    for name in ("sitting-relaxing", "sitting-working"):
        assert models[name].torso_height < standing.torso_height - 0.3
        thighs = leg_angles(models[name].joints[None])["thigh"]
        assert ((thighs >= SEATED_THIGH[0]) & (thighs <= SEATED_THIGH[1])).all(), (name, thighs)
    assert abs(leg_angles(standing.joints[None])["thigh"]).max() < 15
    hands = standing.joints[[J["L_HAND"], J["R_HAND"]]]
    assert ((hands[:, 2] + standing.torso_height > 0.85) & (hands[:, 2] + standing.torso_height < 1.05)).all()
    assert (hands[:, 0] > 0.2).all()
    # a real cluster nearly fits a bench
    assert max(derived.clusters["standing-working"]["forearm_turns"]) < 30
    head = standing.torso_height + standing.joints[J["HEAD"], 2]
    assert 1.55 < head < 1.70  # head centre of a 1.75 m adult


def test_shipped_files_name_their_source():
    for path in BUILTIN_DIR.glob("*.json"):
        source = json.loads(path.read_text())["source"]
        assert "MSR DailyActivity3D" in source and "K-means cluster" in source and "filtered frames" in source
