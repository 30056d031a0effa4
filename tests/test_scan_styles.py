"""The scan styles (affordcore/synth/styles.py) and the Kinect noise they use: each style looks like the
sensor it imitates (mesh: sparse on flat surfaces, dense at edges; laser: density falling with range, no
colour; frames: one spot; walk: the assembler's drifting map), flying pixels only at depth edges, dropouts in
patches, styles dealt by index, and the same seed giving the same bytes."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
from scipy.spatial import cKDTree

from affordcore.synth.batch import synthesize
from affordcore.synth.dataset import SynthOptions
from affordcore.synth.rooms import generate_room, inside_polygon
from affordcore.synth.scanner import (
    EDGE_JUMP,
    DepthCamera,
    Raycaster,
    axial_sigma,
    depth_frame,
    look_at,
    mix_edges,
    patchy_dropouts,
    scan_room,
    trajectory,
)
from affordcore.synth.shapes import Box
from affordcore.synth.styles import (
    GREY,
    STYLES,
    SWEEP_STRIDE,
    WALK_STEP,
    assemble_walk,
    edge_samples,
    frames_scan,
    fused_scan,
    laser_station,
    mesh_scan,
    odometry,
    sweep_scan,
)

# a wall 3 m in front of the camera with a box 1.5 m in front of it: depth edges round the box's outline
WALL_AND_BOX = [Box.span((-4, 3.0, -3), (4, 3.1, 3)), Box.span((-0.3, 1.5, -0.3), (0.3, 1.8, 0.3))]
FACING_WALL = look_at(np.zeros(3), np.array([0.0, 1.0, 0.0]))


def _room(kind: str = "workshop", seed: int = 3):
    rng = np.random.default_rng(seed)
    return generate_room(kind, rng, f"{kind}-{seed}"), rng


def _edge_pixels(depth: np.ndarray, valid: np.ndarray, widen: int = 0) -> np.ndarray:
    """Pixels whose depth differs from a valid 4-neighbour's by more than EDGE_JUMP, grown by `widen`."""
    from scipy.ndimage import binary_dilation

    edge = np.zeros(depth.shape, bool)
    rows = valid[1:] & valid[:-1] & (np.abs(np.diff(depth, axis=0)) > EDGE_JUMP)
    columns = valid[:, 1:] & valid[:, :-1] & (np.abs(np.diff(depth, axis=1)) > EDGE_JUMP)
    edge[1:] |= rows
    edge[:-1] |= rows
    edge[:, 1:] |= columns
    edge[:, :-1] |= columns
    return binary_dilation(edge, iterations=widen) if widen else edge


# ---------------------------------------------------------------- the Kinect noise model


def test_flying_pixels_lie_only_on_depth_edges_and_between_the_two_sides():
    raycaster = Raycaster(WALL_AND_BOX)
    depth, _ = depth_frame(raycaster, DepthCamera(noisy=False), FACING_WALL, np.random.default_rng(0))
    valid = depth > 0
    mixed = mix_edges(depth, valid, np.random.default_rng(1), share=1.0)
    changed = mixed != depth
    edge = _edge_pixels(depth, valid)
    assert changed.sum() > 500  # the box's outline, both sides of it
    assert not (changed & ~edge).any()  # nothing moves off the edges
    # each moved pixel lies strictly between the box (about 1.5 m) and the wall (about 3 m)
    assert np.all((mixed[changed] > 1.5) & (mixed[changed] < 3.1))
    assert np.all(np.abs(mixed[changed] - depth[changed]) > 0.1 * EDGE_JUMP)


