"""A virtual depth camera (and a spinning LiDAR) that sees a generated room the way a real sensor would.

The room's boxes become one triangle mesh in an open3d ray-casting scene. A depth frame casts one ray per
pixel (jittered by the lateral noise), keeps the first hit, and then applies what a Kinect-class sensor does
to it: range limits (0.5 to 4.5 m), axial noise growing with the square of the range (Nguyen, Izadi & Lovell
2012: sigma(z) = 0.0012 + 0.0019 (z - 0.4)^2 m, which already includes the disparity quantisation, so only the
remainder is added as Gaussian noise before quantising to steps of 2.85e-3 z^2 m), no return
at grazing incidence (beyond 80 degrees), and random dropouts. Occlusion is exact, so what the camera never
sees (under tables, behind sofas, the far side of a chair back) is missing as in real scans.

A room scan fuses frames from several person-height viewpoints in free space and thins the result to one
point per 1 cm voxel (the mean), like the real rooms in ../shared/data (fused at 1 to 1.5 cm). Uniform
surface sampling is the cheap alternative: every face of every box, no occlusion, no noise.

Camera frame: x right, y down, z forward (OpenCV, 7-Scenes). LiDAR frame: x forward, y left, z up (ROS).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..geometry.scene import voxel_thin
from .rooms import Room, inside_polygon
from .shapes import Box, overlaps_any

FUSION_VOXEL = 0.01
# A Kinect v1's faults beyond axial noise, quantisation and grazing: half the pixels on a depth edge mix the
# two sides (its 9 x 9 correlation window straddles the edge), 3 % of the image is lost in patches, black
# surfaces lose half their returns, and at the 4.5 m limit a third are gone (the speckle is too faint).
KINECT_NOISE = {"flying": 0.5, "blob_dropout": 0.03, "dark_dropout": 0.5, "far_dropout": 0.3}
EDGE_JUMP = 0.05  # m: neighbouring pixels further apart than this in depth straddle an edge


@dataclass(frozen=True)
class DepthCamera:
    width: int = 640
    height: int = 480
    fx: float = 585.0
    fy: float = 585.0
    cx: float = 320.0
    cy: float = 240.0
    min_range: float = 0.5
    max_range: float = 4.5
    lateral_px: float = 0.5
    dropout: float = 0.02
    grazing_deg: float = 80.0
    noisy: bool = True
    # What the defaults leave out (they are the model every fused room was made with): mixed ("flying")
    # pixels, the share of pixels at a depth edge that return a depth between the two sides; and missing
    # returns in patches rather than single pixels: a base share, more on dark surfaces (by the share lost
    # on black) and beyond 3.5 m (by the share lost at 4.5 m). `kinect_noise()` turns them on.
    flying: float = 0.0
    blob_dropout: float = 0.0
    dark_dropout: float = 0.0
    far_dropout: float = 0.0
    # A reconstruction (TSDF fusion) averages each surface over many frames: its axial noise is a single
    # frame's over the square root of their number, and the disparity steps average out (no quantisation).
    averaged_frames: int = 1

    @classmethod
    def qvga(cls, **changes) -> DepthCamera:
        """The same sensor at 320 x 240 (Kinect's QVGA depth mode): a quarter of the rays, for fused room
        scans where 1 cm fusion voxels are coarser than a VGA pixel's footprint anyway."""
        return cls(width=320, height=240, fx=292.5, fy=292.5, cx=160.0, cy=120.0, lateral_px=0.25, **changes)

    def with_kinect_noise(self) -> DepthCamera:
        """The same camera with the full noise model: flying pixels and patchy missing returns as well."""
        return replace(self, **KINECT_NOISE)

    @property
    def intrinsics(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])


def axial_sigma(depth: np.ndarray) -> np.ndarray:
    """Kinect v1 axial noise (m) at a given depth (m)."""
    return 0.0012 + 0.0019 * (depth - 0.4) ** 2


