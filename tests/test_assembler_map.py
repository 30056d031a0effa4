"""The assembler's global map: per voxel the mean of every observation, and no depth-edge blocks.

A noisy synthetic depth walk through a furnished room (Kinect v1 noise, depth steps and flying pixels) with
its true poses: the map's floor is flatter than a map of one observation per voxel (the map before), and the
points that hang in mid-air between a foreground edge and what lies behind it stay out of it."""

from __future__ import annotations

import numpy as np
import pytest

from affordcore.assembly.assembler import Assembler, SensorFrame, within_range
from affordcore.assembly.depth import DepthImage, back_project
from affordcore.assembly.voxelmap import VoxelMeans
from affordcore.geometry.fields import voxel_down_sample
from affordcore.settings import AssemblerSettings
from affordcore.synth.scanner import DepthCamera, Raycaster, depth_frame, look_at
from affordcore.synth.shapes import Box

ROOM = [
    Box.span((-3, -2.5, -0.1), (3, 2.5, 0)),  # floor slab
    Box.span((-3.1, -2.5, 0), (-3, 2.5, 2.6)),
    Box.span((3, -2.5, 0), (3.1, 2.5, 2.6)),
    Box.span((-3, 2.5, 0), (3, 2.6, 2.6)),
    Box.span((-0.6, 0.6, 0.70), (0.6, 1.4, 0.75)),  # a table top on two legs: edges over the floor
    Box.span((-0.55, 0.65, 0), (-0.5, 0.7, 0.7)),
    Box.span((0.5, 1.3, 0), (0.55, 1.35, 0.7)),
    Box.span((1.5, 1.8, 0), (2.5, 2.5, 0.9)),  # a counter
]
CAMERA = DepthCamera().with_kinect_noise()  # with flying pixels at depth edges


@pytest.fixture(scope="module")
def walk():
    """(depth images, true camera-to-world poses): 16 frames of a camera 1.4 m up, 2 m from the table,
    stepping 4 cm and turning 1.5 degrees a frame, pitched 30 degrees down."""
    raycaster, rng = Raycaster(ROOM), np.random.default_rng(3)
    images, poses = [], []
    for k in range(16):
        eye = np.array([-1.2 + 0.04 * k, -1.4, 1.4])
        yaw, pitch = np.radians(60 + 1.5 * k), np.radians(-30)
        forward = [np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), np.sin(pitch)]
        poses.append(look_at(eye, eye + forward))
        depth, _ = depth_frame(raycaster, CAMERA, poses[-1], rng)
        images.append(DepthImage(np.round(depth * 1000).astype(np.uint16), CAMERA.intrinsics))
    return images, poses


def _world(points: np.ndarray, first: np.ndarray) -> np.ndarray:
    return points @ first[:3, :3].T + first[:3, 3]


def _open_floor(points: np.ndarray) -> np.ndarray:
    """The heights of the points on the floor away from the furniture and walls."""
    away = (np.abs(points[:, 0]) < 2.5) & (points[:, 1] > -2.0) & (points[:, 1] < 0.4)
    return points[away & (np.abs(points[:, 2]) < 0.1), 2]


def test_voxel_means_are_the_mean_of_every_point_and_replay_from_cell_means():
    rng = np.random.default_rng(0)
    batches = [rng.uniform(-1, 1, (30_000, 3)) * [1, 1, 0.05] for _ in range(8)]  # merges along the way
    means = VoxelMeans(0.02)
    for batch in batches:
        means.add_points(batch)
    expected = voxel_down_sample(np.vstack(batches), 0.02)  # the mean per cell, sorted by cell
    np.testing.assert_allclose(means.point_cloud(), expected, atol=1e-12)
    assert means.counts().sum() == 8 * 30_000
    replayed = VoxelMeans(0.02)  # a journal holds each frame's cell means and their counts
    for batch in batches:
        cells = VoxelMeans(0.02)
        cells.add_points(batch)
        replayed.add_points(cells.point_cloud(), cells.counts())
    np.testing.assert_allclose(replayed.point_cloud(), expected, atol=1e-12)
    np.testing.assert_array_equal(replayed.counts(), means.counts())