def test_the_full_kinect_noise_flies_at_edges_and_stays_within_the_axial_noise_elsewhere():
    raycaster = Raycaster(WALL_AND_BOX)
    truth, _ = depth_frame(raycaster, DepthCamera(noisy=False), FACING_WALL, np.random.default_rng(0))
    camera = DepthCamera(dropout=0.0, grazing_deg=90.0).with_kinect_noise()
    noisy, _ = depth_frame(raycaster, camera, FACING_WALL, np.random.default_rng(2))
    both = (noisy > 0) & (truth > 0)
    error = np.abs(noisy - truth)
    near_edge = _edge_pixels(truth, truth > 0, widen=3)  # lateral jitter moves an edge by a pixel or two
    far = both & ~near_edge
    assert np.all(error[far] < 6 * axial_sigma(truth[far]) + 2.85e-3 * truth[far] ** 2)
    flown = both & (error > 0.2)  # a mixed pixel: 10-90 % of the way across a 1.2-1.5 m step
    assert flown.sum() > 100 and not (flown & ~near_edge).any()


def test_dropouts_come_in_patches_and_more_on_dark_surfaces_and_far_away():
    shape = (480, 640)
    camera = DepthCamera(blob_dropout=0.05)
    light = np.full((*shape, 3), 0.8)
    lost = patchy_dropouts(np.full(shape, 2.0), light, camera, np.random.default_rng(0))
    assert 0.02 < lost.mean() < 0.10
    # a lost pixel's neighbour is lost far more often than the 5 % an independent draw would give
    assert (lost[:, 1:] & lost[:, :-1]).sum() / lost.sum() > 0.7
    camera = DepthCamera(dark_dropout=0.5, far_dropout=0.3)
    dark = patchy_dropouts(np.full(shape, 2.0), np.full((*shape, 3), 0.1), camera, np.random.default_rng(0))
    far = patchy_dropouts(np.full(shape, 4.5), light, camera, np.random.default_rng(0))
    near = patchy_dropouts(np.full(shape, 2.0), light, camera, np.random.default_rng(0))
    assert dark.mean() > 0.35 and far.mean() > 0.2 and near.mean() == 0.0


def test_the_default_camera_keeps_the_old_noise_model():
    camera = DepthCamera()
    assert (camera.flying, camera.blob_dropout, camera.dark_dropout, camera.far_dropout) == (0, 0, 0, 0)
    assert camera.averaged_frames == 1 and camera.with_kinect_noise().flying > 0


# ---------------------------------------------------------------- the styles


def test_fused_style_is_the_old_room_scan_draw_for_draw():
    room, rng = _room()
    before, after = copy.deepcopy(rng), copy.deepcopy(rng)
    points, colors = scan_room(room, before, regime="few")
    scan = fused_scan(room, after, "few")
    assert scan.points.tobytes() == points.tobytes() and scan.colors.tobytes() == colors.tobytes()
    assert before.random() == after.random()  # and the generator is left where it was
    assert 3 <= len(scan.origins) <= 8 and np.all((scan.origins[:, 2] > 0.9) & (scan.origins[:, 2] < 1.8))


def _per_m2(points: np.ndarray, probes: np.ndarray, radius: float = 0.05) -> np.ndarray:
    return cKDTree(points).query_ball_point(probes, radius, return_length=True) / (np.pi * radius**2)


def test_mesh_vertices_are_sparse_on_a_flat_floor_and_dense_at_edges():
    room, rng = _room()
    scan = mesh_scan(room, rng)
    to_edge, _ = cKDTree(edge_samples(room.shell_boxes() + room.furniture_boxes())).query(scan.points)
    floor = (scan.points[:, 2] < 0.03) & (to_edge > 0.10)
    edges = to_edge < 0.02
    assert floor.sum() > 100 and edges.sum() > 1000
    flat_density = np.median(_per_m2(scan.points, scan.points[floor]))
    edge_density = np.median(_per_m2(scan.points, scan.points[edges]))
    # flat: one vertex per 4-8 cm cell (150-630 per m^2); edges: one per 1.5 cm
    assert 100 < flat_density < 700 and edge_density > 4 * flat_density, (flat_density, edge_density)
    assert len(scan.origins) >= 3 and scan.colors.shape == scan.points.shape