class Raycaster:
    """All boxes of a room as one mesh; a hit reports the box it struck (for colour) and the surface
    normal."""

    def __init__(self, boxes: list[Box]):
        import open3d as o3d

        vertices, triangles = [], []
        for index, box in enumerate(boxes):
            v, t = box.mesh_arrays()
            vertices.append(v)
            triangles.append(t + 8 * index)
        self.colors = np.array([box.color for box in boxes], dtype=np.float32)
        mesh = o3d.t.geometry.TriangleMesh()
        mesh.vertex.positions = o3d.core.Tensor(np.vstack(vertices).astype(np.float32))
        mesh.triangle.indices = o3d.core.Tensor(np.vstack(triangles).astype(np.int32))
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(mesh)

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Distance along each direction (in units of its length; inf for a miss), box index, unit normal."""
        import open3d as o3d

        rays = np.concatenate([origins, directions], axis=-1).astype(np.float32)
        hit = self.scene.cast_rays(o3d.core.Tensor(rays), nthreads=0)
        distance = hit["t_hit"].numpy().astype(np.float64)
        box = (hit["primitive_ids"].numpy().astype(np.int64) // 12).clip(0, len(self.colors) - 1)
        return distance, box, hit["primitive_normals"].numpy().astype(np.float64)


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Camera-to-world (4 x 4) for an OpenCV camera at `eye` looking at `target`, image upright (z is up)."""
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([right, down, forward])
    pose[:3, 3] = eye
    return pose


def depth_frame(
    raycaster: Raycaster, camera: DepthCamera, cam_to_world: np.ndarray, rng: np.random.Generator
):
    """(depth (H, W) in metres with 0 where nothing was measured, box index (H, W) of each hit)."""
    v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(np.float64)
    if camera.noisy and camera.lateral_px > 0:
        u = u + rng.normal(0, camera.lateral_px, u.shape)
        v = v + rng.normal(0, camera.lateral_px, v.shape)
    rays_cam = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], axis=-1)
    directions = rays_cam @ cam_to_world[:3, :3].T  # z component 1 in the camera: distance = depth
    origins = np.broadcast_to(cam_to_world[:3, 3], directions.shape)
    depth, box, normal = raycaster.cast(origins, directions)
    valid = np.isfinite(depth) & (depth >= camera.min_range) & (depth <= camera.max_range)
    if camera.noisy:
        unit = directions / np.linalg.norm(directions, axis=-1, keepdims=True)
        incidence = np.abs(np.einsum("hwi,hwi->hw", unit, normal))
        valid &= incidence > np.cos(np.radians(camera.grazing_deg))
        valid &= rng.random(depth.shape) >= camera.dropout
        if camera.blob_dropout or camera.dark_dropout or camera.far_dropout:
            valid &= ~patchy_dropouts(depth, raycaster.colors[box], camera, rng)
        if camera.flying:
            depth = mix_edges(depth, valid, rng, camera.flying)
        depth = np.where(valid, depth, 1.0)  # placeholder where nothing returns, so the noise stays finite
        # Nguyen's sigma was measured on real output, quantisation included: add only the rest before
        # quantising.
        if camera.averaged_frames > 1:
            depth = depth + rng.normal(0, 1, depth.shape) * axial_sigma(depth) / np.sqrt(
                camera.averaged_frames
            )
        else:
            step = 2.85e-3 * depth**2
            extra = np.sqrt(np.maximum(axial_sigma(depth) ** 2 - step**2 / 12, 0.0))
            noisy = depth + rng.normal(0, 1, depth.shape) * extra
            depth = np.round(noisy / (2.85e-3 * noisy**2)) * (2.85e-3 * noisy**2)
    return np.where(valid, depth, 0.0), box


