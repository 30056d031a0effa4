"""The room generator's invariants, its labels, the virtual scanner, and reproducibility of `afford synth`."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from affordcore.labels import load_labels, save_labels
from affordcore.skeleton import all_skeletons, get_skeleton, place_joints
from affordcore.synth import furniture as F
from affordcore.synth.rooms import KINDS, any_overlap, generate_room, inside_polygon, role_affordances
from affordcore.synth.scanner import (
    DepthCamera,
    Raycaster,
    axial_sigma,
    backproject,
    depth_frame,
    look_at,
    sample_room_uniform,
)
from affordcore.synth.shapes import Box, boxes_overlap

ROOMS = [(kind, seed) for kind in KINDS for seed in range(6)]


@pytest.fixture(scope="module")
def rooms():
    return [generate_room(kind, np.random.default_rng(seed), f"{kind}-{seed}") for kind, seed in ROOMS]


def test_no_furniture_intersects_furniture_or_walls(rooms):
    for room in rooms:
        for i, piece in enumerate(room.pieces):
            parts = piece.world_parts()
            corners = np.vstack([p.corners_xy() for p in parts])
            assert inside_polygon(room.polygon, corners).all(), f"{room.name}: {piece.kind} leaves the room"
            assert not any_overlap(parts, room.walls), f"{room.name}: {piece.kind} cuts a wall"
            for other in room.pieces[i + 1 :]:
                assert not any_overlap(parts, other.world_parts()), (
                    f"{room.name}: {piece.kind} hits {other.kind}"
                )


def test_every_label_has_room_for_its_skeleton(rooms):
    """The free space a label needs is clear of everything else, and its skeleton, placed anywhere along the
    label, puts no joint inside another piece or a wall."""
    roles = role_affordances()
    for room in rooms:
        for piece in room.pieces:
            others = room.walls + [
                p for other in room.pieces if other is not piece for p in other.world_parts()
            ]
            for anchor in piece.anchors:
                clearance = [box.placed(piece.x, piece.y, piece.yaw) for box in anchor.clearance]
                assert clearance and not any_overlap(clearance, others), (
                    f"{room.name}: {piece.note} has no room"
                )
                skeleton = get_skeleton(roles[anchor.role])
                for t in (0.0, 0.5, 1.0):
                    xy = piece.world_point(np.add(anchor.start, t * np.subtract(anchor.end, anchor.start)))
                    pose = np.array([[*xy, skeleton.torso_height, anchor.facing + piece.yaw]])
                    for joint in place_joints(skeleton.joints, pose)[0]:
                        dot = Box(tuple(joint), (0.02, 0.02, 0.02))
                        assert not any(boxes_overlap(dot, box) for box in others), (
                            f"{room.name}: {piece.note}"
                        )


def test_labels_are_valid_and_round_trip(rooms, tmp_path):
    known = {s.affordance for s in all_skeletons()}
    total = 0
    for room in rooms:
        path = tmp_path / f"{room.name}.labels.json"
        path.write_text(json.dumps(room.labels()))
        labels = load_labels(path)
        assert {label.affordance for label in labels.labels} <= known
        save_labels(tmp_path / "again.json", labels)
        assert load_labels(tmp_path / "again.json") == labels
        total += len(labels.labels)
    assert total >= 2 * len(rooms)  # rooms are not empty of affordances


def test_each_kind_yields_its_affordances(rooms):
    roles = role_affordances()
    by_kind = {kind: set() for kind in KINDS}
    for room in rooms:
        by_kind[room.kind] |= {label["affordance"] for label in room.labels()["labels"]}
    assert roles["lounge-seat"] in by_kind["living"]
    assert roles["desk-seat"] in by_kind["office"]
    assert roles["standing-work-edge"] in by_kind["workshop"]
    assert len(by_kind["mixed"]) >= 2


@pytest.mark.parametrize("seed", range(25))
def test_furniture_dimensions_are_real(seed):
    rng = np.random.default_rng(seed)
    seat = F.sofa(rng).parts[0].z_range[1]
    assert 0.38 <= seat <= 0.50
    desk_top = max(p.z_range[1] for p in F.table(rng, 1.2, 0.7, rng.uniform(0.70, 0.78)))
    assert 0.70 <= desk_top <= 0.78
    for piece in (F.counter(rng), F.workbench(rng), F.high_table(rng)):
        edge = piece.anchors[0]
        surface = max(p.z_range[1] for p in piece.parts if p.size[0] > 0.5 and p.size[1] > 0.5)
        assert 0.85 <= surface <= 1.00, piece.note
        # the label is 0.30 m in front of the working edge and faces it
        assert np.cos(edge.facing) < -0.99


def test_distractors_afford_nothing():
    rng = np.random.default_rng(0)
    for piece in (
        F.bench(rng),
        F.storage_box(rng),
        F.lone_chair(rng),
        F.shelf(rng, low=True),
        F.coffee_table(rng),
        F.counter(rng, cluttered=True),
        F.workbench(rng, cluttered=True),
        F.desk(rng, with_chair=False),
    ):
        assert piece.anchors == [], piece.note


def test_chair_labels_sit_outside_the_table_edge_facing_it():
    rng = np.random.default_rng(3)
    for _ in range(10):
        desk = F.desk(rng, with_chair=True)
        if not desk.anchors:
            continue
        top = desk.parts[0]
        edge_x = top.centre[0] + top.size[0] / 2
        anchor = desk.anchors[0]
        assert anchor.is_point and anchor.start[0] == pytest.approx(edge_x + F.DESK_LABEL_OFFSET)
        assert np.cos(anchor.facing) == pytest.approx(-1.0)


# ---------------------------------------------------------------- the scanner


def _probe_room():
    """A room with a table (top 0.70-0.74 m) and a solid box on the floor, nothing else."""
    room = generate_room("living", np.random.default_rng(0), "probe")
    room.pieces = [
        F.Piece("table", F.table(np.random.default_rng(1), 1.6, 1.0, 0.74), x=2.0, y=2.0),
        F.Piece("box", [Box.span((-0.3, -0.3, 0.0), (0.3, 0.3, 0.45))], x=1.0, y=1.2),
    ]
    return room


def test_depth_camera_misses_what_a_real_one_never_sees():
    """From person height no ray reaches the underside of a table top or the floor under a box; uniform
    surface sampling has points there."""
    room = _probe_room()
    raycaster = Raycaster(room.shell_boxes() + room.furniture_boxes())
    camera = DepthCamera(noisy=False)
    seen = []
    for eye in ((0.6, 3.4), (3.4, 0.6), (3.4, 3.4), (0.4, 0.4)):
        pose = look_at(np.array([*eye, 1.6]), np.array([1.6, 1.8, 0.3]))
        seen.append(
            backproject(depth_frame(raycaster, camera, pose, np.random.default_rng(0))[0], camera, pose)
        )
    scanned = np.concatenate(seen)
    sampled, _ = sample_room_uniform(room, np.random.default_rng(0))

    underside = room.pieces[0].parts[0].z_range[0]

    def table_underside(points):
        return np.sum(
            (np.abs(points[:, 0] - 2.0) < 0.45)
            & (np.abs(points[:, 1] - 2.0) < 0.75)
            & (np.abs(points[:, 2] - underside) < 0.002)
        )

    def under_box(points):
        return np.sum(
            (np.abs(points[:, 0] - 1.0) < 0.25) & (np.abs(points[:, 1] - 1.2) < 0.25) & (points[:, 2] < 0.02)
        )

    assert table_underside(sampled) > 1000 and under_box(sampled) > 300
    assert table_underside(scanned) == 0 and under_box(scanned) == 0
    assert len(scanned) > 100_000  # the cameras did see the room


def test_depth_noise_grows_with_range_as_the_kinect_model_says():
    wall = Box.span((-5, -5, -0.1), (5, 5, 0.0))  # a plane z = 0 seen from above
    raycaster = Raycaster([wall])
    camera = DepthCamera(dropout=0.0, lateral_px=0.0)
    rng = np.random.default_rng(0)
    for height in (1.0, 3.0):
        pose = look_at(np.array([0.0, 0.0, height]), np.array([0.0, 0.001, 0.0]))
        depth, _ = depth_frame(raycaster, camera, pose, rng)
        centre = depth[200:280, 280:360]
        measured = np.std(centre[centre > 0])
        expected = axial_sigma(height)
        assert 0.7 * expected < measured < 1.6 * expected + 2.85e-3 * height**2  # plus the quantisation step
    far = look_at(np.array([0.0, 0.0, 6.0]), np.array([0.0, 0.001, 0.0]))
    assert np.all(depth_frame(raycaster, camera, far, rng)[0] == 0)  # beyond the 4.5 m range


# ---------------------------------------------------------------- data sets


def _synth(out, seed, *extra):
    return subprocess.run(
        [
            sys.executable,
            "-m",
            "afford",
            "synth",
            "--rooms",
            "2",
            "--seed",
            str(seed),
            "--out",
            str(out),
            "--kinds",
            "office,workshop",
            "--quiet",
            *extra,
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )


def test_same_seed_same_files_and_a_class_table(tmp_path):
    first, second, other = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    for folder, seed in ((first, 4), (second, 4), (other, 5)):
        result = _synth(folder, seed, "--scanner", "uniform")
        assert result.returncode == 0, result.stderr
    names = sorted(p.name for p in first.iterdir())
    assert names == sorted(p.name for p in second.iterdir())
    assert {
        "office-000.ply",
        "office-000.labels.json",
        "workshop-001.ply",
        "summary.json",
        "summary.md",
    } <= set(names)
    for name in names:
        assert (first / name).read_bytes() == (second / name).read_bytes(), name
    assert (first / "office-000.ply").read_bytes() != (other / "office-000.ply").read_bytes()
    summary = json.loads((first / "summary.json").read_text())
    table = summary["class_imbalance"]
    assert set(table) == {s.affordance for s in all_skeletons()}
    for count in table.values():
        assert count["negatives"] > 100 * max(count["positives"], 1)
    assert "| affordance | labels | positive poses |" in (first / "summary.md").read_text()


@pytest.mark.slow
def test_depth_sequence_frames_back_project_onto_the_room(tmp_path):
    """Poses are camera-to-world and depth is millimetres: every frame lands on the same room surfaces."""
    import open3d as o3d
    from PIL import Image

    result = _synth(tmp_path, 9, "--sequences", "--frames", "12")
    assert result.returncode == 0, result.stderr
    folder = tmp_path / "office-000.sequence"
    intrinsics = np.loadtxt(folder / "camera-intrinsics.txt")
    camera = DepthCamera(fx=intrinsics[0, 0], fy=intrinsics[1, 1], cx=intrinsics[0, 2], cy=intrinsics[1, 2])
    # The same room again: room i of a data set draws from the i-th child of SeedSequence(seed).
    room = generate_room("office", np.random.default_rng(np.random.SeedSequence(9).spawn(2)[0]), "office-000")
    surfaces = Raycaster(room.shell_boxes() + room.furniture_boxes()).scene
    for k in (0, 11):
        depth = np.asarray(Image.open(folder / f"frame-{k:06d}.depth.png")).astype(float) / 1000.0
        assert np.mean(depth > 0) > 0.3
        points = backproject(depth, camera, np.loadtxt(folder / f"frame-{k:06d}.pose.txt"))
        distance = surfaces.compute_distance(
            o3d.core.Tensor(points[:: max(1, len(points) // 3000)].astype(np.float32))
        ).numpy()
        assert np.quantile(distance, 0.9) < 0.05
