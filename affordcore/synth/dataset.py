"""Labelled data sets of generated rooms: `afford synth`.

Per room: ``<room>.ply`` (gravity-aligned, metres, colours), ``<room>.labels.json`` (affordance-labels/1),
``<room>.origins.npy`` (float32 (M, 3): where the sensor stood for each frame or station, world frame;
(0, 3) for uniform samples, which no sensor took), and with sequences ``<room>.sequence/`` (a depth camera's
frames in the 7-Scenes layout, or a LiDAR's scans, with ground-truth poses). ``summary.json`` and
``summary.md`` give the class imbalance per affordance. Depth-scanned rooms are scanned in the scan styles
(`styles.py`) dealt to them by index; each room's report says which.

Reproducible: room i draws from the i-th child of ``SeedSequence(seed)``, so the same seed gives the same
files byte for byte, in any order and with any number of worker processes.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .rooms import FURNITURE, KINDS, generate_room
from .styles import STYLES

SENSORS = ("depth", "lidar")
SCANNERS = ("depth", "uniform")


@dataclass(frozen=True)
class SynthOptions:
    rooms: int
    seed: int = 0
    kinds: tuple[str, ...] = ("living", "office", "workshop")
    scanner: str = "depth"  # how the room cloud is made: fused depth frames, or uniform surface samples
    sequences: bool = False
    sensor: str = "depth"  # what a sequence holds: depth frames or LiDAR scans
    frames: int = 300
    # share of depth-scanned rooms captured from a few viewpoints (scanner.few_viewpoints), as real rooms are;
    # the rest are scanned from spots spread over the whole floor
    few_views: float = 0.5
    # how depth-scanned rooms are scanned (styles.STYLES), dealt to rooms by index (`style_of`)
    styles: tuple[str, ...] = tuple(STYLES)
    furniture: str = "base"  # rooms.FURNITURE

    def __post_init__(self) -> None:
        unknown = set(self.kinds) - set(KINDS)
        if unknown or not self.kinds:
            raise ValueError(f"unknown room kinds {sorted(unknown)}; choose from {', '.join(KINDS)}")
        if self.scanner not in SCANNERS:
            raise ValueError(f"scanner must be one of {', '.join(SCANNERS)}, not {self.scanner!r}")
        if self.sensor not in SENSORS:
            raise ValueError(f"sensor must be one of {', '.join(SENSORS)}, not {self.sensor!r}")
        if not 0.0 <= self.few_views <= 1.0:
            raise ValueError(f"few_views is a share, between 0 and 1, not {self.few_views}")
        unknown = set(self.styles) - set(STYLES)
        if unknown or not self.styles:
            raise ValueError(f"unknown scan styles {sorted(unknown)}; choose from {', '.join(STYLES)}")
        if self.furniture not in FURNITURE:
            raise ValueError(f"furniture must be one of {', '.join(FURNITURE)}, not {self.furniture!r}")
        if self.rooms < 1 or self.frames < 1:
            raise ValueError("rooms and frames must be at least 1")

    def room_name(self, index: int) -> str:
        return f"{self.kinds[index % len(self.kinds)]}-{index:03d}"

    def style_of(self, index: int) -> str:
        """Room `index`'s scan style, from its index alone (so room i depends only on the seed and i): the
        styles in turn, shifted by one every lcm(kinds, styles) rooms. Every block of that many rooms holds
        each style equally often, and since kinds are dealt in turn too, the shift makes every kind meet
        every style (without it, with as many kinds as styles, each kind would always get the same one)."""
        count = len(self.styles)
        cycle = int(np.lcm(len(self.kinds), count))
        return self.styles[(index + index // cycle) % count]


def make_room(options: SynthOptions, out: Path, index: int, seed: np.random.SeedSequence) -> dict:
    """Generate, scan and label one room; returns its report (points, labels and class counts)."""
    from ..geometry.scene import Cloud, save_cloud
    from ..geometry.skeleton import all_skeletons
    from ..labels import class_counts, load_labels
    from ..mapping.pipeline import pose_grids_for_footprint
    from .scanner import sample_room_uniform
    from .styles import scan_in_style

    rng = np.random.default_rng(seed)
    name = options.room_name(index)
    room = generate_room(options.kinds[index % len(options.kinds)], rng, name, options.furniture)
    regime = "few" if rng.random() < options.few_views else "full"  # drawn whatever the style: same stream
    if options.scanner == "depth":
        style = options.style_of(index)
        scan = scan_in_style(style, room, rng, regime)
        points, colors, origins, views = scan.points, scan.colors, scan.origins, scan.views
    else:
        style, views, origins = "uniform", "every surface", np.zeros((0, 3))
        points, colors = sample_room_uniform(room, rng)
    save_cloud(out / f"{name}.ply", Cloud(points, colors))
    np.save(out / f"{name}.origins.npy", origins.astype(np.float32))
    labels_path = out / f"{name}.labels.json"
    document = room.labels(points)
    labels_path.write_text(json.dumps(document, indent=1) + "\n")
    labels = load_labels(labels_path)  # what was written must read back valid
    footprint = (*points[:, :2].min(axis=0), *points[:, :2].max(axis=0))
    heights = {skeleton.affordance: skeleton.torso_height for skeleton in all_skeletons()}
    counts = class_counts(labels, pose_grids_for_footprint(footprint), heights)
    if options.sequences:
        write_sequence(room, rng, out / f"{name}.sequence", options.sensor, options.frames)
    return {
        "room": name,
        "kind": room.kind,
        "size_m": [round(float(v), 2) for v in np.ptp(room.polygon, axis=0)],
        "points": int(len(points)),
        "style": style,
        "views": views,
        "origins": int(len(origins)),
        "pieces": [piece.kind for piece in room.pieces],
        "unlabelled_regions": len(document["unlabelled_regions"]),
        "labels": {name: sum(label.affordance == name for label in labels.labels) for name in counts},
        "class_counts": {name: [c.positives, c.negatives] for name, c in counts.items()},
    }


def write_sequence(room, rng: np.random.Generator, folder: Path, sensor: str, frames: int) -> None:
    """Frames along a walk with ground-truth poses and the robot's odometry.

    depth: ``frame-NNNNNN.depth.png`` (16-bit millimetres, 0 = no return), ``frame-NNNNNN.pose.txt``
    (camera-to-world 4 x 4), ``camera-intrinsics.txt`` and ``gravity-direction.txt``: the 7-Scenes layout.
    lidar: ``scan-NNNNNN.bin`` (float32 x y z in the sensor frame) and ``scan-NNNNNN.pose.txt``.
    Both: ``<stem>.odometry.txt``, the sensor's pose by wheel odometry (`styles.odometry`: drifting with the
    distance gone, as the walk style's robot has it).
    """
    from PIL import Image

    from .scanner import DepthCamera, Raycaster, depth_frame, lidar_scan, trajectory
    from .styles import odometry

    folder.mkdir(parents=True, exist_ok=True)
    raycaster = Raycaster(room.shell_boxes() + room.furniture_boxes())
    camera = DepthCamera()
    np.savetxt(folder / "camera-intrinsics.txt", camera.intrinsics, fmt="%.6f")
    np.savetxt(folder / "gravity-direction.txt", [0.0, 0.0, -1.0], fmt="%.6f")
    # ROS axes from camera axes
    to_lidar = np.array([[0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1]], float)
    sensor_poses, stems = [], []
    for k, pose in enumerate(trajectory(room, rng, frames)):
        if sensor == "depth":
            depth, _ = depth_frame(raycaster, camera, pose, rng)
            millimetres = np.clip(np.round(depth * 1000), 0, 65534).astype(np.uint16)
            # zlib level 1, not PIL's default 6: a few per cent more bytes, written several times faster
            # (PNG encoding was half of a sequence's time; docs/synthetic-rooms.md, "Sequences")
            Image.fromarray(millimetres).save(folder / f"frame-{k:06d}.depth.png", compress_level=1)
            stem = f"frame-{k:06d}"
        else:
            pose = pose @ np.linalg.inv(to_lidar)
            lidar_scan(raycaster, pose, rng).astype("<f4").tofile(folder / f"scan-{k:06d}.bin")
            stem = f"scan-{k:06d}"
        np.savetxt(folder / f"{stem}.pose.txt", pose, fmt="%.9f")
        sensor_poses.append(pose)
        stems.append(stem)
    # drawn after the frames, so the frames are what they were before odometry was written
    for stem, guess in zip(stems, odometry(sensor_poses, rng)):
        np.savetxt(folder / f"{stem}.odometry.txt", guess, fmt="%.9f")


def _summary(options: SynthOptions, reports: list[dict]) -> dict:
    from ..labels import ClassCount

    totals: dict[str, list[int]] = {}
    for report in reports:
        for name, (positives, negatives) in report["class_counts"].items():
            total = totals.setdefault(name, [0, 0])
            total[0] += positives
            total[1] += negatives
    return {
        "seed": options.seed,
        "kinds": list(options.kinds),
        "scanner": options.scanner,
        "styles": list(options.styles) if options.scanner == "depth" else ["uniform"],
        "rooms": reports,
        "class_imbalance": {name: ClassCount.of(*pair)._asdict() for name, pair in sorted(totals.items())},
    }


def summary_table(summary: dict) -> str:
    rows = [
        f"# Generated rooms (seed {summary['seed']}, {len(summary['rooms'])} rooms, "
        f"scanner {summary['scanner']})",
        "",
        "| affordance | labels | positive poses | negative poses | ratio |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, count in summary["class_imbalance"].items():
        labels = sum(room["labels"].get(name, 0) for room in summary["rooms"])
        rows.append(
            f"| {name} | {labels} | {count['positives']:,} | {count['negatives']:,} | {count['ratio']} |"
        )
    rows += ["", "| room | kind | style | size (m) | points | labels |", "|---|---|---|---|---:|---|"]
    for room in summary["rooms"]:
        labels = ", ".join(f"{n} {k}" for n, k in room["labels"].items() if k) or "none"
        rows.append(
            f"| {room['room']} | {room['kind']} | {room['style']} | "
            f"{room['size_m'][0]} x {room['size_m'][1]} | {room['points']:,} | {labels} |"
        )
    return "\n".join(rows) + "\n"