def mix_edges(depth: np.ndarray, valid: np.ndarray, rng: np.random.Generator, share: float) -> np.ndarray:
    """Flying pixels: of the valid pixels whose depth differs from a valid 4-neighbour's by more than
    `EDGE_JUMP`, a `share` return a depth between their own and that neighbour's (uniform between 10 and
    90 % of the way), as a sensor whose footprint straddles an edge averages the two sides. Works on any
    organised range image (a camera's depth, a laser's rows and columns of ranges)."""
    neighbour, jump = _largest_neighbour_jump(depth, valid)
    mixed = valid & (jump > EDGE_JUMP) & (rng.random(depth.shape) < share)
    towards = rng.uniform(0.1, 0.9, depth.shape)
    out = depth.copy()
    out[mixed] += towards[mixed] * (neighbour[mixed] - depth[mixed])
    return out


def _largest_neighbour_jump(depth: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel, the depth of the valid 4-neighbour that differs most from it, and by how much (-1: none)."""
    padded = np.pad(np.where(valid, depth, np.nan), 1, constant_values=np.nan)
    neighbours = np.stack([padded[:-2, 1:-1], padded[2:, 1:-1], padded[1:-1, :-2], padded[1:-1, 2:]])
    jump = np.nan_to_num(np.abs(neighbours - depth), nan=-1.0)
    which = jump.argmax(axis=0)[None]
    return np.take_along_axis(neighbours, which, 0)[0], np.take_along_axis(jump, which, 0)[0]


def patchy_dropouts(
    depth: np.ndarray,
    colors: np.ndarray,
    camera: DepthCamera,
    rng: np.random.Generator,
    patch_px: float = 6.0,
) -> np.ndarray:
    """Pixels (H, W) that return nothing, lost in patches: a smooth random field (white noise blurred over
    `patch_px` pixels, made uniform) falls below each pixel's chance of being lost, so neighbours go
    together, as glare, a dark stripe or a far, faint patch takes out a region and not a scatter of pixels.
    The chance: `blob_dropout` everywhere, up to `dark_dropout` more on dark surfaces (luminance below 0.3,
    all of it at 0.15 and below), and up to `far_dropout` more from 3.5 m to 4.5 m."""
    from scipy.ndimage import gaussian_filter
    from scipy.special import ndtr

    field = gaussian_filter(rng.normal(size=depth.shape), patch_px)
    uniform = ndtr(field / field.std())
    luminance = colors @ np.array([0.299, 0.587, 0.114])
    chance = (
        camera.blob_dropout
        + camera.dark_dropout * np.clip((0.3 - luminance) / 0.15, 0.0, 1.0)
        + camera.far_dropout * np.clip(depth - 3.5, 0.0, 1.0)
    )
    return uniform < chance


def backproject(depth: np.ndarray, camera: DepthCamera, cam_to_world: np.ndarray | None = None) -> np.ndarray:
    """Points (N, 3) of the valid pixels, in the camera frame or, with a pose, in the world."""
    v, u = np.nonzero(depth > 0)
    z = depth[v, u]
    points = np.column_stack([(u - camera.cx) * z / camera.fx, (v - camera.cy) * z / camera.fy, z])
    if cam_to_world is not None:
        points = points @ cam_to_world[:3, :3].T + cam_to_world[:3, 3]
    return points


def free_floor(room: Room, rng: np.random.Generator, clearance: float = 0.35) -> np.ndarray:
    """Random floor positions (n, 2) where a person could stand with a sensor: `clearance` from everything."""
    low, high = room.polygon.min(axis=0), room.polygon.max(axis=0)
    candidates = rng.uniform(low, high, size=(400, 2))
    candidates = candidates[inside_polygon(room.polygon, candidates)]
    people = [Box((p[0], p[1], 1.0), (2 * clearance, 2 * clearance, 2.0)) for p in candidates]
    free = candidates[~overlaps_any(people, room.furniture_boxes() + room.walls)]
    if not len(free):
        raise RuntimeError(f"{room.name}: no free floor to scan from")
    return free


def free_positions(room: Room, rng: np.random.Generator, count: int, clearance: float = 0.35) -> np.ndarray:
    """Up to `count` floor positions where a person could stand with a sensor, spread out (farthest-point)."""
    free = free_floor(room, rng, clearance)
    chosen = [int(rng.integers(len(free)))]
    distance = np.linalg.norm(free - free[chosen[0]], axis=1)
    while len(chosen) < min(count, len(free)):
        chosen.append(int(distance.argmax()))
        distance = np.minimum(distance, np.linalg.norm(free - free[chosen[-1]], axis=1))
    return free[chosen]


VIEW_REGIMES = ("full", "few")


def viewpoints(
    room: Room, rng: np.random.Generator, count: int | None = None, turns: int = 3, regime: str = "full"
) -> list[np.ndarray]:
    """Camera poses for a room scan. ``full``: person-height cameras spread over the free floor; at each spot
    the person turns round in `turns` steps, the first aimed at a piece of furniture, pitched 15 to 35 degrees
    down (the floor near walls shows, as in real scans). ``few``: `few_viewpoints`."""
    if regime == "few":
        return few_viewpoints(room, rng, count)
    if regime != "full":
        raise ValueError(f"regime must be one of {', '.join(VIEW_REGIMES)}, not {regime!r}")
    area = abs(_polygon_area(room.polygon))
    count = count or int(np.clip(round(area / 6) + 2, 3, 10))
    targets = [box.centre for box in room.furniture_boxes()] or [(*room.polygon.mean(axis=0), 0.5)]
    poses = []
    for eye_xy in free_positions(room, rng, count):
        eye = np.array([*eye_xy, rng.uniform(1.2, 1.7)])
        aim = np.array(targets[int(rng.integers(len(targets)))][:2]) - eye_xy
        heading = np.arctan2(aim[1], aim[0]) if np.linalg.norm(aim) > 0.3 else rng.uniform(0, 2 * np.pi)
        for turn in range(turns):
            yaw = heading + 2 * np.pi * turn / turns + rng.normal(0, 0.15)
            pitch = -np.radians(rng.uniform(15, 35))
            direction = np.array([np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), np.sin(pitch)])
            poses.append(look_at(eye, eye + direction))
    return poses


def few_viewpoints(room: Room, rng: np.random.Generator, count: int | None = None) -> list[np.ndarray]:
    """A short hand-held capture, the way the real rooms were taken (the NYU room is 5 frames, the kitchen a
    few metres of one walk): 3 to 8 frames from spots 0.4 to 1.5 m apart along a walk, the camera at one
    person's height (1.0 to 1.7 m, drawn per room) aimed at pieces of furniture, labelled ones more often.
    Whatever none of the frames sees (the far side of the room, the floor under most tables) is missing."""
    count = count or int(rng.integers(3, 9))
    free = free_floor(room, rng)
    height = rng.uniform(1.0, 1.7)
    pieces = [piece for piece in room.pieces if piece.anchors] or room.pieces
    spot = free[int(rng.integers(len(free)))]
    poses = []
    for _ in range(count):
        choices = pieces if rng.random() < 0.6 else room.pieces
        piece = choices[int(rng.integers(len(choices)))] if choices else None
        eye = np.array([*spot, height + rng.normal(0, 0.03)])
        target = aim_at_piece(piece, eye, rng)
        poses.append(look_at(eye, target))
        step = np.linalg.norm(free - spot, axis=1)
        near = np.flatnonzero((step > 0.4) & (step < 1.5))
        spot = free[int(rng.choice(near))] if len(near) else spot
    return poses


def aim_at_piece(piece, eye: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A point 0.6-1.1 m up over the piece's centre (a person frames a table or a sofa by its top, not by the
    floor under it), or (no piece, or one too close to aim at) straight ahead in a random direction, pitched
    15-35 degrees down."""
    if piece is not None:
        lo, hi = piece.local_bounds()
        target = np.array([*piece.world_point((lo + hi) / 2), rng.uniform(0.6, 1.1)])
        if np.linalg.norm(target[:2] - eye[:2]) > 0.8:
            return target
    yaw, pitch = rng.uniform(0, 2 * np.pi), -np.radians(rng.uniform(15, 35))
    return eye + np.array([np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), np.sin(pitch)])