def test_laser_density_falls_with_range_and_its_noise_is_millimetres():
    floor_and_walls = [Box.span((-8, -8, -0.1), (8, 8, 0)), Box.span((8, -8, 0), (8.1, 8, 3))]
    eye = np.array([0.0, 0.0, 1.5])
    points = laser_station(Raycaster(floor_and_walls), eye, np.radians(0.36), np.random.default_rng(0))
    floor = points[points[:, 2] < 0.05]
    distance = np.linalg.norm(floor[:, :2], axis=1)

    def per_m2(low: float, high: float) -> float:
        return np.sum((distance >= low) & (distance < high)) / (np.pi * (high**2 - low**2))

    assert per_m2(1.0, 1.5) > 5 * per_m2(3.0, 3.5) > 5 * per_m2(6.0, 6.5) > 0
    near = floor[distance < 3]
    assert np.std(near[:, 2]) < 0.005  # 3 mm along the ray, less in z at these angles
    assert not np.any(distance < 0.85)  # the tripod's cone: nothing steeper than 60 degrees down


def test_a_laser_scan_is_grey_has_its_stations_and_nothing_outside_the_room():
    from affordcore.synth.styles import laser_scan

    room, rng = _room("office", 5)
    scan = laser_scan(room, rng)
    assert np.all(scan.colors == np.array(GREY, np.float32))
    assert 1 <= len(scan.origins) <= 3 and np.all((scan.origins[:, 2] >= 1.2) & (scan.origins[:, 2] <= 1.7))
    assert np.all(inside_polygon(room.polygon, scan.origins[:, :2]))
    # windows and the door are holes with nothing beyond: no return comes from outside the walls (10 cm)
    low, high = room.polygon.min(axis=0) - 0.12, room.polygon.max(axis=0) + 0.12
    assert np.all((scan.points[:, :2] > low) & (scan.points[:, :2] < high))


def test_frames_see_from_one_spot_only_what_lies_in_front():
    room, rng = _room("office", 5)
    scan = frames_scan(room, rng)
    assert 1 <= len(scan.origins) <= 3 and np.ptp(scan.origins, axis=0).max() == 0.0  # one spot
    eye = scan.origins[0]
    rays = scan.points - eye
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    ahead = rays.mean(axis=0) / np.linalg.norm(rays.mean(axis=0))
    # nothing behind the camera: every ray within a Kinect's half diagonal (about 35 degrees) of its own
    # frame's axis, and the frames' axes are close together
    assert np.degrees(np.arccos(np.clip(rays @ ahead, -1, 1))).max() < 70
    # depth (along the axis) stops at 4.5 m; a corner pixel's ray is 1.21 times longer
    assert np.linalg.norm(scan.points - eye, axis=1).max() < 4.5 * 1.25
    assert len(scan.points) > 50_000 * len(scan.origins)  # raw VGA frames, every pixel kept


def test_a_sweep_pans_a_few_frames_across_the_room_from_farther_than_frames_do():
    room, rng = _room("living", 4)
    sweep = sweep_scan(room, rng)
    frames = frames_scan(*_room("living", 4))
    eyes = sweep.origins
    assert 3 <= len(eyes) <= 6 and np.all((eyes[:, 2] >= 1.2) & (eyes[:, 2] <= 1.7))
    steps = np.linalg.norm(np.diff(eyes, axis=0), axis=1)
    assert np.all(steps <= SWEEP_STRIDE + 1e-9) and np.ptp(steps) < 1e-9  # carried evenly, a hand-held pace
    # panned: the frames look different ways (frames_scan's look at one piece from one spot)
    per_frame = np.array_split(sweep.points, len(eyes))  # frames of roughly equal size, in order
    axes = [(part - eye).mean(axis=0) for part, eye in zip(per_frame, eyes, strict=True)]
    headings = np.degrees([np.arctan2(a[1], a[0]) for a in axes])
    assert np.ptp(headings) > 3.0
    ranges = np.linalg.norm(sweep.points - eyes.mean(axis=0), axis=1)
    assert np.median(ranges) > np.median(np.linalg.norm(frames.points - frames.origins[0], axis=1))


