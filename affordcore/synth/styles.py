"""Scan styles: a generated room scanned each of the ways real rooms arrive (issue 24, item 2).

Models, thresholds and place decisions are chosen on generated rooms, so those rooms should look like what a
deployment sees. Real clouds come as fused depth frames, a reconstruction's mesh vertices (ScanNet, Replica),
a terrestrial laser scan, one or a few raw depth frames, or a robot's walk through the assembler. Each style
below is one of them: a function of the room and its generator returning a `Scan` in the room's world frame
(z up, floor at 0, the frame its labels are in), with the sensor positions a later free/unknown voxel state
needs. docs/synthetic-rooms.md describes and measures them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from .rooms import Room
from .scanner import (
    DepthCamera,
    Raycaster,
    aim_at_piece,
    backproject,
    depth_frame,
    free_floor,
    free_positions,
    fuse_frames,
    look_at,
    mix_edges,
    perturbed,
    trajectory,
    viewpoints,
)

GREY = (0.5, 0.5, 0.5)  # the colour of every point of a sensor that sees none (a laser, the assembler's map)


@dataclass
class Scan:
    points: np.ndarray  # (N, 3) world frame
    colors: np.ndarray  # (N, 3) float32 in [0, 1]; GREY throughout when the sensor has no colour
    origins: np.ndarray  # (M, 3) where the sensor stood for each frame or station, world frame
    views: str  # how it was taken, for the room report


def scan_in_style(style: str, room: Room, rng: np.random.Generator, regime: str = "full") -> Scan:
    """The room scanned in `style` (one of STYLES); `regime` is the fused style's viewpoints."""
    if style not in STYLES:
        raise ValueError(f"scan style must be one of {', '.join(STYLES)}, not {style!r}")
    if style == "fused":
        return fused_scan(room, rng, regime)
    return STYLES[style](room, rng)


def _raycaster(room: Room) -> Raycaster:
    return Raycaster(room.shell_boxes() + room.furniture_boxes())


def _grey(count: int) -> np.ndarray:
    return np.tile(np.array(GREY, np.float32), (count, 1))


def _eyes(poses: list[np.ndarray]) -> np.ndarray:
    return np.array([pose[:3, 3] for pose in poses]).reshape(-1, 3)


# -- fused: today's fused depth frames -----------------------------------------------------------------------


def fused_scan(room: Room, rng: np.random.Generator, regime: str = "full") -> Scan:
    """`scanner.scan_room`, draw for draw (the same points and colours), with its camera positions."""
    raycaster = _raycaster(room)
    poses = viewpoints(room, rng, regime=regime)
    points, colors = fuse_frames(raycaster, poses, rng)
    return Scan(points, colors, _eyes(poses), regime)


# -- mesh: a reconstruction's vertices -----------------------------------------------------------------------

MESH_FLAT_SPACING = (0.04, 0.08)  # m, drawn per room: how far apart decimation leaves flat-surface vertices
MESH_EDGE_SPACING = 0.015  # m: vertices kept near edges and corners
MESH_EDGE_BAND = 0.03  # m: points this near a box edge count as on the edge
# A reconstruction averages each surface over many frames (TSDF fusion), and its poses come from a global
# optimisation: less noise, fewer mixed pixels and a smaller registration error than a fusion of raw frames.
MESH_AVERAGED_FRAMES = 9
MESH_FLYING = 0.1
MESH_REGISTRATION = (0.002, 0.1)
BOX_EDGES = np.array(
    [[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4], [0, 4], [1, 5], [2, 6], [3, 7]]
)


def mesh_scan(room: Room, rng: np.random.Generator) -> Scan:
    """A reconstruction's mesh vertices, as ScanNet or Replica ship them: a walk round the whole room (the
    `full` viewpoints) fused at 1 cm, its noise that of a TSDF averaging 9 frames, then decimated as mesh
    simplification does: one vertex per 4-8 cm cell on flat surfaces, one per 1.5 cm within 3 cm of an edge
    or a corner (a simplifier keeps vertices where the shape bends; the room's true box edges say where that
    is, which the noisy points say poorly: their surface variation on a floor is as high as at an edge)."""
    boxes = room.shell_boxes() + room.furniture_boxes()
    raycaster = Raycaster(boxes)
    poses = viewpoints(room, rng, regime="full")
    camera = replace(
        DepthCamera.qvga().with_kinect_noise(), averaged_frames=MESH_AVERAGED_FRAMES, flying=MESH_FLYING
    )
    points, colors = fuse_frames(raycaster, poses, rng, camera, MESH_REGISTRATION)
    flat_spacing = rng.uniform(*MESH_FLAT_SPACING)
    to_edge, _ = cKDTree(edge_samples(boxes)).query(points, workers=-1)
    edge = to_edge < MESH_EDGE_BAND
    keep_flat = one_per_cell(points[~edge], flat_spacing, rng)
    keep_edge = one_per_cell(points[edge], MESH_EDGE_SPACING, rng)
    kept = np.sort(np.concatenate([np.flatnonzero(~edge)[keep_flat], np.flatnonzero(edge)[keep_edge]]))
    views = f"{len(poses)} frames, flat {100 * flat_spacing:.0f} cm"
    return Scan(points[kept], colors[kept], _eyes(poses), views)


