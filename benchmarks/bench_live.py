"""Live maps against offline ones, on an idle and on a busy computer (issue 25).

For each source, a depth sequence with true poses and the room's fused cloud with labels (the real 7-Scenes
kitchen of ../shared, and generated rooms of `afford synth --sequences`), the sequence is streamed through
the router and the three services as processes on this machine (every --step-th frame at --rate Hz), once
with the machine otherwise idle and once with a CPU hog on every core. The final maps (the ones that cover
the last scan, as `afford watch --frames N` waits for them) are scored against the room's labels beside
`afford map`'s maps of the fused room (the offline path):

* frames taken of those published; the trajectory the assembler published against the true poses (mean and
  worst position error, anchored at the first frame, cm); the lag from the last scan published to every map;
* per affordance, places found live / offline and false skeletons live / offline (DESIGN.md's place
  tolerances), the live map brought into the labels' frame by the true pose of the first frame and the
  map's own levelling, refined by ICP of the live map cloud onto the fused room (the refinement is printed).

    .venv/bin/python benchmarks/bench_live.py                        # kitchen + 3 generated rooms, ~15 min
    .venv/bin/python benchmarks/bench_live.py --generated 0 --loads 2  # the kitchen, busy only
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from affordcore.assembly.assembler import trajectory_errors  # noqa: E402
from affordcore.assembly.sequence import read_sequence  # noqa: E402
from affordcore.geometry.scene import load_cloud  # noqa: E402
from affordcore.labels import load_labels, match_places  # noqa: E402
from affordcore.learn.model import load_model, shipped_models  # noqa: E402
from affordcore.mapping.pipeline import map_affordances, prepare_scene  # noqa: E402
from affordcore.settings import Settings  # noqa: E402
from affordwire import messages  # noqa: E402
from services.clients import MapWatcher, publish_sequence, sequence_messages  # noqa: E402
from services.launch import Stack, cpu_hogs  # noqa: E402
from services.transport import Keys, open_session, schema_of  # noqa: E402

SHARED = ROOT.parent / "shared" / "data"
KITCHEN = SHARED / "sequences" / "7scenes_redkitchen_frames_000000-000299"
KITCHEN_ROOM = SHARED / "rooms" / "7scenes_redkitchen_fused_zup_DERIVED"


@dataclass
class Source:
    name: str
    sequence: Path
    room: Path  # <room>.ply and <room>.labels.json, in the labels' frame
    room_from_truth: np.ndarray  # the sequence's true poses' frame into the room's


# -- frames --------------------------------------------------------------------------------------------------


def icp(source: np.ndarray, target: np.ndarray, guess: np.ndarray) -> tuple[np.ndarray, float]:
    """target_from_source refined from `guess` (point to point, 3 cm clouds, shrinking distances), and the
    inliers' RMSE (m)."""
    import open3d as o3d

    def cloud(points):
        return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points)).voxel_down_sample(0.03)

    a, b, transform = cloud(source), cloud(target), guess
    for distance in (0.2, 0.08, 0.03):
        result = o3d.pipelines.registration.registration_icp(a, b, distance, transform)
        transform = result.transformation
    return np.asarray(transform), float(result.inlier_rmse)


def kitchen_source() -> Source:
    """The kitchen's fused room is z-up with its floor at 0; its frame from the sequence's is the rotation
    taking the sequence's gravity to -z, lifted to the floor, refined by ICP of every 10th frame onto it."""
    from scipy.spatial.transform import Rotation

    from affordcore.assembly.depth import DepthImage, back_project

    sequence = read_sequence(KITCHEN)
    down = np.loadtxt(KITCHEN / "gravity-direction.txt")
    guess = np.eye(4)
    guess[:3, :3] = Rotation.align_vectors([[0, 0, -1]], [down / np.linalg.norm(down)])[0].as_matrix()
    frames = []
    for index in range(0, len(sequence.frames), 10):
        pose = sequence.pose(index)
        image = DepthImage(sequence.depth(index), sequence.intrinsics, 0.001, 65535)
        frames.append(back_project(image, 2, 0.3, 4.0) @ pose[:3, :3].T + pose[:3, 3])
    fused = np.vstack(frames)
    guess[2, 3] = -(fused @ guess[:3, :3].T)[:, 2].min()
    room = load_cloud(KITCHEN_ROOM.with_suffix(".ply")).points
    room_from_truth, _ = icp(fused, room, guess)
    return Source("7-Scenes kitchen (real)", KITCHEN, KITCHEN_ROOM, room_from_truth)