def test_blocks_across_a_depth_edge_are_left_out(walk):
    """Flying pixels at the table's edges average into blocks in mid-air; `max_spread` drops those blocks
    and next to nothing else."""
    images, poses = walk
    surfaces = Raycaster(ROOM)

    def in_mid_air(points: np.ndarray, pose: np.ndarray) -> int:
        """Points more than 5 cm off the first surface along their own ray (in front of it or behind)."""
        rays = _world(points, pose) - pose[:3, 3]
        hit, _, _ = surfaces.cast(np.broadcast_to(pose[:3, 3], rays.shape), rays)  # in units of the ray
        off = np.abs(hit - 1) * np.linalg.norm(rays, axis=1)
        return int(np.sum(np.isfinite(off) & (off > 0.05)))

    every = [back_project(image, 2, 0.3, 4.0) for image in images]
    kept = [back_project(image, 2, 0.3, 4.0, max_spread=0.05) for image in images]
    before = sum(in_mid_air(points, pose) for points, pose in zip(every, poses))
    after = sum(in_mid_air(points, pose) for points, pose in zip(kept, poses))
    assert before > 200 and after < before / 4, (before, after)
    assert sum(map(len, kept)) > 0.95 * sum(map(len, every))


def test_the_map_of_a_noisy_walk_is_flatter_than_one_observation_per_voxel(walk):
    """The same frames at their true poses: the map the assembler makes of its keyframes (running means of
    the blocks, less those across depth edges) against a map of the first point per voxel.
    Quantised Kinect depth repeats its steps from similar viewpoints, so 16 looks average out a third of the
    floor's spread, not three quarters."""
    from kiss_icp.mapping import VoxelHashMap
    from kiss_icp.voxelization import voxel_down_sample as first_point

    images, poses = walk
    settings = AssemblerSettings()
    now = VoxelMeans(settings.map_voxel)
    before = VoxelHashMap(settings.map_voxel, max_distance=np.inf, max_points_per_voxel=1)
    low, high = settings.min_range, settings.max_range
    for image, pose in zip(images, poses):
        now.add_points(_world(back_project(image, 2, low, high, max_spread=settings.map_edge_spread), pose))
        before.add_points(_world(first_point(back_project(image, 2, low, high), settings.map_voxel), pose))
    flat_now, flat_before = _open_floor(now.point_cloud()), _open_floor(before.point_cloud())
    assert len(flat_now) > 3000 and len(flat_before) > 3000
    assert np.std(flat_now) < 0.75 * np.std(flat_before), (np.std(flat_now), np.std(flat_before))


def test_the_assembler_map_is_the_running_mean_of_its_keyframes(walk):
    """What `Assembler.add` puts in the map: each keyframe's edge-filtered blocks within range, at its
    registered pose."""
    images, _ = walk
    settings = AssemblerSettings()
    assembler = Assembler(settings)
    expected = VoxelMeans(settings.map_voxel)
    for k, image in enumerate(images):
        record = assembler.add(SensorFrame("camera", k / 10, depth=image), k / 10)
        if record.map_points is not None:
            blocks = back_project(
                image, 2, settings.min_range, settings.max_range, max_spread=settings.map_edge_spread
            )
            expected.add_points(_world(within_range(blocks, settings), record.pose))
    assert assembler.keyframes > 3
    np.testing.assert_allclose(assembler.map_points(), expected.point_cloud(), atol=1e-9)


def _floor_tilt_deg(points: np.ndarray) -> float:
    """The tilt of the plane fitted (least squares) to the points near z = 0, refitted to those within 2 cm
    of it (a wall's foot leaves)."""
    floor, plane = points[np.abs(points[:, 2]) < 0.2], np.zeros(3)
    for _ in range(5):
        design = np.column_stack([floor[:, :2], np.ones(len(floor))])
        plane, *_ = np.linalg.lstsq(design, floor[:, 2], rcond=None)
        near = points[
            np.abs(points[:, 2] - np.column_stack([points[:, :2], np.ones(len(points))]) @ plane) < 0.02
        ]
        floor = near[np.abs(near[:, 2]) < 0.2]
    return float(np.degrees(np.arctan(np.hypot(*plane[:2]))))


@pytest.mark.parametrize("limit, levelled", [(5.0, True), (0.0, False)])
def test_the_map_is_levelled_on_its_floor_when_the_gravity_is_a_few_degrees_off(walk, limit, levelled):
    """An IMU 3 degrees off: the map is levelled on its floor plane (with `floor_level_max_deg` 0, on the
    IMU's gravity alone: the floor then leans 3 degrees)."""
    images, poses = walk
    tilt = np.radians(3.0)
    wrong_down = np.array([0.0, np.sin(tilt), -np.cos(tilt)])  # the world's down turned 3 deg about x
    assembler = Assembler(AssemblerSettings(floor_level_max_deg=limit))
    for k, (image, pose) in enumerate(zip(images, poses)):
        gravity = pose[:3, :3].T @ wrong_down
        assembler.add(SensorFrame("camera", k / 10, depth=image, gravity=gravity), k / 10)
    points, _ = assembler.aligned_map()
    if levelled:
        assert _floor_tilt_deg(points) < 0.5
    else:
        assert 2.5 < _floor_tilt_deg(points) < 3.5