def edge_samples(boxes, step: float = 0.005) -> np.ndarray:
    """Points (n, 3) every `step` along every edge of every box."""
    segments = np.concatenate([box.mesh_arrays()[0][BOX_EDGES] for box in boxes])  # (edges, 2, 3)
    counts = np.ceil(np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1) / step).astype(int) + 1
    which = np.repeat(np.arange(len(segments)), counts)
    # the position along each segment, 0 to 1, from the running count
    first = np.repeat(np.cumsum(counts) - counts, counts)
    along = (np.arange(len(which)) - first) / np.repeat(np.maximum(counts - 1, 1), counts)
    return segments[which, 0] + along[:, None] * (segments[which, 1] - segments[which, 0])


def one_per_cell(points: np.ndarray, cell: float, rng: np.random.Generator) -> np.ndarray:
    """Indices of one point, drawn at random, per occupied `cell`: an actual surface point (a vertex), not a
    cell mean, which would float off a corner between the two surfaces it averages. Cells are centred on
    multiples of `cell`, so the floor (z = 0, give or take the noise) lies mid-cell rather than on a face,
    where it would keep two vertices per cell, one each side."""
    if not len(points):
        return np.zeros(0, np.int64)
    order = rng.permutation(len(points))
    keys = np.floor(points[order] / cell + 0.5).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return np.sort(order[first])


# -- laser: a terrestrial laser scanner on a tripod ----------------------------------------------------------

LASER_SIGMA = 0.003  # m: range noise of a phase or time-of-flight TLS at room range
LASER_RANGE = (0.5, 30.0)
LASER_STEP_DEG = (0.3, 0.45)  # angular step, drawn per room: 1.6-2.4 cm between points at 3 m
LASER_ELEVATION_DEG = (-60.0, 90.0)  # the tripod hides the cone below
LASER_MIXED = 0.3  # share of the returns on a range edge that mix the two sides


def laser_scan(room: Room, rng: np.random.Generator) -> Scan:
    """A 360-degree terrestrial laser scan from 1-3 stations spread over the free floor, the scanner on a
    tripod 1.2-1.7 m up: rows and columns at one angular step (so the density falls with the square of the
    range), 3 mm range noise, mixed pixels on range edges, no colour, nothing through windows and doors (the
    rays leave the room and return nothing)."""
    raycaster = _raycaster(room)
    stations = free_positions(room, rng, int(rng.integers(1, 4)), clearance=0.4)
    eyes = np.column_stack([stations, rng.uniform(1.2, 1.7, len(stations))])
    step = np.radians(rng.uniform(*LASER_STEP_DEG))
    points = np.concatenate([laser_station(raycaster, eye, step, rng) for eye in eyes])
    return Scan(points, _grey(len(points)), eyes, f"{len(eyes)} stations, {np.degrees(step):.2f} deg")


def laser_station(raycaster: Raycaster, eye: np.ndarray, step: float, rng: np.random.Generator) -> np.ndarray:
    """One station's points (N, 3), world frame: a range image of elevation rows by azimuth columns."""
    low, high = np.radians(LASER_ELEVATION_DEG)
    elevation = np.arange(low, high, step)
    azimuth = np.arange(0.0, 2 * np.pi, step) + rng.uniform(0, step)  # where the head starts is arbitrary
    el, az = np.meshgrid(elevation, azimuth, indexing="ij")
    directions = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1)
    distance, _, _ = raycaster.cast(np.broadcast_to(eye, directions.shape), directions)
    valid = np.isfinite(distance) & (distance > LASER_RANGE[0]) & (distance < LASER_RANGE[1])
    distance = np.where(valid, distance, 0.0)
    distance = mix_edges(distance, valid, rng, LASER_MIXED)
    ranges = distance[valid] + rng.normal(0, LASER_SIGMA, int(valid.sum()))
    return eye + directions[valid] * ranges[:, None]


# -- frames: one or a few raw depth frames from one spot -----------------------------------------------------