def scan_room(
    room: Room,
    rng: np.random.Generator,
    camera: DepthCamera | None = None,
    views: int | None = None,
    registration_error: tuple[float, float] = (0.005, 0.3),
    regime: str = "full",
) -> tuple[np.ndarray, np.ndarray]:
    """Fused, thinned points (N, 3) and colours (N, 3) of depth frames from the `regime`'s viewpoints.

    Each frame is fused with its pose off by `registration_error` (metres, degrees; standard deviations), as
    a real fusion's poses are: surfaces seen from two places come out slightly thick or doubled."""
    raycaster = Raycaster(room.shell_boxes() + room.furniture_boxes())
    poses = viewpoints(room, rng, views, regime=regime)
    return fuse_frames(raycaster, poses, rng, camera, registration_error)


def fuse_frames(
    raycaster: Raycaster,
    poses: list[np.ndarray],
    rng: np.random.Generator,
    camera: DepthCamera | None = None,
    registration_error: tuple[float, float] = (0.005, 0.3),
    voxel: float = FUSION_VOXEL,
) -> tuple[np.ndarray, np.ndarray]:
    """One depth frame per camera pose, each placed with its pose off by `registration_error`, thinned to
    the mean point and colour per `voxel`."""
    camera = camera or DepthCamera.qvga()
    points, colors = [], []
    for pose in poses:
        depth, box = depth_frame(raycaster, camera, pose, rng)
        points.append(backproject(depth, camera, perturbed(pose, rng, registration_error)))
        colors.append(raycaster.colors[box[depth > 0]])
    return voxel_thin(np.concatenate(points), voxel, np.concatenate(colors))


