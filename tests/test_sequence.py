"""affordcore.assembly.sequence: recorded sequences on disk (7-Scenes depth frames, LiDAR scans) and the
folders that
are not."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import SHARED_DATA
from PIL import Image

from affordcore.assembly.depth import back_project
from affordcore.assembly.sequence import DEPTH_SCALE, INVALID_DEPTH, SequenceError, read_sequence
from affordwire import messages

K = np.array([[585.0, 0.0, 320.0], [0.0, 585.0, 240.0], [0.0, 0.0, 1.0]])
SEVEN_SCENES = SHARED_DATA / "sequences" / "7scenes_redkitchen_frames_000000-000299"


def _write_depth(path: Path, depth: np.ndarray) -> None:
    Image.fromarray(depth.astype(np.uint16)).save(path)


def _pose(index: int) -> np.ndarray:
    pose = np.eye(4)
    angle = 0.1 * (index + 1)
    pose[:3, :3] = [[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]]
    pose[:3, 3] = [0.5 * index, -0.25, 1.2]
    return pose


def _depth_folder(folder: Path, indices=(0, 1, 2), poses=True, intrinsics=K) -> dict[int, np.ndarray]:
    """Frames in the 7-Scenes layout, written out of order; returns {index: depth image}."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    images = {}
    for index in reversed(indices):
        depth = rng.integers(400, 4500, size=(12, 16)).astype(np.uint16)
        depth[0, :3] = 0
        depth[5, 7] = INVALID_DEPTH
        _write_depth(folder / f"frame-{index:06d}.depth.png", depth)
        if poses:
            np.savetxt(folder / f"frame-{index:06d}.pose.txt", _pose(index))
        (folder / f"frame-{index:06d}.color.jpg").write_bytes(b"not read")
        images[index] = depth
    if intrinsics is not None:
        np.savetxt(folder / "camera-intrinsics.txt", intrinsics)
    return images


def test_a_7scenes_folder_reads_back(tmp_path):
    images = _depth_folder(tmp_path / "seq", indices=(10, 2, 0))
    sequence = read_sequence(tmp_path / "seq")
    assert sequence.kind == "depth" and sequence.folder == tmp_path / "seq"
    assert [path.name for path in sequence.frames] == [
        "frame-000000.depth.png",
        "frame-000002.depth.png",
        "frame-000010.depth.png",
    ]
    np.testing.assert_array_equal(sequence.intrinsics, K)
    for position, index in enumerate((0, 2, 10)):
        depth = sequence.depth(position)
        assert depth.dtype == np.uint16 and depth.shape == (12, 16)
        np.testing.assert_array_equal(depth, images[index])
        np.testing.assert_allclose(sequence.pose(position), _pose(index), atol=1e-12)


def test_a_sequence_frame_becomes_a_depth_frame_message(tmp_path):
    images = _depth_folder(tmp_path / "seq", indices=(0,))
    sequence = read_sequence(tmp_path / "seq")
    frame = messages.depth_frame_message(
        sequence.depth(0), sequence.intrinsics, depth_scale=DEPTH_SCALE, invalid_value=INVALID_DEPTH
    )
    points = back_project(messages.depth_image(frame))
    valid = (images[0] != 0) & (images[0] != INVALID_DEPTH)
    assert len(points) == valid.sum() == 12 * 16 - 4
    np.testing.assert_allclose(np.sort(points[:, 2]), np.sort(images[0][valid] * 0.001))


def test_odometry_beside_a_frame_is_its_pose_guess_on_the_wire(tmp_path):
    from services.clients import sequence_messages

    _depth_folder(tmp_path / "seq", indices=(0, 1, 2))
    guess = _pose(5)  # any frame of the robot's own: only its motion is used
    np.savetxt(tmp_path / "seq" / "frame-000001.odometry.txt", guess)
    sequence = read_sequence(tmp_path / "seq")
    assert sequence.odometry(0) is None and not sequence.has_odometry()
    np.testing.assert_allclose(sequence.odometry(1), guess, atol=1e-12)
    sent = dict(sequence_messages(sequence, [0, 1]))
    assert not sent[0].HasField("pose_guess")
    np.testing.assert_allclose(messages.pose_matrix(sent[1].pose_guess), guess, atol=1e-9)
    assert sent[1].pose_guess.child_frame_id == sent[1].frame_id == "camera"
    without = dict(sequence_messages(sequence, [1], with_odometry=False))
    assert not without[1].HasField("pose_guess")