def frames_scan(room: Room, rng: np.random.Generator) -> Scan:
    """1-3 unfused VGA Kinect frames from one spot 1.0-2.5 m from a labelled piece (a desk, a sofa), the
    camera 1.0-1.7 m up and aimed at the piece's top (each frame a little elsewhere on it): what one organised
    frame of a desk is, every pixel kept."""
    raycaster = _raycaster(room)
    camera = DepthCamera().with_kinect_noise()
    piece, spot = _piece_and_spot(room, rng)
    eye = np.array([*spot, rng.uniform(1.0, 1.7)])
    poses = [look_at(eye, aim_at_piece(piece, eye, rng)) for _ in range(int(rng.integers(1, 4)))]
    points, colors = [], []
    for pose in poses:
        depth, box = depth_frame(raycaster, camera, pose, rng)
        points.append(backproject(depth, camera, perturbed(pose, rng, (0.002, 0.1))))
        colors.append(raycaster.colors[box[depth > 0]])
    return Scan(np.concatenate(points), np.concatenate(colors), _eyes(poses), f"{len(poses)} frames")


def _piece_and_spot(
    room: Room, rng: np.random.Generator, band: tuple[float, float] = (1.0, 2.5), nearest: float = 1.8
):
    """A labelled piece (any piece in a room with none) and a free floor spot `band` m from its centre (the
    free spot nearest `nearest` m when none is in the band)."""
    pieces = [piece for piece in room.pieces if piece.anchors] or room.pieces
    piece = pieces[int(rng.integers(len(pieces)))] if pieces else None
    free = free_floor(room, rng)
    if piece is None:
        return None, free[int(rng.integers(len(free)))]
    lo, hi = piece.local_bounds()
    distance = np.linalg.norm(free - piece.world_point((lo + hi) / 2), axis=1)
    within = np.flatnonzero((distance > band[0]) & (distance < band[1]))
    spot = free[int(rng.choice(within))] if len(within) else free[int(np.abs(distance - nearest).argmin())]
    return piece, spot


# -- sweep: a few raw frames panned across the room from its edge --------------------------------------------

SWEEP_FRAMES = (3, 7)  # frames per sweep, drawn per room (upper bound excluded)
SWEEP_DISTANCE = (2.5, 4.5)  # m from the piece the sweep is centred on: across a room, to the Kinect's limit
SWEEP_PAN = 12.0  # degrees at most between one frame's heading and the next
SWEEP_STRIDE = 0.15  # m at most a hand-held camera moves between frames


def sweep_scan(room: Room, rng: np.random.Generator) -> Scan:
    """3-6 unfused VGA Kinect frames of a hand-held sweep from a spot 2.5-4.5 m from a labelled piece: the
    camera 1.2-1.7 m up, panned across the room a few degrees a frame and carried a few centimetres, each
    frame registered with a visual odometry's small error. What a short RGB-D capture of a room is (the few
    posed frames of an SLAM tutorial's data set): far surfaces at the sensor's noisiest, seats seen over
    tables and from behind, most of the floor plan never seen."""
    raycaster = _raycaster(room)
    camera = DepthCamera().with_kinect_noise()
    piece, spot = _piece_and_spot(room, rng, SWEEP_DISTANCE, nearest=3.5)
    eye = np.array([*spot, rng.uniform(1.2, 1.7)])
    target = aim_at_piece(piece, eye, rng)
    count = int(rng.integers(*SWEEP_FRAMES))
    pan = np.radians(rng.uniform(-SWEEP_PAN, SWEEP_PAN)) * (np.arange(count) - (count - 1) / 2)
    heading = rng.uniform(0, 2 * np.pi)
    carried = np.outer(np.arange(count) - (count - 1) / 2, [np.cos(heading), np.sin(heading), 0.0])
    carried *= rng.uniform(0, SWEEP_STRIDE)
    points, colors, poses = [], [], []
    for turn, offset in zip(pan, carried, strict=True):
        c, s = np.cos(turn), np.sin(turn)
        ahead = target - eye
        turned = np.array([c * ahead[0] - s * ahead[1], s * ahead[0] + c * ahead[1], ahead[2]])
        pose = look_at(eye + offset, eye + offset + turned)
        depth, box = depth_frame(raycaster, camera, pose, rng)
        points.append(backproject(depth, camera, perturbed(pose, rng, (0.005, 0.3))))
        colors.append(raycaster.colors[box[depth > 0]])
        poses.append(pose)
    return Scan(np.concatenate(points), np.concatenate(colors), _eyes(poses), f"a sweep of {count} frames")


# -- walk: a robot's walk through the assembler --------------------------------------------------------------