def floor_under_furniture(room: Room, cell: float = 0.05) -> np.ndarray:
    """Centres (n, 2) of the `cell` m floor cells under a table top or a seat: under a furniture part whose
    underside is 0.25-1.05 m up and that is at least 0.09 m^2 in plan, but not under anything standing on the
    floor (legs, pedestals, a counter's body: no floor there to see)."""
    low, high = room.polygon.min(axis=0), room.polygon.max(axis=0)
    xs, ys = np.arange(low[0], high[0], cell) + cell / 2, np.arange(low[1], high[1], cell) + cell / 2
    centres = np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1).reshape(-1, 2)
    under, standing = np.zeros(len(centres), bool), np.zeros(len(centres), bool)
    for box in room.furniture_boxes():
        bottom, top = box.z_range
        if 0.25 <= bottom and top <= 1.05 and box.size[0] * box.size[1] >= 0.09:
            under |= box.contains_xy(centres)
        elif bottom < 0.02:
            standing |= box.contains_xy(centres)
    return centres[under & ~standing]


def floor_seen_share(room: Room, points: np.ndarray, cell: float = 0.05) -> tuple[float, int]:
    """(share of the floor cells under tables and seats holding a floor point (z < 3 cm), how many cells)."""
    cells = floor_under_furniture(room, cell)
    if not len(cells):
        return float("nan"), 0
    low = room.polygon.min(axis=0)
    shape = np.ceil((room.polygon.max(axis=0) - low) / cell).astype(int) + 1
    index = np.floor((points[np.abs(points[:, 2]) < 0.03, :2] - low) / cell).astype(int)
    index = index[np.all((index >= 0) & (index < shape), axis=1)]
    seen = np.zeros(shape, bool)
    seen[index[:, 0], index[:, 1]] = True
    cell_index = np.floor((cells - low) / cell).astype(int)
    return float(seen[cell_index[:, 0], cell_index[:, 1]].mean()), len(cells)