@pytest.mark.slow
def test_a_walk_is_the_assembler_s_map_near_the_true_room_but_not_exact():
    import open3d as o3d

    room, rng = _room("living", 2)
    raycaster = Raycaster(room.shell_boxes() + room.furniture_boxes())
    poses = trajectory(room, rng, 60, step=WALK_STEP)
    scan = assemble_walk(raycaster, poses, rng, guesses=odometry(poses, rng))
    sample = scan.points[:: max(1, len(scan.points) // 5000)].astype(np.float32)
    distance = raycaster.scene.compute_distance(o3d.core.Tensor(sample)).numpy()
    # measured: 7 mm median, 7 cm at the 90th percentile (the far, noisy edges of the frames)
    assert np.median(distance) < 0.02 and np.quantile(distance, 0.9) < 0.10, np.quantile(distance, [0.5, 0.9])
    truth = np.array([pose[:3, 3] for pose in poses])
    assert len(scan.origins) == len(poses)  # every frame was taken
    drift = np.linalg.norm(scan.origins - truth, axis=1)
    assert drift[0] == pytest.approx(0.0, abs=1e-9)  # the first frame anchors the map
    assert 0.001 < drift.mean() < 0.10, drift  # registered, not placed at the true poses (measured 1.2 cm)
    assert np.all(scan.colors == np.array(GREY, np.float32))


# ---------------------------------------------------------------- data sets


def test_styles_are_dealt_by_index_so_every_kind_meets_every_style():
    options = SynthOptions(18, kinds=("living", "office", "workshop"))
    assert {options.style_of(i) for i in range(6)} == set(STYLES)
    pairs = {(options.room_name(i).split("-")[0], options.style_of(i)) for i in range(18)}
    assert len(pairs) == 18
    four_by_two = SynthOptions(8, kinds=("living", "office", "workshop", "mixed"), styles=("laser", "mesh"))
    assert len({(i % 4, four_by_two.style_of(i)) for i in range(8)}) == 8  # not locked kind to style
    with pytest.raises(ValueError, match="scan styles"):
        SynthOptions(1, styles=("fused", "photo"))


def test_same_seed_same_bytes_with_origins_and_styles_in_the_report(tmp_path):
    options = SynthOptions(2, 11, ("office", "workshop"), styles=("laser", "frames"))
    summaries = [synthesize(options, tmp_path / name) for name in ("a", "b")]
    names = sorted(path.name for path in (tmp_path / "a").iterdir() if path.is_file())
    assert {"office-000.origins.npy", "workshop-001.origins.npy"} <= set(names)
    for name in names:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    assert [room["style"] for room in summaries[0]["rooms"]] == ["laser", "frames"]
    assert summaries[0]["styles"] == ["laser", "frames"]
    origins = np.load(tmp_path / "a" / "office-000.origins.npy")
    assert origins.dtype == np.float32 and origins.shape[1] == 3
    assert summaries[0]["rooms"][0]["origins"] == len(origins)
    assert "| office-000 | office | laser |" in (tmp_path / "a" / "summary.md").read_text()
    assert json.loads((tmp_path / "a" / "summary.json").read_text())["rooms"][1]["style"] == "frames"


def test_uniform_samples_have_no_origins(tmp_path):
    summary = synthesize(SynthOptions(1, 2, ("office",), scanner="uniform"), tmp_path)
    assert np.load(tmp_path / "office-000.origins.npy").shape == (0, 3)
    assert summary["rooms"][0]["style"] == "uniform" and summary["styles"] == ["uniform"]


def test_the_command_refuses_an_unknown_style_before_writing_anything(tmp_path):
    import subprocess
    import sys

    out = tmp_path / "out"
    command = [sys.executable, "-m", "affordcli", "synth", "--rooms", "1", "--out", str(out), "--quiet"]
    result = subprocess.run(
        command + ["--styles", "fused,sketch"], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 2 and "sketch" in result.stderr and not out.exists()
