"""Scan assembly: KISS-ICP registers each frame, and a global map keeps what it saw.

KISS-ICP's own local map forgets everything beyond ``max_range`` of the sensor (it is built for odometry), so
the assembler keeps a second voxel map, one point per ``map_voxel``, that never forgets. Frames join it as
keyframes (the sensor moved or turned enough since the last one), which keeps the cost of a frame close to
bare KISS-ICP's. The odometry frame is the first sensor frame; `aligned_map` brings the map to the world
frame (gravity-aligned, z up, floor at 0) with the same alignment `afford map` uses.

Frames arrive as `SensorFrame`s, whatever message brought them (affordwire.sensors decodes them); depth images
are back-projected by `affordcore.depth.back_project`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .depth import DepthImage, back_project
from .settings import AssemblerSettings, Settings


@dataclass
class SensorFrame:
    """One frame as the assembler takes it, whatever message brought it (affordwire.sensors decodes them)."""

    frame_id: str
    stamp: float  # seconds since the epoch; 0 when the message did not say
    points: np.ndarray | None = None  # (N, 3) in the sensor frame ...
    depth: DepthImage | None = None  # ... or a depth image to back-project
    gravity: np.ndarray | None = None  # unit direction of gravity (down) in the sensor frame, from an IMU
    pose_guess: np.ndarray | None = None  # world_from_sensor from the robot's own odometry


@dataclass
class Trajectory:
    stamps: list[float] = field(default_factory=list)
    poses: list[np.ndarray] = field(default_factory=list)  # odom_from_sensor, 4 x 4

    @property
    def positions(self) -> np.ndarray:
        return np.array([pose[:3, 3] for pose in self.poses]).reshape(-1, 3)


class Assembler:
    def __init__(self, settings: AssemblerSettings | None = None):
        from kiss_icp.config import KISSConfig
        from kiss_icp.kiss_icp import KissICP
        from kiss_icp.mapping import VoxelHashMap

        self.settings = settings = settings or AssemblerSettings()
        config = KISSConfig()
        config.data.max_range, config.data.min_range = settings.max_range, settings.min_range
        config.data.deskew = False
        config.mapping.voxel_size = settings.voxel_size
        config.registration.max_num_threads = 0  # all cores
        self.odometry = KissICP(config)
        self.global_map = VoxelHashMap(settings.map_voxel, max_distance=np.inf, max_points_per_voxel=1)
        self.trajectory = Trajectory()
        self._last_keyframe: np.ndarray | None = None
        self._last_guess: np.ndarray | None = None
        # the last frame as KISS-ICP registered it (thinned, sensor frame)
        self.registered_points = np.empty((0, 3))
        self._gravity_sum = np.zeros(3)  # gravity directions reported with the frames, in the odometry frame
        self.keyframes = 0  # frames that joined the global map

    @property
    def frames(self) -> int:
        return len(self.trajectory.poses)

    def add(self, frame: SensorFrame, stamp: float) -> np.ndarray:
        """Register a sensor frame (depth images back-projected as block means); returns odom_from_sensor."""
        points = frame.points
        if frame.depth is not None:
            settings = self.settings
            points = back_project(frame.depth, settings.pixel_step, settings.min_range, settings.max_range)
        return self.register(points, stamp, frame.pose_guess, frame.gravity)

    def register(
        self,
        points: np.ndarray,
        stamp: float,
        pose_guess: np.ndarray | None = None,
        gravity: np.ndarray | None = None,
    ) -> np.ndarray:
        """Register one frame (points in the sensor frame); returns the sensor's pose, odom_from_sensor.

        `pose_guess` (world_from_sensor from the robot's own odometry) replaces KISS-ICP's constant-velocity
        prediction by the guessed motion since the previous frame. `gravity` (its direction in the sensor
        frame, from an IMU) is averaged in the odometry frame and used by `aligned_map` instead of a floor
        search over candidate axes, which fails when a hand-held camera has seen little floor."""
        points = np.asarray(points, dtype=np.float64)
        ranges = np.linalg.norm(points, axis=1)
        points = points[(ranges >= self.settings.min_range) & (ranges <= self.settings.max_range)]
        if len(points) < 100:
            raise ValueError(
                f"the frame has {len(points)} points within "
                f"{self.settings.min_range}-{self.settings.max_range} m; at least 100 are needed"
            )
        if pose_guess is not None and self._last_guess is not None:
            self.odometry.last_delta = np.linalg.inv(self._last_guess) @ pose_guess
        self._last_guess = pose_guess
        _, self.registered_points = self.odometry.register_frame(points, np.zeros(len(points)))
        pose = self.odometry.last_pose.copy()
        if gravity is not None:
            self._gravity_sum += pose[:3, :3] @ (gravity / np.linalg.norm(gravity))
        self.trajectory.stamps.append(stamp)
        self.trajectory.poses.append(pose)
        if self._is_keyframe(pose):
            self.global_map.update(points, pose)
            self._last_keyframe = pose
            self.keyframes += 1
        return pose

    def _is_keyframe(self, pose: np.ndarray) -> bool:
        if self._last_keyframe is None:
            return True
        motion = np.linalg.inv(self._last_keyframe) @ pose
        angle = np.degrees(np.arccos(np.clip((np.trace(motion[:3, :3]) - 1) / 2, -1, 1)))
        return (
            np.linalg.norm(motion[:3, 3]) >= self.settings.keyframe_distance
            or angle >= self.settings.keyframe_angle_deg
        )

    def map_points(self) -> np.ndarray:
        """The global map in the odometry frame (the first sensor frame)."""
        return self.global_map.point_cloud() if self.frames else np.empty((0, 3))

    def aligned_map(self, settings: Settings | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(map points in the world frame, world_from_odom), by the same path as every other cloud
        (`pipeline.to_world`), with gravity from the frames when they carried it. Raises ValueError when no
        floor is found yet."""
        from .pipeline import to_world
        from .scene import Cloud

        known = self._gravity_sum if np.linalg.norm(self._gravity_sum) > 0 else "auto"
        world = to_world(Cloud(self.map_points(), source="assembler map"), settings, known)
        return world.cloud.points, world.alignment.world_from_input


def trajectory_errors(estimated: list[np.ndarray], truth: list[np.ndarray]) -> dict[str, float]:
    """Position and final rotation error of an odometry trajectory against ground truth, both anchored at the
    first frame (the estimate starts at the identity; ground truth is world_from_camera)."""
    truth = np.asarray(truth)
    anchored = truth[0] @ np.asarray(estimated)
    position = np.linalg.norm(anchored[:, :3, 3] - truth[:, :3, 3], axis=1)
    final = anchored[-1, :3, :3].T @ truth[-1, :3, :3]
    rotation = np.degrees(np.arccos(np.clip((np.trace(final) - 1) / 2, -1, 1)))
    path = np.linalg.norm(np.diff(truth[:, :3, 3], axis=0), axis=1).sum()
    return {
        "frames": len(truth),
        "mean_m": float(position.mean()),
        "worst_m": float(position.max()),
        "final_rotation_deg": float(rotation),
        "path_m": float(path),
    }