def generated_sources(count: int, seed: int, folder: Path) -> list[Source]:
    """`afford synth --sequences` rooms: the sequences' true poses are in the room's own frame."""
    if count == 0:
        return []
    command = [sys.executable, "-m", "affordcli", "synth", "--rooms", str(count), "--seed", str(seed)]
    command += ["--out", str(folder), "--sequences", "--styles", "fused", "--frames", "300", "--quiet"]
    subprocess.run(command, check=True, capture_output=True, cwd=ROOT)
    return [
        Source(f"generated {path.stem}", path.with_suffix(".sequence"), path.with_suffix(""), np.eye(4))
        for path in sorted(folder.glob("*.ply"))
    ]


# -- scoring -------------------------------------------------------------------------------------------------


def places(
    labels, affordance: str, skeletons: np.ndarray, room_from_world: np.ndarray
) -> tuple[int, int, int]:
    """(found, labelled, false) of skeleton rows (x, y, z, theta, ...) in a world frame, in the room's."""
    xy = skeletons[:, :2] @ room_from_world[:2, :2].T + room_from_world[:2, 3]
    theta = skeletons[:, 3] + np.arctan2(room_from_world[1, 0], room_from_world[0, 0])
    match = match_places(labels, affordance, np.column_stack([xy, theta]))
    return int(match.found.sum()), len(match.found), int(match.false.sum())


def offline(source: Source, settings: Settings, models: list) -> dict[str, tuple[int, int, int]]:
    """`afford map` of the fused room (stored z-up: no levelling), scored in its own frame."""
    labels = load_labels(source.room.with_suffix(".labels.json"))
    scene = prepare_scene(load_cloud(source.room.with_suffix(".ply")), settings, "none")
    maps = map_affordances(scene.fields, scene.layout, models, settings)
    return {name: places(labels, name, amap.skeletons, np.eye(4)) for name, amap in maps.items()}


# -- where the live path could lose places ----------------------------------------------------------------


def where(source: Source, indices: list[int], settings: Settings, models: list) -> dict[str, dict]:
    """The same frames made into a room four ways, in this process (every frame taken), each mapped and
    scored: the live path's steps one at a time, from true poses and every pixel to the assembler's map."""
    from kiss_icp.voxelization import voxel_down_sample

    from affordcore.assembly.assembler import Assembler
    from affordcore.assembly.depth import DepthImage, back_project
    from affordcore.geometry.scene import Cloud

    sequence, a = read_sequence(source.sequence), settings.assembler
    images = [DepthImage(sequence.depth(i), sequence.intrinsics, 0.001, 65535) for i in indices]
    every_pixel = [back_project(image, 1, a.min_range, a.max_range) for image in images]
    blocks = [back_project(image, a.pixel_step, a.min_range, a.max_range) for image in images]
    assembler = Assembler(a)
    for index, points in zip(indices, blocks):
        assembler.register(points, 1.0 + index / 30, gravity=sequence.gravity(index))
    truth = [source.room_from_truth @ sequence.pose(i) for i in indices]
    estimated = [truth[0] @ pose for pose in assembler.trajectory.poses]

    def fused(clouds, poses):
        return np.vstack([c @ pose[:3, :3].T + pose[:3, 3] for c, pose in zip(clouds, poses)])

    labels = load_labels(source.room.with_suffix(".labels.json"))
    room = load_cloud(source.room.with_suffix(".ply")).points

    def scored(points: np.ndarray, room_from_input: np.ndarray, gravity) -> dict | str:
        try:
            scene = prepare_scene(Cloud(points), settings, gravity)
        except ValueError as error:  # no floor: what the service would answer with no map at all
            return f"no map: {str(error)[:60]}"
        guess = room_from_input @ np.linalg.inv(scene.alignment.world_from_input)
        room_from_world, _ = icp(scene.cloud.points, room, guess)
        maps = map_affordances(scene.fields, scene.layout, models, settings)
        return {name: places(labels, name, m.skeletons, room_from_world) for name, m in maps.items()}

    try:
        map_points, world_from_odom = assembler.aligned_map(settings)
        as_published = scored(map_points, truth[0] @ np.linalg.inv(world_from_odom), "none")
    except ValueError as error:  # the assembler publishes no map until it finds a floor
        as_published = f"no map: {str(error)[:60]}"
    return {
        "true poses, every pixel": scored(fused(every_pixel, truth), np.eye(4), "auto"),
        "true poses, block means, map voxel": scored(
            voxel_down_sample(fused(blocks, truth), a.map_voxel), np.eye(4), "auto"
        ),
        "assembler's poses, every pixel": scored(fused(every_pixel, estimated), np.eye(4), "auto"),
        "assembler's map, as published": as_published,
    }