WALK_FRAMES = (60, 81)  # frames per walk, drawn per room (a frame costs 0.2-0.3 s: depth and registration)
WALK_STEP = 0.021  # m between frames: every third frame of a 0.2 m/s walk at 30 Hz
WALK_RATE = 10.0  # frames a second, the stamps given to the assembler
# the walk stops where the assembler has drifted this far from the truth: the room's labels are the true
# room's, and a real labeller labels the map it is given, so a map smeared past this would teach false places
WALK_MAX_DRIFT = 0.05  # m


# wheel odometry's error per frame: translation (share of the step, per axis) and rotation (degrees)
ODOMETRY_ERROR = (0.05, 0.1)


def walk_scan(room: Room, rng: np.random.Generator) -> Scan:
    """A robot's walk round a loop through the room (`scanner.trajectory`), VGA depth frames with the full
    Kinect noise, registered by the project's own assembler (KISS-ICP) with gravity from an IMU and the
    robot's drifting wheel odometry as its pose guess, rather than placed at their true poses: the map is
    what the assembler built, partial and drifting."""
    poses = trajectory(room, rng, int(rng.integers(*WALK_FRAMES)), step=WALK_STEP)
    return assemble_walk(_raycaster(room), poses, rng, guesses=odometry(poses, rng))


def odometry(poses: list[np.ndarray], rng: np.random.Generator) -> list[np.ndarray]:
    """Wheel odometry along the true `poses`: each true motion between frames with an error of
    `ODOMETRY_ERROR`, summed up, so the guess drifts further the further the robot goes. Without a guess the
    assembler predicts constant velocity, and KISS-ICP cannot tell how far a camera that sees little but the
    floor moved along it (a generated office walk stood still: 1.2 m off after 1.3 m)."""
    share, degrees = ODOMETRY_ERROR
    guesses = [poses[0]]
    for before, after in zip(poses[:-1], poses[1:]):
        motion = np.linalg.inv(before) @ after
        step = float(np.linalg.norm(motion[:3, 3]))
        guesses.append(guesses[-1] @ perturbed(motion, rng, (share * step, degrees)))
    return guesses


def assemble_walk(
    raycaster: Raycaster,
    poses: list[np.ndarray],
    rng: np.random.Generator,
    camera: DepthCamera | None = None,
    guesses: list[np.ndarray] | None = None,
) -> Scan:
    """Depth frames at the true `poses` through `Assembler.add`, as the assembler service takes them (16-bit
    millimetres). The assembler's odometry frame is the first accepted frame's camera frame, so that frame's
    true pose brings its map (and its trajectory: the origins) into the room's frame; every later error is
    the assembler's own drift. `guesses`: the robot's odometry, world_from_camera per frame (a frame's
    SensorFrame.pose_guess). A frame the assembler refuses is left out, as the service leaves it out."""
    from ..assembly.assembler import Assembler, SensorFrame
    from ..assembly.depth import DepthImage

    camera = camera or DepthCamera().with_kinect_noise()
    assembler, first = Assembler(), None
    for k, pose in enumerate(poses):
        depth, _ = depth_frame(raycaster, camera, pose, rng)
        image = DepthImage(np.round(depth * 1000).astype(np.uint16), camera.intrinsics)
        down = pose[:3, :3].T @ np.array([0.0, 0.0, -1.0])  # what an IMU on the camera reports
        try:
            guess = None if guesses is None else guesses[k]
            frame = SensorFrame("camera", k / WALK_RATE, depth=image, gravity=down, pose_guess=guess)
            assembler.add(frame, k / WALK_RATE)
        except ValueError:
            continue
        first = pose if first is None else first
        if _drift(assembler, np.linalg.inv(first) @ pose) > WALK_MAX_DRIFT:
            break
    if first is None:
        raise RuntimeError("the assembler refused every frame of the walk")
    points = assembler.map_points() @ first[:3, :3].T + first[:3, 3]
    origins = np.array([(first @ pose)[:3, 3] for pose in assembler.trajectory.poses])
    views = f"{assembler.frames} of {len(poses)} frames assembled"
    return Scan(points, _grey(len(points)), origins, views)


def _drift(assembler, odom_from_camera: np.ndarray) -> float:
    """How far (m) the assembler's latest pose is from the true one, both in its odometry frame."""
    return float(np.linalg.norm(assembler.trajectory.poses[-1][:3, 3] - odom_from_camera[:3, 3]))


STYLES: dict[str, Callable[[Room, np.random.Generator], Scan]] = {
    "fused": fused_scan,
    "mesh": mesh_scan,
    "laser": laser_scan,
    "frames": frames_scan,
    "walk": walk_scan,
    "sweep": sweep_scan,
}