def perturbed(pose: np.ndarray, rng: np.random.Generator, error: tuple[float, float]) -> np.ndarray:
    """A pose moved by a random translation and rotation of the given standard deviations (m, degrees)."""
    translation, degrees = error
    axis = rng.normal(size=3)
    angle = np.radians(rng.normal(0, degrees))
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]]) / np.linalg.norm(
        axis
    )
    out = pose.copy()
    out[:3, :3] = (np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k) @ pose[:3, :3]
    out[:3, 3] += rng.normal(0, translation, 3)
    return out


def sample_room_uniform(
    room: Room, rng: np.random.Generator, points_per_m2: float = 2500.0
) -> tuple[np.ndarray, np.ndarray]:
    """Points spread uniformly over every face of every box (no occlusion, no noise): the cheap option."""
    points, colors = [], []
    for box in room.shell_boxes() + room.furniture_boxes():
        vertices, triangles = box.mesh_arrays()
        if box.z_range[1] <= 0.0:  # the floor slab: only its top face, not the underside below the floor
            triangles = triangles[vertices[triangles].min(axis=1)[:, 2] >= 0.0]
        a, b, c = (vertices[triangles[:, k]] for k in range(3))
        areas = np.linalg.norm(np.cross(b - a, c - a), axis=1) / 2
        counts = rng.poisson(areas * points_per_m2)
        which = np.repeat(np.arange(len(triangles)), counts)
        r1, r2 = rng.random((2, len(which)))
        flip = r1 + r2 > 1
        r1, r2 = np.where(flip, 1 - r1, r1), np.where(flip, 1 - r2, r2)
        points.append(a[which] + r1[:, None] * (b - a)[which] + r2[:, None] * (c - a)[which])
        colors.append(np.tile(np.array(box.color, np.float32), (len(which), 1)))
    return np.concatenate(points), np.concatenate(colors)


def walkable(
    room: Room, resolution: float = 0.05, body_radius: float = 0.30
) -> tuple[np.ndarray, np.ndarray]:
    """Cell centres (nx, ny, 2) of a plan raster and whether a person can stand there: inside the room and at
    least `body_radius` from every wall and every piece below head height (a table too: nobody walks through
    it)."""
    low, high = room.polygon.min(axis=0), room.polygon.max(axis=0)
    xs, ys = np.arange(low[0], high[0], resolution), np.arange(low[1], high[1], resolution)
    cells = np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1)
    free = inside_polygon(room.polygon, cells.reshape(-1, 2)).reshape(cells.shape[:2])
    for box in room.walls + room.furniture_boxes():
        if box.z_range[0] > 1.9:
            continue
        local = (cells - box.centre[:2]) @ np.array(
            [[np.cos(box.yaw), -np.sin(box.yaw)], [np.sin(box.yaw), np.cos(box.yaw)]]
        )
        outside = np.maximum(np.abs(local) - np.array(box.size[:2]) / 2, 0.0)
        free &= np.linalg.norm(outside, axis=-1) > body_radius
    return cells, free