@pytest.mark.parametrize("text", ["1 2 3\n4 5 6\n", "nan " * 16, "not a number"])
def test_odometry_that_is_no_pose_is_refused_with_the_file_named(tmp_path, text):
    _depth_folder(tmp_path / "seq", indices=(0,))
    (tmp_path / "seq" / "frame-000000.odometry.txt").write_text(text)
    with pytest.raises(SequenceError, match=r"frame-000000\.odometry\.txt"):
        read_sequence(tmp_path / "seq").odometry(0)


def test_frames_without_poses_have_none(tmp_path):
    _depth_folder(tmp_path / "seq", poses=False)
    sequence = read_sequence(tmp_path / "seq")
    assert len(sequence.frames) == 3 and sequence.pose(0) is None and sequence.pose(2) is None


def test_a_lidar_folder_reads_back(tmp_path):
    rng = np.random.default_rng(1)
    scans = {index: rng.normal(scale=10.0, size=(50 + index, 3)).astype("<f4") for index in (3, 0, 1)}
    for index, points in scans.items():
        points.tofile(tmp_path / f"scan-{index:06d}.bin")
    np.savetxt(tmp_path / "scan-000001.pose.txt", _pose(1))
    sequence = read_sequence(tmp_path)
    assert sequence.kind == "lidar" and sequence.intrinsics is None
    assert [path.name for path in sequence.frames] == [
        "scan-000000.bin",
        "scan-000001.bin",
        "scan-000003.bin",
    ]
    for position, index in enumerate((0, 1, 3)):
        points = sequence.scan(position)
        assert points.dtype == np.float64 and points.shape == (50 + index, 3)
        np.testing.assert_array_equal(points, scans[index].astype(np.float64))
    assert sequence.pose(0) is None
    np.testing.assert_allclose(sequence.pose(1), _pose(1), atol=1e-12)


def test_depth_frames_win_over_scans_in_one_folder(tmp_path):
    _depth_folder(tmp_path, indices=(0,))
    np.zeros((4, 3), dtype="<f4").tofile(tmp_path / "scan-000000.bin")
    sequence = read_sequence(tmp_path)
    assert sequence.kind == "depth" and len(sequence.frames) == 1


# -- folders that are not sequences --------------------------------------------------------------------------


def test_not_a_folder(tmp_path):
    with pytest.raises(SequenceError, match=r"missing: not a folder"):
        read_sequence(tmp_path / "missing")
    (tmp_path / "file.bin").write_bytes(b"\x00" * 12)
    with pytest.raises(SequenceError, match=r"file\.bin: not a folder"):
        read_sequence(tmp_path / "file.bin")


def test_a_folder_without_frames(tmp_path):
    (tmp_path / "frame-000000.color.jpg").write_bytes(b"colour only")
    (tmp_path / "scan-000000.las").write_bytes(b"another format")
    np.savetxt(tmp_path / "camera-intrinsics.txt", K)
    with pytest.raises(
        SequenceError, match=rf"{tmp_path.name}: no frame-NNNNNN\.depth\.png .* \.ply or \.pcd files"
    ):
        read_sequence(tmp_path)


def test_depth_frames_without_intrinsics(tmp_path):
    _depth_folder(tmp_path, intrinsics=None)
    with pytest.raises(SequenceError, match=r"depth frames without camera-intrinsics\.txt"):
        read_sequence(tmp_path)