# -- the live run --------------------------------------------------------------------------------------------


class Listener:
    """The assembler's poses (by the stamp of the frame each answers) and its newest map cloud."""

    def __init__(self, keys: Keys):
        self.keys, self.poses, self.cloud = keys, {}, None
        self.lock = threading.Lock()

    def on_sample(self, sample) -> None:
        key = str(sample.key_expr)
        if key == self.keys.pose and schema_of(sample) == messages.schema_name(messages.Pose):
            pose = messages.parse(messages.Pose, sample.payload.to_bytes())
            with self.lock:
                self.poses[messages.seconds(pose.timestamp)] = messages.pose_matrix(pose)
        elif key == self.keys.cloud and schema_of(sample) == messages.schema_name(messages.CloudMessage):
            with self.lock:
                self.cloud = messages.parse(messages.CloudMessage, sample.payload.to_bytes())


def stamped(sequence, indices: list[int], sent: dict[float, int]):
    """The sequence's messages, each stamped as it is sent, remembering which frame has which stamp."""
    for index, message in sequence_messages(sequence, indices):
        messages.stamp(message.timestamp)
        sent[messages.seconds(message.timestamp)] = index
        yield index, message


def frames_of(poses: dict[float, np.ndarray], sent: dict[float, int]) -> list[tuple[int, np.ndarray]]:
    """(frame index, pose) of every pose published, by the stamp of the frame it answers (to 1 ms: the
    assembler carries stamps as float seconds)."""
    stamps = np.array(sorted(sent))
    taken = []
    for stamp, pose in sorted(poses.items()):
        nearest = stamps[np.argmin(np.abs(stamps - stamp))]
        if abs(nearest - stamp) < 1e-3:
            taken.append((sent[nearest], pose))
    return taken


