"""The services level what they are given, as a client in any language sends it: a room in its own frame (y
up, floor off the origin) comes back with the same maps as the levelled room; a 'world' cloud whose floor is
not at z = 0 is refused with the reason, never answered with empty maps; and `afford watch` waits for the
maps of the newest cloud, never returning an older cloud's."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from affordcore.example import example_room
from affordwire import messages
from services.clients import publish_map
from services.launch import Stack
from services.transport import Keys

pytestmark = pytest.mark.slow
AFFORD = [sys.executable, "-m", "affordcli"]
AFFORDANCES = ("sitting-relaxing", "sitting-working", "standing-working")


def _watch(stack: Stack, *args: str) -> subprocess.CompletedProcess:
    command = ["watch", "--connect", stack.endpoint, "--robot", stack.robot, "--timeout", "240", "-q", *args]
    return subprocess.run(AFFORD + command, capture_output=True, text=True, timeout=300)


def _places(folder) -> dict[str, tuple]:
    """Per affordance: (k, 5) rows x, y, z, theta, score of the skeleton map, the same of its positive poses,
    and its world_from_input."""
    places = {}
    for name in AFFORDANCES:
        document = json.loads((folder / f"{name}.json").read_text())
        fields = ("x", "y", "z", "theta", "score")
        rows, positives = (
            np.array([[s[k] for k in fields] for s in document[key]]).reshape(-1, 5)
            for key in ("skeletons", "positives")
        )
        places[name] = (rows, positives, np.array(document["world_from_input"]))
    return places


def _near(places: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Per place: whether a pose lies within a grid step of it in plan, at its height, facing within two
    steps."""
    plan = np.linalg.norm(places[:, None, :2] - poses[None, :, :2], axis=2) < 0.11
    height = np.abs(places[:, None, 2] - poses[None, :, 2]) < 0.05
    facing = np.abs(np.angle(np.exp(1j * (places[:, None, 3] - poses[None, :, 3])))) < 0.21
    return (plan & height & facing).any(axis=1)


def _in_plan(rows: np.ndarray, transform: np.ndarray) -> np.ndarray:
    """Places moved by a transform about z (x, y and the facing change; height and score do not)."""
    moved = rows.copy()
    moved[:, :3] = rows[:, :3] @ transform[:3, :3].T + transform[:3, 3]
    moved[:, 3] = rows[:, 3] + np.arctan2(transform[1, 0], transform[0, 0])
    return moved


def test_an_unlevelled_room_gives_the_maps_of_the_levelled_one_and_a_bad_world_cloud_is_refused(tmp_path):
    room = example_room().points
    # y up, the floor 1.1 m under the frame's origin. Levelling finds up and the floor, not the heading: the
    # room keeps its turn about z and its place in plan, and the maps on a square grid depend on the turn (a
    # room turned 30 deg is voxelised differently), so the frame differs from the world by whole cells in plan
    camera_from_world = np.eye(4)
    camera_from_world[:3, :3] = Rotation.from_euler("x", -90, degrees=True).as_matrix()
    camera_from_world[:3, 3] = [0.4, 1.1, -2.0]
    keys = Keys("levelbot")

    with Stack(tmp_path / "run", robot="levelbot") as stack:
        session = stack.session()
        try:
            levelled = messages.cloud_message(room, np.eye(4), "example")
            publish_map(session, keys, levelled, wait=30)
            stamp = f"{levelled.timestamp.seconds}.{levelled.timestamp.nanos:09d}"
            first = _watch(stack, "--since", stamp, "--out", str(tmp_path / "levelled"))
            assert first.returncode == 0, first.stdout + first.stderr + stack.logs()

            unlevelled = messages.cloud_message(
                room @ camera_from_world[:3, :3].T + camera_from_world[:3, 3], np.eye(4), "example"
            )
            unlevelled.frame_id = "camera"
            publish_map(session, keys, unlevelled, wait=30)
            second = _watch(stack, "--out", str(tmp_path / "unlevelled"))  # the newest cloud's, not the first
            assert second.returncode == 0, second.stdout + second.stderr + stack.logs()

            raised = messages.cloud_message(room + [0.0, 0.0, 0.8], np.eye(4), "example")
            publish_map(session, keys, raised, wait=30)
            started = time.monotonic()
            stamp = (
                f"{raised.timestamp.seconds}.{raised.timestamp.nanos:09d}"  # as publish --as-map prints it
            )
            third = _watch(stack, "--since", stamp, "--out", str(tmp_path / "raised"))
            waited = time.monotonic() - started
        finally:
            session.close()

    levelled_places, unlevelled_places = _places(tmp_path / "levelled"), _places(tmp_path / "unlevelled")
    # The levelling's fitted floor is a hair off the exact one: points near a cell's boundary cross it, and
    # scores move a little. The positive poses stay; where places sit along a counter of near-equal scores,
    # which peaks the non-maximum suppression keeps may not, so places are checked against the positives.
    for name in AFFORDANCES:
        rows, positives, world_from_input = levelled_places[name]
        assert np.allclose(world_from_input, np.eye(4)), "a levelled cloud keeps its frame"
        got, got_positives, world_from_camera = unlevelled_places[name]
        # the levelled room's world to the unlevelled room's: a turn about z and a shift in plan only
        plan = world_from_camera @ camera_from_world
        assert np.allclose(plan[2], [0, 0, 1, 0], atol=0.01), plan
        expected, expected_positives = _in_plan(rows, plan), _in_plan(positives, plan)
        assert abs(len(got) - len(expected)) <= 1, f"{name}: {len(got)} places, levelled {len(expected)}"
        assert _near(got, expected_positives).all() and _near(expected, got_positives).all(), name
        # the positive poses agree, pose by pose (a step in plan, two in facing)
        assert _near(got_positives, expected_positives).mean() > 0.95, name
        assert _near(expected_positives, got_positives).mean() > 0.95, name
    assert sum(len(rows) for rows, *_ in levelled_places.values()) >= 3, "the room has places to compare"

    assert third.returncode == 1, third.stdout + third.stderr
    assert "refused the cloud: a 'world' cloud has its floor at z = 0" in third.stderr
    assert not (tmp_path / "raised").exists(), "no map of an older cloud was taken for the refused one's"
    assert waited < 30, f"the refusal took {waited:.0f} s to report"