def trajectory(room: Room, rng: np.random.Generator, frames: int, step: float = 0.007) -> list[np.ndarray]:
    """A hand-held camera carried round a loop through free space at 7 mm per frame (a slow walk at 30 Hz,
    like the 7-Scenes sequences), looking across the room (towards the loop's centre, swaying up to 45
    degrees either side) and pitched 22-38 degrees down, as a person scanning a room frames its floor and
    furniture (held more level, a walk through a cluttered room sees too little floor to level its map, and
    KISS-ICP drifts on the walls). The loop is the longest ellipse, of random candidates, that never comes
    within a body's width of a wall or a piece of furniture."""
    cells, free = walkable(room)
    origin, resolution = cells[0, 0], cells[1, 0, 0] - cells[0, 0, 0]
    candidates = cells[free]
    if len(candidates) == 0:
        raise RuntimeError(f"{room.name}: nowhere to walk")
    best, best_length = None, 0.0
    for _ in range(150):
        centre = candidates[int(rng.integers(len(candidates)))]
        radii, turn = rng.uniform(0.2, 1.6, 2), rng.uniform(0, np.pi)
        angles = np.linspace(0, 2 * np.pi, 400, endpoint=False)
        loop = centre + np.column_stack([radii[0] * np.cos(angles), radii[1] * np.sin(angles)]) @ np.array(
            [[np.cos(turn), np.sin(turn)], [-np.sin(turn), np.cos(turn)]]
        )
        index = np.round((loop - origin) / resolution).astype(int)
        inside = np.all((index >= 0) & (index < free.shape), axis=1)
        if not inside.all() or not free[index[:, 0], index[:, 1]].all():
            continue
        length = float(np.linalg.norm(np.diff(np.vstack([loop, loop[:1]]), axis=0), axis=1).sum())
        if length > best_length:
            best, best_length = (centre, loop), length
    if best is None:  # no room for a loop: walk to and fro along the longest free straight line
        best = _to_and_fro(candidates, free, origin, resolution, rng)
        if best is None:
            raise RuntimeError(f"{room.name}: no free path to walk")
    centre, loop = best
    dense = _resample(np.vstack([loop, loop[:1]]), step)
    poses = []
    height = rng.uniform(1.3, 1.6)
    for k in range(frames):
        position = dense[k % len(dense)]
        across = centre - position if np.linalg.norm(centre - position) > 0.2 else np.array([1.0, 0.0])
        heading = np.arctan2(across[1], across[0]) + 0.8 * np.sin(k / 120.0)
        pitch = np.radians(-30 + 8 * np.sin(k / 150.0))
        eye = np.array([*position, height + 0.03 * np.sin(k / 45.0)])
        target = eye + np.array(
            [np.cos(heading) * np.cos(pitch), np.sin(heading) * np.cos(pitch), np.sin(pitch)]
        )
        poses.append(look_at(eye, target))
    return poses


def _to_and_fro(candidates, free, origin, resolution, rng):
    best, best_length = None, 0.0
    for _ in range(300):
        a, b = candidates[rng.integers(len(candidates), size=2)]
        line = a + np.linspace(0, 1, 200)[:, None] * (b - a)
        index = np.round((line - origin) / resolution).astype(int)
        length = float(np.linalg.norm(b - a))
        if length > best_length and free[index[:, 0], index[:, 1]].all():
            # look at a point off to the side of the line, so the view sweeps the room as the camera walks
            side = np.array([-(b - a)[1], (b - a)[0]]) / max(length, 1e-9)
            best, best_length = ((a + b) / 2 + side, np.vstack([line, line[::-1]])), length
    return best


def _resample(path: np.ndarray, step: float) -> np.ndarray:
    """A polyline resampled at a fixed arc length."""
    arc = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    samples = np.arange(0, arc[-1], step)
    return np.column_stack([np.interp(samples, arc, path[:, 0]), np.interp(samples, arc, path[:, 1])])


def lidar_scan(
    raycaster: Raycaster,
    sensor_to_world: np.ndarray,
    rng: np.random.Generator,
    beams: int = 16,
    vertical_fov_deg: float = 30.0,
    columns: int = 1800,
    max_range: float = 30.0,
    sigma: float = 0.015,
) -> np.ndarray:
    """One revolution of a spinning multi-beam LiDAR: points (N, 3) in the sensor frame (x forward, z up)."""
    elevation = np.radians(np.linspace(-vertical_fov_deg / 2, vertical_fov_deg / 2, beams))
    azimuth = np.linspace(-np.pi, np.pi, columns, endpoint=False)
    el, az = np.meshgrid(elevation, azimuth, indexing="ij")
    local = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1)
    directions = local @ sensor_to_world[:3, :3].T
    origins = np.broadcast_to(sensor_to_world[:3, 3], directions.shape)
    distance, _, _ = raycaster.cast(origins, directions)
    valid = np.isfinite(distance) & (distance > 0.3) & (distance < max_range)
    ranges = distance[valid] + rng.normal(0, sigma, valid.sum())
    return local[valid] * ranges[:, None]


def _polygon_area(polygon: np.ndarray) -> float:
    x, y = polygon[:, 0], polygon[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