def live(source: Source, indices: list[int], rate: float, hogs: int, workdir: Path, models: list) -> dict:
    sequence = read_sequence(source.sequence)
    with cpu_hogs(hogs), Stack(workdir) as stack:
        keys = Keys(stack.robot)
        listener = Listener(keys)
        watcher = MapWatcher(keys, [m.affordance for m in models], len(indices), None, lambda line: None)
        session = open_session([stack.endpoint])
        subscribers = [
            session.declare_subscriber(keys.key("**"), listener.on_sample),
            session.declare_subscriber(keys.key("affordance", "*"), watcher.on_sample),
        ]
        sent: dict[float, int] = {}
        try:
            publish_sequence(session, keys, stamped(sequence, indices, sent), "camera", rate, wait=60)
            last_scan = time.monotonic()
            # None: no map covers every scan (the assembler found no floor in its drifting map)
            lag = time.monotonic() - last_scan if watcher.done.wait(180) else None
        finally:
            for subscriber in subscribers:
                subscriber.undeclare()
            session.close()
    taken = frames_of(listener.poses, sent)
    truth = [source.room_from_truth @ sequence.pose(index) for index, _ in taken]
    errors = trajectory_errors([pose for _, pose in taken], truth)
    cloud = listener.cloud
    if lag is None or cloud is None:
        return {"taken": len(taken), "errors": errors, "lag": None, "places": None, "icp": "no map"}
    world_from_odom = messages.pose_matrix(cloud.world_from_input)
    # the odometry frame is the first frame's sensor frame; ICP takes out what drift and levelling moved
    guess = truth[0] @ np.linalg.inv(world_from_odom)
    room = load_cloud(source.room.with_suffix(".ply")).points
    room_from_world, rmse = icp(messages.cloud_points(cloud), room, guess)
    labels = load_labels(source.room.with_suffix(".labels.json"))
    scores = {}
    for name, document in watcher.received.items():
        rows = np.array([[s["x"], s["y"], s["z"], s["theta"]] for s in document["skeletons"]]).reshape(-1, 4)
        scores[name] = places(labels, name, rows, room_from_world)
    moved = np.linalg.norm((room_from_world - guess)[:3, 3])
    return {
        "taken": len(taken),
        "errors": errors,
        "lag": lag,
        "places": scores,
        "icp": f"ICP moved the map {moved * 100:.1f} cm, {rmse * 100:.1f} cm RMSE",
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--generated", type=int, default=3, help="generated rooms with sequences (0: none)")
    parser.add_argument("--seed", type=int, default=11, help="their seed (the models never saw it)")
    parser.add_argument("--rate", type=float, default=15.0, help="frames per second published")
    parser.add_argument("--step", type=int, default=3, help="every n-th frame of the sequence")
    parser.add_argument(
        "--loads", default=f"0,{os.cpu_count()}", help="CPU hogs beside the services, per run"
    )
    parser.add_argument("--no-where", action="store_true", help="skip the in-process steps of the live path")
    args = parser.parse_args()
    settings = Settings()
    models = [load_model(path) for path in shipped_models().values()]
    names = [m.affordance for m in models]
    loads = [int(v) for v in args.loads.split(",")]
    print(
        f"Every {args.step}th frame at {args.rate:g} Hz, {os.cpu_count()} cores; places live / offline "
        "(found of labelled, + false skeletons)\n"
    )
    print(
        "| source | CPU hogs | frames taken | trajectory error mean / worst (cm) "
        "| last scan to every map (s) | " + " | ".join(names) + " |"
    )
    print("|---|---:|---:|---:|---:|" + "---|" * len(names), flush=True)
    steps = []
    with tempfile.TemporaryDirectory() as tmp:
        sources = ([kitchen_source()] if KITCHEN.is_dir() else []) + generated_sources(
            args.generated, args.seed, Path(tmp) / "generated"
        )
        for number, source in enumerate(sources):
            indices = list(range(0, len(read_sequence(source.sequence).frames), args.step))
            reference = offline(source, settings, models)
            if not args.no_where:
                steps.append(
                    (
                        source,
                        {
                            "the fused room (afford map)": reference,
                            **where(source, indices, settings, models),
                        },
                    )
                )
            for hogs in loads:
                run = live(source, indices, args.rate, hogs, Path(tmp) / f"run-{number}-{hogs}", models)
                print(live_row(source, len(indices), hogs, run, reference, names), flush=True)
                print(f"{source.name}, {hogs} hogs: {run['icp']}", file=sys.stderr, flush=True)
    if steps:
        print("\nThe live path's steps in this process, every frame taken (found of labelled, + false):\n")
        print("| source | made from | " + " | ".join(names) + " |\n|---|---|" + "---|" * len(names))
        for source, variants in steps:
            for made, result in variants.items():
                print(f"| {source.name} | {made} | " + " | ".join(cells_of(result, names)) + " |")


def cells_of(result: dict | str | None, names: list[str]) -> list[str]:
    """A table's cells of places (found/labelled +false) per affordance, or why there is no map."""
    if not isinstance(result, dict):
        return [result or "no map"] * len(names)
    return [f"{r[0]}/{r[1]} +{r[2]}" for r in (result.get(n, (0, 0, 0)) for n in names)]


def live_row(source: Source, published: int, hogs: int, run: dict, reference: dict, names: list[str]) -> str:
    live_cells, offline_cells = cells_of(run["places"], names), cells_of(reference, names)
    errors, lag = run["errors"], "no map" if run["lag"] is None else f"{run['lag']:.1f}"
    return (
        f"| {source.name} | {hogs} | {run['taken']} / {published} | "
        f"{errors['mean_m'] * 100:.1f} / {errors['worst_m'] * 100:.1f} | {lag} | "
        + " | ".join(f"{a} / {b}" for a, b in zip(live_cells, offline_cells))
        + " |"
    )


if __name__ == "__main__":
    main()
