"""Registration weighted by odometry (affordcore.assembly.planes): the geometry decides the directions it
constrains, the odometry's prior the ones it does not; and on a generated walk with wheel odometry the
assembler stays on the true path, where KISS-ICP's point-to-point registration from the same odometry
drifts."""

from __future__ import annotations

import numpy as np
import pytest

from affordcore.assembly.assembler import Assembler, SensorFrame, trajectory_errors
from affordcore.assembly.depth import DepthImage
from affordcore.assembly.planes import LocalPlanes, align_with_prior, odometry_information
from affordcore.assembly.sequence import read_sequence
from affordcore.settings import AssemblerSettings


class _Map:
    """What LocalPlanes reads of KISS-ICP's local map."""

    def __init__(self, points: np.ndarray):
        self.points = points

    def point_cloud(self) -> np.ndarray:
        return self.points


def _corridor(rng: np.random.Generator, spacing: float) -> np.ndarray:
    """A floor and two walls 2 m apart along x, sampled at random every `spacing` or so: nothing in it says
    where along x one stands."""
    count = int(4.0 * 2.0 / spacing**2)
    floor = np.column_stack([rng.uniform(-2, 2, count), rng.uniform(-1, 1, count), np.zeros(count)])
    walls = [
        np.column_stack([rng.uniform(-2, 2, count), np.full(count, side), rng.uniform(0, 2, count)])
        for side in (-1.0, 1.0)
    ]
    return np.concatenate([floor, *walls])


def _pose(x: float, y: float, z: float, yaw_deg: float = 0.0) -> np.ndarray:
    angle = np.radians(yaw_deg)
    pose = np.eye(4)
    pose[:2, :2] = [[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]]
    pose[:3, 3] = x, y, z
    return pose


@pytest.fixture
def corridor():
    rng = np.random.default_rng(3)
    planes = LocalPlanes()
    planes.refresh(_Map(_corridor(rng, 0.02)), frame=0)
    truth = _pose(0.1, 0.2, 1.0, yaw_deg=4.0)
    world = _corridor(rng, 0.06)
    source = (world - truth[:3, 3]) @ truth[:3, :3]  # the sensor's view: sensor_from_world
    return planes, truth, source


def test_the_geometry_corrects_what_it_constrains_and_the_prior_keeps_the_rest(corridor):
    planes, truth, source = corridor
    prior = truth @ _pose(0.05, -0.04, 0.03, yaw_deg=-1.0)  # off along, across and above the corridor
    information = np.diag([np.radians(2.0) ** -2] * 3 + [0.01**-2] * 3)
    pose = align_with_prior(source, prior, information, planes, reach=0.15, noise=0.02)
    error = pose[:3, 3] - truth[:3, 3]
    prior_along = prior[0, 3] - truth[0, 3]
    assert abs(error[0] - prior_along) < 0.003  # along the corridor only the odometry says where
    assert abs(error[1]) < 0.003 and abs(error[2]) < 0.003  # the walls and the floor correct the rest
    yaw = np.degrees(np.arctan2(pose[1, 0], pose[0, 0]))
    assert abs(yaw - 4.0) < 0.2  # and the walls the turn


def test_a_confident_prior_outweighs_the_planes_and_a_vague_one_does_not(corridor):
    planes, truth, source = corridor
    prior = truth @ _pose(0.0, 0.03, 0.0)  # 3 cm across the corridor
    sure = align_with_prior(source, prior, np.eye(6) * 1e12, planes, reach=0.15, noise=0.02)
    vague = align_with_prior(source, prior, np.eye(6) * 1e-2, planes, reach=0.15, noise=0.02)
    assert np.allclose(sure, prior, atol=1e-4)
    assert abs(vague[1, 3] - truth[1, 3]) < 0.003


def test_with_no_plane_in_reach_the_prior_is_the_answer(corridor):
    planes, _, source = corridor
    far = _pose(0.0, 0.0, 50.0)
    pose = align_with_prior(source, far, np.eye(6), planes, reach=0.15, noise=0.02)
    assert np.allclose(pose, far)


def test_the_odometry_error_grows_with_the_step_from_a_least_error():
    still = odometry_information(np.eye(4), 0.05, 0.002, 0.1)
    step = _pose(0.4, 0.0, 0.0, yaw_deg=20.0)
    moving = odometry_information(step, 0.05, 0.002, 0.1)
    assert np.allclose(np.diag(still), [np.radians(0.1) ** -2] * 3 + [0.002**-2] * 3)
    assert np.allclose(np.diag(moving), [(0.05 * np.radians(20.0)) ** -2] * 3 + [0.02**-2] * 3)


def _walk_errors(folder, settings: AssemblerSettings) -> dict[str, float]:
    """The assembler's trajectory error over every third frame of a sequence, given its odometry."""
    sequence, assembler = read_sequence(folder), Assembler(settings)
    indices = list(range(0, len(sequence.frames), 3))
    for index in indices:
        depth = DepthImage(sequence.depth(index), sequence.intrinsics)
        frame = SensorFrame(
            "camera",
            index / 30,
            depth=depth,
            gravity=sequence.gravity(index),
            pose_guess=sequence.odometry(index),
        )
        assembler.add(frame, index / 30)
    return trajectory_errors(list(assembler.trajectory.poses), [sequence.pose(i) for i in indices])


def test_odometry_as_a_prior_keeps_a_generated_walk_on_its_path(generated_sequence):
    """KISS-ICP from the same odometry slides along the room's flat surfaces (docs/services.md)."""
    with_prior = _walk_errors(generated_sequence, AssemblerSettings())
    point_to_point = _walk_errors(generated_sequence, AssemblerSettings(odometry_prior=False))
    assert with_prior["worst_m"] < 0.03 < point_to_point["worst_m"]
