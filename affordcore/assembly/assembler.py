"""Scan assembly: KISS-ICP registers each frame, and a global map keeps what it saw.

With the robot's odometry (a pose guess per frame), a frame is registered point to plane from the odometry's
motion, weighted by it (`planes`), on KISS-ICP's local map: KISS-ICP's own registration takes no prior.

KISS-ICP's own local map forgets everything beyond ``max_range`` of the sensor (it is built for odometry), so
the assembler keeps a second voxel map that never forgets: per ``map_voxel``, the mean of every point seen in
it (`voxelmap.VoxelMeans`), from depth images without the blocks that straddle a depth edge
(``map_edge_spread``). Frames join it as keyframes (the sensor moved or turned enough since the last one),
which keeps the cost of a frame close to bare KISS-ICP's. The odometry frame is the first sensor frame;
`aligned_map` brings the map to the world frame (gravity-aligned, z up, floor at 0) with the same alignment
`afford map` uses.

Frames arrive as `SensorFrame`s, whatever message brought them (affordwire.sensors decodes them); depth images
are back-projected by `affordcore.assembly.depth.back_project`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..geometry.cells import cell_sums
from ..settings import AssemblerSettings, LimitSettings, Settings
from .depth import DepthImage, back_project
from .planes import LocalPlanes, align_with_prior, odometry_information
from .voxelmap import VoxelMeans


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


@dataclass
class FrameRecord:
    """What one accepted frame changed: enough to replay it onto a restored assembler
    (affordcore.assembly.checkpoint
    journals these)."""

    index: int  # the frame's number, from 0
    stamp: float
    pose: np.ndarray  # odom_from_sensor, 4 x 4
    guess: np.ndarray | None  # the pose guess it carried (world_from_sensor), if any
    gravity: np.ndarray  # its gravity direction in the odometry frame; zeros without an IMU
    map_points: np.ndarray | None  # (N, 3) odometry-frame cell means it added to the global map (keyframes)
    map_weights: np.ndarray | None = None  # (N,) the points each of them averages (None: one each)
    note: str = ""  # what a person watching the robot should hear of this frame (not journaled)


@dataclass
class _Proposal:
    """A frame registered but not yet part of anything."""

    record: FrameRecord
    frame_downsample: np.ndarray  # what KISS-ICP's local map takes
    source: np.ndarray  # what KISS-ICP registered (thinned, sensor frame)
    deviation: np.ndarray  # registration against prediction, for KISS-ICP's adaptive threshold
    delta: np.ndarray  # motion since the previous frame


class Assembler:
    def __init__(self, settings: AssemblerSettings | None = None, limits: LimitSettings | None = None):
        self.settings = settings or AssemblerSettings()
        self.limits = limits or LimitSettings()
        self.odometry = self._kiss_icp()
        self.global_map = VoxelMeans(self.settings.map_voxel)
        self.trajectory = Trajectory()
        self._last_keyframe: np.ndarray | None = None
        self._last_guess: np.ndarray | None = None
        self._last_guess_stamp = 0.0
        # the last frame as KISS-ICP registered it (thinned, sensor frame)
        self.registered_points = np.empty((0, 3))
        self._planes = LocalPlanes()  # the local map's planes, for registration weighted by odometry
        self._gravity_sum = np.zeros(3)  # gravity directions reported with the frames, in the odometry frame
        self.keyframes = 0  # frames that joined the global map
        # the last levelling found (world_from_odom); a later map whose floor search fails keeps it
        self.world_from_odom: np.ndarray | None = None
        self.levelling_kept = ""  # why the last aligned map was levelled as before ("" when levelled anew)

    def _kiss_icp(self):
        from kiss_icp.kiss_icp import KissICP

        return KissICP(kiss_config(self.settings))

    @property
    def frames(self) -> int:
        return len(self.trajectory.poses)

    def add(self, frame: SensorFrame, stamp: float, busy: bool = False) -> FrameRecord:
        """Register a sensor frame (depth images back-projected as block means) and add it to the map; returns
        what it changed. A frame refused by the limits (time going back, a jump beyond the speed limit, a pose
        beyond the largest extent) raises ValueError and changes nothing. `busy`: other frames wait, so
        register on fewer points (`busy_registration_voxels`). A depth image joins the map (keyframes) as
        every block, less the blocks across depth edges (`map_edge_spread`)."""
        points, map_frame = frame.points, None
        if frame.depth is not None:
            points, map_frame = self.depth_points(frame.depth)
        return self.register(points, stamp, frame.pose_guess, frame.gravity, busy, map_frame)

    def depth_points(self, depth: DepthImage) -> tuple[np.ndarray, Callable[[], np.ndarray] | None]:
        """The block means a depth image is registered on, and how to get the points it adds to the map as a
        keyframe (None: the same points): every block but those across depth edges."""
        settings = self.settings
        low, high = settings.min_range, settings.max_range
        points = back_project(depth, settings.pixel_step, low, high, settings.block_stride)
        if settings.map_edge_spread <= 0:
            return points, None
        return points, lambda: back_project(
            depth, settings.pixel_step, low, high, max_spread=settings.map_edge_spread
        )

    def register(
        self,
        points: np.ndarray,
        stamp: float,
        pose_guess: np.ndarray | None = None,
        gravity: np.ndarray | None = None,
        busy: bool = False,
        map_frame: Callable[[], np.ndarray] | None = None,
    ) -> FrameRecord:
        """Register one frame (points in the sensor frame) and add it to the map; returns its record, whose
        `pose` is the sensor's, odom_from_sensor.

        `pose_guess` (world_from_sensor from the robot's own odometry) replaces KISS-ICP's constant-velocity
        prediction by the guessed motion since the previous frame. `gravity` (its direction in the sensor
        frame, from an IMU) is averaged in the odometry frame and used by `aligned_map` instead of a floor
        search over candidate axes, which fails when a hand-held camera has seen little floor. `map_frame()`
        gives the points (sensor frame) a keyframe adds to the map instead of `points`, only when needed."""
        settings = self.settings
        source_voxel = settings.voxel_size * (
            settings.busy_registration_voxels if busy else settings.registration_voxels
        )
        proposal = self._propose(
            np.asarray(points, dtype=np.float64), stamp, pose_guess, gravity, source_voxel, map_frame
        )
        odometry = self.odometry  # from here on nothing can fail: the frame is in
        odometry.adaptive_threshold.update_model_deviation(proposal.deviation)
        odometry.local_map.update(proposal.frame_downsample, proposal.record.pose)
        odometry.last_delta, odometry.last_pose = proposal.delta, proposal.record.pose.copy()
        self.registered_points = proposal.source
        self.apply(proposal.record)
        return proposal.record

    def _propose(
        self,
        points: np.ndarray,
        stamp: float,
        pose_guess: np.ndarray | None,
        gravity: np.ndarray | None,
        source_voxel: float,
        map_frame: Callable[[], np.ndarray] | None = None,
    ) -> _Proposal:
        """Everything KISS-ICP's register_frame does, without changing anything, and the limits' checks;
        registration on one point per `source_voxel` of the frame."""
        from kiss_icp.voxelization import voxel_down_sample

        self._check_input(points, stamp, pose_guess, gravity)
        odometry = self.odometry
        delta = self._predicted_motion(stamp)
        guessed = pose_guess is not None and self._last_guess is not None
        note = self._odometry_jump(pose_guess, stamp) if guessed else ""
        if note:  # a reset or relocalised odometry: this frame without it, the next ones from its new pose
            guessed = False
        if guessed:
            delta = nearest_rigid(np.linalg.inv(self._last_guess) @ pose_guess)
        # KISS-ICP's preprocessing with deskew off, without copying the frame into C++ and back: its range
        # filter (the same strict bounds on the same norms; tests/test_assembly.py checks the poses match)
        settings = self.settings
        if len(points) > settings.max_frame_points:  # every n-th point: a dense cloud's order is scan order
            points = points[:: thinning_step(len(points), settings.max_frame_points)]
        frame = within_range(points, settings)
        if len(frame) < 100:
            raise ValueError(
                f"the frame has {len(frame)} points within "
                f"{settings.min_range}-{settings.max_range} m; at least 100 are needed"
            )
        # KISS-ICP's voxelize, with the registration's voxel a setting of its own
        frame_downsample = voxel_down_sample(frame, 0.5 * settings.voxel_size)
        source = voxel_down_sample(frame_downsample, source_voxel)
        sigma = odometry.adaptive_threshold.get_threshold()
        initial_guess = odometry.last_pose @ delta
        if guessed and settings.odometry_prior:
            pose = self._align_with_odometry(source, initial_guess, delta, 3 * sigma)
        else:
            pose = odometry.registration.align_points_to_map(
                points=source,
                voxel_map=odometry.local_map,
                initial_guess=initial_guess,
                max_correspondance_distance=3 * sigma,
                kernel=sigma,
            )
        self._check_motion(odometry.last_pose, pose, stamp, "registration")
        if float(np.linalg.norm(pose[:3, 3])) > self.limits.max_extent:
            raise ValueError(
                f"registration puts the sensor {np.linalg.norm(pose[:3, 3]):.1f} m from where it started, "
                f"beyond AFFORD_LIMITS__MAX_EXTENT ({self.limits.max_extent:g} m)"
            )
        up = np.zeros(3) if gravity is None else pose[:3, :3] @ (gravity / np.linalg.norm(gravity))
        keyframe = self._is_keyframe(pose)
        map_points = weights = None
        if keyframe:  # moved, then reduced to the map's cells: their sums are all the map keeps of them
            mapped = frame if map_frame is None else within_range(map_frame(), settings)
            _, sums, weights = cell_sums(mapped @ pose[:3, :3].T + pose[:3, 3], settings.map_voxel)
            map_points = sums / weights[:, None]
        record = FrameRecord(self.frames, stamp, pose, pose_guess, up, map_points, weights, note)
        return _Proposal(
            record,
            frame_downsample,
            source,
            np.linalg.inv(initial_guess) @ pose,
            np.linalg.inv(odometry.last_pose) @ pose,
        )

    def _align_with_odometry(
        self, source: np.ndarray, prior: np.ndarray, step: np.ndarray, reach: float
    ) -> np.ndarray:
        """Point-to-plane registration on the local map from the odometry's `prior` pose, weighted by it
        (`planes.align_with_prior`); the odometry's `step` since the last frame sets the prior's weight."""
        settings = self.settings
        self._planes.refresh(self.odometry.local_map, self.frames)
        information = odometry_information(
            step,
            settings.odometry_error,
            settings.odometry_least_error,
            settings.odometry_least_turn_error_deg,
        )
        return align_with_prior(source, prior, information, self._planes, reach, settings.plane_noise)

    def _predicted_motion(self, stamp: float) -> np.ndarray:
        """KISS-ICP's constant-velocity prediction, constant in time rather than per frame: the last motion
        scaled to the time since the last frame. A stream thinned to keep up (services pass over late frames)
        has uneven gaps; predicting one frame's motion across three would count as model deviation, widen
        KISS-ICP's adaptive threshold and slow every registration after it."""
        delta, stamps = self.odometry.last_delta, self.trajectory.stamps
        if len(stamps) < 2 or not stamps[-1] > stamps[-2]:
            return delta
        ratio = (stamp - stamps[-1]) / (stamps[-1] - stamps[-2])
        if abs(ratio - 1) < 1e-6:  # a steady stream: KISS-ICP's own prediction, as it is
            return delta
        return scaled_motion(delta, ratio)

    def _check_input(
        self, points: np.ndarray, stamp: float, guess: np.ndarray | None, gravity: np.ndarray | None
    ) -> None:
        limits = self.limits
        if points.ndim != 2 or points.shape[1] != 3 or not np.isfinite(points).all():
            raise ValueError(f"a frame's points must be finite (N, 3), got shape {points.shape}")
        if len(points) > limits.max_points:
            raise ValueError(
                f"{len(points):,} points; at most {limits.max_points:,} (AFFORD_LIMITS__MAX_POINTS)"
            )
        if not 0 <= stamp <= limits.latest_timestamp:
            raise ValueError(f"frame time {stamp:.6g} s is outside 0 ... {limits.latest_timestamp:.0f} s")
        if self.frames and stamp <= self.trajectory.stamps[-1]:
            raise ValueError(
                f"frame time {stamp:.6f} s is not after the last frame's ({self.trajectory.stamps[-1]:.6f} s)"
            )
        if gravity is not None and not (np.isfinite(gravity).all() and np.linalg.norm(gravity) > 1e-6):
            raise ValueError(f"gravity {np.asarray(gravity).tolist()} is not a direction")
        if guess is not None:
            guess = np.asarray(guess)
            if guess.shape != (4, 4) or not np.isfinite(guess).all():
                raise ValueError(f"the pose guess is not a finite 4 x 4 transform (shape {guess.shape})")
            rotation = guess[:3, :3]
            rigid = np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-3) and np.linalg.det(rotation) > 0
            if not rigid or not np.allclose(guess[3], (0, 0, 0, 1), atol=1e-6):
                raise ValueError("the pose guess is not a rigid transform")

    def _odometry_jump(self, guess: np.ndarray, stamp: float) -> str:
        """Why the guess cannot follow the last one ("" when it can): a motion beyond the limits since the
        last guess is the odometry reset or relocalised, not the robot moving. The frame is still good."""
        try:
            self._check_motion(self._last_guess, guess, stamp, "the odometry", self._last_guess_stamp)
        except ValueError as jump:
            return f"{jump}: taken as a reset, this frame registered without it and the next ones from it"
        return ""

    def _check_motion(
        self, before: np.ndarray, after: np.ndarray, stamp: float, what: str, since: float | None = None
    ) -> None:
        """Refuse a motion faster than the limits allow (at least 0.1 s of it: frames may come in bursts)."""
        if not self.frames:
            return
        seconds = max(stamp - (self.trajectory.stamps[-1] if since is None else since), 0.1)
        motion = np.linalg.inv(before) @ after
        distance = float(np.linalg.norm(motion[:3, 3]))
        angle = rotation_angle_deg(motion[:3, :3])
        limits = self.limits
        if distance > limits.max_speed * seconds or angle > limits.max_turn_rate_deg * seconds:
            raise ValueError(
                f"{what} moves the sensor {distance:.2f} m and {angle:.0f} degrees in {seconds:.2f} s, "
                f"faster than AFFORD_LIMITS__MAX_SPEED ({limits.max_speed:g} m/s) or MAX_TURN_RATE_DEG "
                f"({limits.max_turn_rate_deg:g})"
            )

    def apply(self, record: FrameRecord) -> None:
        """Add an accepted frame to the trajectory and the global map (as registration does, and as a
        restored assembler replays its journal)."""
        self.trajectory.stamps.append(record.stamp)
        self.trajectory.poses.append(record.pose)
        self._gravity_sum += record.gravity
        if record.guess is not None:
            self._last_guess, self._last_guess_stamp = record.guess, record.stamp
        if record.map_points is not None:
            self.global_map.add_points(record.map_points, record.map_weights)
            self._last_keyframe = record.pose
            self.keyframes += 1

    def state_arrays(self) -> dict[str, np.ndarray]:
        """Everything `load_state` needs to rebuild this assembler's map and trajectory
        (affordcore.assembly.checkpoint
        saves it)."""
        trajectory = self.trajectory
        return {
            "map_points": self.map_points(),
            "map_weights": self.global_map.counts() if self.frames else np.empty(0, np.int64),
            "stamps": np.array(trajectory.stamps, dtype=np.float64),
            "poses": np.array(trajectory.poses, dtype=np.float64).reshape(-1, 4, 4),
            "gravity_sum": self._gravity_sum,
            "last_guess": np.empty((0, 4)) if self._last_guess is None else self._last_guess,
            "last_guess_stamp": np.float64(self._last_guess_stamp),
            "last_keyframe": np.empty((0, 4)) if self._last_keyframe is None else self._last_keyframe,
            "keyframes": np.int64(self.keyframes),
            "world_from_odom": np.empty((0, 4)) if self.world_from_odom is None else self.world_from_odom,
        }

    def load_state(self, data) -> None:
        """Take the state `state_arrays` gave, on a fresh assembler."""
        # snapshots written before the map kept running means held one point per voxel: one observation each
        self.global_map.add_points(data["map_points"], data["map_weights"] if "map_weights" in data else None)
        self.trajectory.stamps = [float(t) for t in data["stamps"]]
        self.trajectory.poses = list(data["poses"])
        self._gravity_sum = data["gravity_sum"].copy()
        self._last_guess = data["last_guess"] if data["last_guess"].size else None
        self._last_guess_stamp = float(data["last_guess_stamp"])
        self._last_keyframe = data["last_keyframe"] if data["last_keyframe"].size else None
        self.keyframes = int(data["keyframes"])
        if "world_from_odom" in data and data["world_from_odom"].size:  # checkpoints before it lack it
            self.world_from_odom = data["world_from_odom"]

    def resume(self) -> None:
        """After a restore: KISS-ICP starts again at the last pose, at rest, its local map refilled from the
        global map around it (its adaptive threshold starts afresh: it adapts within a few frames)."""
        pose = self.trajectory.poses[-1]
        self.odometry.last_pose, self.odometry.last_delta = pose.copy(), np.eye(4)
        points = self.map_points()
        near = np.linalg.norm(points - pose[:3, 3], axis=1) <= self.settings.max_range
        self.odometry.local_map.add_points(points[near])
        self._planes.forget()

    def _is_keyframe(self, pose: np.ndarray) -> bool:
        if self._last_keyframe is None:
            return True
        motion = np.linalg.inv(self._last_keyframe) @ pose
        angle = rotation_angle_deg(motion[:3, :3])
        return (
            np.linalg.norm(motion[:3, 3]) >= self.settings.keyframe_distance
            or angle >= self.settings.keyframe_angle_deg
        )

    def map_points(self) -> np.ndarray:
        """The global map in the odometry frame (the first sensor frame)."""
        return self.global_map.point_cloud() if self.frames else np.empty((0, 3))

    def sensor_origins(self, world_from_odom: np.ndarray, count: int) -> np.ndarray:
        """Where the sensor stood, at most `count` of its positions spread out (the few the features service
        carves free space from), in the frame `world_from_odom` takes the map to (`aligned_map`'s)."""
        from ..geometry.visibility import spread_origins

        positions = spread_origins(self.trajectory.positions, count)
        return positions @ world_from_odom[:3, :3].T + world_from_odom[:3, 3]

    def aligned_map(self, settings: Settings | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(map points in the world frame, world_from_odom), by the same path as every other cloud
        (`pipeline.to_world`), with gravity from the frames when they carried it. Raises ValueError when no
        floor has been found yet.

        Once a floor has been found, a map whose floor search fails is levelled as the last one was (and
        `levelling_kept` says why): odometry drift smears a floor seen from a few frames over decimetres, and
        the search can then fail on one map and succeed on the next; a robot's world frame should not
        vanish in between."""
        from ..geometry.gravity import NoFloorError
        from ..geometry.scene import Cloud
        from ..mapping.pipeline import to_world

        known = self._gravity_sum if np.linalg.norm(self._gravity_sum) > 0 else "auto"
        # without the frames' gravity, where the sensor stood tells the floor from a wall (gravity.py)
        origins = self.trajectory.positions if isinstance(known, str) and self.trajectory.poses else None
        cloud = Cloud(self.map_points(), source="assembler map", origins=origins)
        try:
            world = self._on_floor(to_world(cloud, settings, known))
        except NoFloorError as error:
            if self.world_from_odom is None:
                raise
            self.levelling_kept = str(error)
            return self._levelled_as_before(cloud, settings)
        self.levelling_kept = ""
        if self.world_from_odom is not None and not self._moves(world.alignment.world_from_input, cloud):
            return self._levelled_as_before(cloud, settings)
        self.world_from_odom = world.alignment.world_from_input
        return world.cloud.points, self.world_from_odom

    def _on_floor(self, world):
        """The map levelled on its own floor plane when the frames' gravity found one leaning at most
        `floor_level_max_deg` from it: the fields measure heights above the floor, and a floor tilted 3 deg
        (the kitchen's under its gravity file) is 15 cm higher at one end of a 3 m room than at the other.
        The floor search without gravity levels a cloud on its floor the same way. The plane is the one the
        gravity's floor search found: no second search (it took as long as the first)."""
        from dataclasses import replace

        from ..geometry.gravity import rotation_between

        alignment, limit = world.alignment, self.settings.floor_level_max_deg
        if alignment.method != "gravity" or not 0 < alignment.tilt_deg <= limit:
            return world
        floor = alignment.candidates[0]  # normal and height along it, in the input (odometry) frame
        on_floor = np.eye(4)
        on_floor[:3, :3] = rotation_between(floor.normal, np.array([0.0, 0.0, 1.0]))
        on_floor[2, 3] = -floor.offset
        correction = on_floor @ np.linalg.inv(alignment.world_from_input)
        levelled = replace(alignment, world_from_input=on_floor)
        return replace(world, cloud=world.cloud.transformed(correction), alignment=levelled)

    def _levelled_as_before(self, cloud, settings: Settings | None) -> tuple[np.ndarray, np.ndarray]:
        from ..mapping.pipeline import to_world

        kept = to_world(cloud, settings, "none").cloud.transformed(self.world_from_odom)
        return kept.points, self.world_from_odom

    def _moves(self, world_from_odom: np.ndarray, cloud) -> bool:
        """Whether a new levelling moves some point of the map (a corner of its box) further than
        `relevel_distance` from where the kept one puts it."""
        low, high = cloud.points.min(axis=0), cloud.points.max(axis=0)
        corners = np.array(
            [[x, y, z, 1.0] for x in (low[0], high[0]) for y in (low[1], high[1]) for z in (low[2], high[2])]
        )
        moved = corners @ (world_from_odom - self.world_from_odom).T
        return float(np.linalg.norm(moved[:, :3], axis=1).max()) > self.settings.relevel_distance


def kiss_config(settings: AssemblerSettings):
    """KISS-ICP's configuration for these settings: the assembler's, and bare KISS-ICP's in
    benchmarks/bench_assembler.py."""
    from kiss_icp.config import KISSConfig

    config = KISSConfig()
    config.data.max_range, config.data.min_range = settings.max_range, settings.min_range
    config.data.deskew = False  # a depth image is one instant, and scans come without per-point times
    config.mapping.voxel_size = settings.voxel_size
    config.mapping.max_points_per_voxel = settings.max_points_per_voxel
    config.adaptive_threshold.initial_threshold = settings.initial_threshold
    config.adaptive_threshold.min_motion_th = settings.min_motion
    config.registration.convergence_criterion = settings.convergence
    config.registration.max_num_threads = settings.registration_threads
    return config


def within_range(points: np.ndarray, settings: AssemblerSettings) -> np.ndarray:
    """The points strictly between `min_range` and `max_range` of the sensor (KISS-ICP's range filter: the
    same strict bounds on the same norms; a depth image's back-projection bounds depth, not range)."""
    squared = np.einsum("ij,ij->i", points, points)
    return points[(squared > settings.min_range**2) & (squared < settings.max_range**2)]


def scaled_motion(delta: np.ndarray, ratio: float) -> np.ndarray:
    """A rigid motion scaled by `ratio` (rotation angle and translation alike; clipped to 0 ... 10 so one
    stalled stamp cannot fling the guess across the room)."""
    from scipy.spatial.transform import Rotation

    ratio = float(np.clip(ratio, 0.0, 10.0))
    scaled = np.eye(4)
    scaled[:3, :3] = Rotation.from_rotvec(Rotation.from_matrix(delta[:3, :3]).as_rotvec() * ratio).as_matrix()
    scaled[:3, 3] = delta[:3, 3] * ratio
    return scaled


def nearest_rigid(matrix: np.ndarray) -> np.ndarray:
    """The rigid transform nearest a 4 x 4 that is one up to rounding (a pose read from text, or composed of
    such): KISS-ICP's Sophus aborts the whole process on a rotation that is off orthogonal by 1e-10."""
    from scipy.spatial.transform import Rotation

    rigid = np.eye(4)
    rigid[:3, :3] = Rotation.from_matrix(matrix[:3, :3]).as_matrix()
    rigid[:3, 3] = matrix[:3, 3]
    return rigid


def rotation_angle_deg(rotation: np.ndarray) -> float:
    """The angle of a 3 x 3 rotation, in degrees."""
    from scipy.spatial.transform import Rotation

    return float(np.degrees(Rotation.from_matrix(rotation).magnitude()))


def thinning_step(points: int, most: int) -> int:
    """n such that every n-th of `points` points leaves at most `most`: how a dense frame is thinned
    (AFFORD_ASSEMBLER__MAX_FRAME_POINTS), here and where a PointCloud2 is read (affordwire.ros)."""
    return max(1, -(-points // most))


def trajectory_errors(estimated: list[np.ndarray], truth: list[np.ndarray]) -> dict[str, float]:
    """Position and final rotation error of an odometry trajectory against ground truth, both anchored at the
    first frame (the estimate starts at the identity; ground truth is world_from_camera)."""
    truth = np.asarray(truth)
    anchored = truth[0] @ np.asarray(estimated)
    position = np.linalg.norm(anchored[:, :3, 3] - truth[:, :3, 3], axis=1)
    final = anchored[-1, :3, :3].T @ truth[-1, :3, :3]
    rotation = rotation_angle_deg(final)
    path = np.linalg.norm(np.diff(truth[:, :3, 3], axis=0), axis=1).sum()
    return {
        "frames": len(truth),
        "mean_m": float(position.mean()),
        "worst_m": float(position.max()),
        "final_rotation_deg": float(rotation),
        "path_m": float(path),
    }