@pytest.mark.parametrize(
    "intrinsics",
    [
        np.eye(2),
        np.array([585.0, 585.0, 320.0, 240.0]),
        np.vstack([K, K[:1]]),
        np.diag([0.0, 585.0, 1.0]),
        np.diag([-585.0, 585.0, 1.0]),
    ],
    ids=["2 x 2", "one row", "4 x 3", "fx 0", "fx negative"],
)
def test_bad_intrinsics(tmp_path, intrinsics):
    _depth_folder(tmp_path, intrinsics=intrinsics)
    with pytest.raises(
        SequenceError, match=r"camera-intrinsics\.txt: expected a 3 x 3 pinhole matrix with fx > 0"
    ):
        read_sequence(tmp_path)


def test_unreadable_intrinsics_name_the_file(tmp_path):
    _depth_folder(tmp_path, intrinsics=None)
    (tmp_path / "camera-intrinsics.txt").write_text("fx fy cx cy\n585 585 320 240\n")
    with pytest.raises(SequenceError, match=r"camera-intrinsics\.txt"):
        read_sequence(tmp_path)


def test_a_depth_frame_that_is_not_16_bit(tmp_path):
    _depth_folder(tmp_path, indices=(0,))
    Image.fromarray(np.full((12, 16), 200, dtype=np.uint8)).save(tmp_path / "frame-000000.depth.png")
    sequence = read_sequence(tmp_path)
    with pytest.raises(SequenceError, match=r"frame-000000\.depth\.png: not a 16-bit depth image \(uint8"):
        sequence.depth(0)


@pytest.mark.parametrize("floats", [1, 4, 3 * 20 + 2])
def test_a_scan_that_is_not_whole_points(tmp_path, floats):
    np.arange(floats, dtype="<f4").tofile(tmp_path / "scan-000000.bin")
    sequence = read_sequence(tmp_path)
    with pytest.raises(
        SequenceError,
        match=rf"scan-000000\.bin: {4 * floats} bytes is not a whole number of float32 x, y, z points",
    ):
        sequence.scan(0)


def test_a_scan_with_a_partial_float_is_refused(tmp_path):
    (tmp_path / "scan-000000.bin").write_bytes(np.ones(3, dtype="<f4").tobytes() + b"\x00")
    sequence = read_sequence(tmp_path)
    with pytest.raises(SequenceError):
        sequence.scan(0)


# -- the real 7-Scenes frames --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def seven_scenes():
    if not SEVEN_SCENES.is_dir():
        pytest.skip(f"shared 7-Scenes frames not available at {SEVEN_SCENES}")
    return read_sequence(SEVEN_SCENES)


def test_the_real_7scenes_sequence_reads(seven_scenes):
    assert seven_scenes.kind == "depth" and len(seven_scenes.frames) == 300
    assert (
        seven_scenes.frames[0].name == "frame-000000.depth.png"
        and seven_scenes.frames[-1].name == "frame-000299.depth.png"
    )
    k = seven_scenes.intrinsics
    assert k[0, 0] == 585 and k[1, 1] == 585 and (k[0, 2], k[1, 2]) == (320, 240)
    pose = seven_scenes.pose(0)
    # rigid (to the ground truth's 1e-4)
    np.testing.assert_allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3), atol=1e-3)
    np.testing.assert_array_equal(pose[3], [0, 0, 0, 1])


def test_the_real_frame_0_back_projects_within_the_kinect_range(seven_scenes):
    depth = seven_scenes.depth(0)
    assert depth.dtype == np.uint16 and depth.shape == (480, 640)
    frame = messages.depth_frame_message(
        depth, seven_scenes.intrinsics, DEPTH_SCALE, invalid_value=INVALID_DEPTH
    )
    points = back_project(messages.depth_image(frame))
    valid = (depth != 0) & (depth != INVALID_DEPTH)
    assert len(points) == valid.sum() > 0.5 * depth.size
    assert points[:, 2].min() >= 0.3 and points[:, 2].max() <= 5.0
    # the view spans the pinhole's field of view: x / z reaches about +-320 / 585 at the image edges
    slope = points[:, 0] / points[:, 2]
    assert slope.min() >= -320 / 585 - 1e-9 and slope.max() <= 319 / 585 + 1e-9
    assert slope.min() < -0.4 and slope.max() > 0.4
