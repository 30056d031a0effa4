"""Recorded sensor sequences on disk: a folder of depth frames in the 7-Scenes layout, or of LiDAR scans.

7-Scenes layout (what `afford synth --sequences` writes too): ``frame-NNNNNN.depth.png`` (16-bit
millimetres; 0, and 65535 in the 7-Scenes README, mean no measurement), ``camera-intrinsics.txt`` (3 x 3)
and optionally ``frame-NNNNNN.pose.txt`` (4 x 4 camera-to-world ground truth) and ``gravity-direction.txt``
(gravity, "down", in the world frame). LiDAR: ``scan-NNNNNN.bin``
(float32 x, y, z in the sensor frame) with optional ``scan-NNNNNN.pose.txt``. Cloud files: any ``*.ply`` or
``*.pcd`` files, one scan each in the sensor frame, in natural name order (``scan2`` before ``scan10``), as
kiss-icp's generic dataset reads a folder; an optional ``<stem>.pose.txt`` beside each.

Any frame may also have ``<stem>.odometry.txt``: the robot's own estimate of the sensor's pose (4 x 4
sensor-to-odometry-frame, as wheel odometry gives it: drifting, in a frame of its own), which `afford
publish` sends as the frame's pose guess. Only its motion from frame to frame is used.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

DEPTH_SCALE = 0.001  # millimetres
CLOUD_SUFFIXES = (".ply", ".pcd")
INVALID_DEPTH = 65535


class SequenceError(ValueError):
    """A folder that is not a usable sequence; the message names the folder and what is missing."""


@dataclass
class Sequence:
    folder: Path
    kind: str  # "depth", "lidar" (scan-NNNNNN.bin) or "cloud" (PLY/PCD files)
    frames: list[Path]
    intrinsics: np.ndarray | None  # 3 x 3 for depth

    def _beside(self, index: int, suffix: str) -> Path:
        """The file of this suffix beside a frame (``frame-000007.pose.txt`` beside its depth image)."""
        return self.folder / f"{self.frames[index].name.split('.')[0]}{suffix}"

    def pose(self, index: int) -> np.ndarray | None:
        """The frame's ground-truth pose (sensor to world), if the sequence has one."""
        path = self._beside(index, ".pose.txt")
        return np.loadtxt(path).reshape(4, 4) if path.exists() else None

    def has_odometry(self) -> bool:
        """Whether the first frame has the robot's odometry (a recording has it for every frame or none)."""
        return bool(self.frames) and self._beside(0, ".odometry.txt").exists()

    def odometry(self, index: int) -> np.ndarray | None:
        """The robot's odometry pose of the sensor at a frame (sensor to odometry frame), if recorded; whether
        it is rigid, the assembler checks as it checks any pose guess."""
        path = self._beside(index, ".odometry.txt")
        if not path.exists():
            return None
        try:
            pose = np.loadtxt(path)
        except ValueError as error:
            raise SequenceError(f"{path}: not a 4 x 4 matrix of numbers ({error})") from None
        if pose.size != 16 or not np.isfinite(pose).all():
            raise SequenceError(f"{path}: expected a finite 4 x 4 transform")
        return pose.reshape(4, 4)

    def gravity(self, index: int) -> np.ndarray | None:
        """Gravity's direction in the sensor frame at a frame, what an accelerometer at rest would give: the
        world's gravity-direction.txt turned by the frame's pose. None without both files."""
        path = self.folder / "gravity-direction.txt"
        pose = self.pose(index)
        if pose is None or not path.exists():
            return None
        down = np.loadtxt(path).reshape(3)
        return pose[:3, :3].T @ (down / np.linalg.norm(down))

    def depth(self, index: int) -> np.ndarray:
        """The 16-bit depth image of a depth frame."""
        from PIL import Image

        image = np.asarray(Image.open(self.frames[index]))
        if image.ndim != 2 or image.dtype not in (np.uint16, np.int32, np.uint32):
            raise SequenceError(
                f"{self.frames[index]}: not a 16-bit depth image ({image.dtype}, shape {image.shape})"
            )
        return image.astype(np.uint16)

    def scan(self, index: int) -> np.ndarray:
        """The points (N, 3) of a LiDAR scan or cloud file (NaN or infinite points dropped)."""
        if self.frames[index].suffix.lower() in CLOUD_SUFFIXES:
            from ..geometry.scene import load_cloud

            return load_cloud(self.frames[index]).points
        size = self.frames[index].stat().st_size
        if size % 12:
            raise SequenceError(
                f"{self.frames[index]}: {size} bytes is not a whole number of float32 x, y, z points (12 "
                "bytes each)"
            )
        return np.fromfile(self.frames[index], dtype="<f4").reshape(-1, 3).astype(np.float64)


def read_sequence(folder: str | Path) -> Sequence:
    folder = Path(folder)
    if not folder.is_dir():
        raise SequenceError(f"{folder}: not a folder")
    depth = sorted(folder.glob("frame-*.depth.png"))
    scans = sorted(folder.glob("scan-*.bin"))
    if depth:
        intrinsics_path = folder / "camera-intrinsics.txt"
        if not intrinsics_path.exists():
            raise SequenceError(
                f"{folder}: depth frames without camera-intrinsics.txt (a 3 x 3 pinhole matrix)"
            )
        try:
            intrinsics = np.loadtxt(intrinsics_path)
        except ValueError as error:
            raise SequenceError(f"{intrinsics_path}: not a 3 x 3 matrix of numbers ({error})") from None
        if intrinsics.shape != (3, 3) or not intrinsics[0, 0] > 0:
            raise SequenceError(f"{intrinsics_path}: expected a 3 x 3 pinhole matrix with fx > 0")
        return Sequence(folder, "depth", depth, intrinsics)
    if scans:
        return Sequence(folder, "lidar", scans, None)
    clouds = sorted(
        (path for path in folder.iterdir() if path.suffix.lower() in CLOUD_SUFFIXES and path.is_file()),
        key=_natural_order,
    )
    if clouds:
        return Sequence(folder, "cloud", clouds, None)
    raise SequenceError(
        f"{folder}: no frame-NNNNNN.depth.png (7-Scenes layout), scan-NNNNNN.bin, .ply or .pcd files"
    )


def _natural_order(path: Path) -> list:
    """scan2.ply before scan10.ply: digits compare as numbers (kiss-icp sorts its folders so, with natsort).
    Splitting on digit runs puts text at even and numbers at odd places, so like compares with like."""
    return [int(part) if index % 2 else part for index, part in enumerate(re.split(r"(\d+)", path.name))]
