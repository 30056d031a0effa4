"""Live maps against offline ones, on an idle and on a busy computer.

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

A second table says where the time goes, from a client that hears every output: the last scan sent to the
assembler's last pose and last map cloud, that cloud to its fields and to each map, the outputs that came
after the last scan (each one the services worked on while the last one waited), and the cores each process
used while the scans streamed and after. `--against KEY=VALUE,...` runs every live run a second time with
those settings, side by side.

    .venv/bin/python benchmarks/bench_live.py                        # kitchen + 3 generated rooms, ~15 min
    .venv/bin/python benchmarks/bench_live.py --generated 0 --loads 2  # the kitchen, busy only
    .venv/bin/python benchmarks/bench_live.py --generated 0 --no-where --repeats 3 \
        --against AFFORD_SERVICE__DOWNSTREAM_NICE=10   # the kitchen: defaults against niced services
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
from affordcore.geometry.scene import Cloud, load_cloud  # noqa: E402
from affordcore.labels import LOOSE_TOLERANCES, load_labels, match_places  # noqa: E402
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


class RoomScore:
    """Maps a cloud of a source's room and scores its places against the room's labels, the cloud brought onto
    the room's fused cloud by ICP from a guess."""

    def __init__(self, source: Source, settings: Settings, models: list):
        self.labels = load_labels(source.room.with_suffix(".labels.json"))
        self.room = load_cloud(source.room.with_suffix(".ply")).points
        self.settings, self.models = settings, models
        gravity = settings.gravity.model_copy(update={"up_candidates": ["+z"]})
        self.z_up = settings.model_copy(update={"gravity": gravity})

    def __call__(
        self, points: np.ndarray, room_from_input: np.ndarray, level: bool, move: np.ndarray | None = None
    ) -> tuple[dict[str, tuple[int, int, int, int]], float]:
        """({affordance: `places`}, the ICP RMSE onto the room in m) of the cloud moved by `move` (a grid
        placement; undone before scoring). `level`: levelled on the floor found along +z alone, as the
        assembler levels its map on the floor under the frames' gravity (a search over every axis can take a
        wall for a partial scan's floor); else mapped as it is (z up, floor at 0). ValueError: no floor."""
        move = np.zeros(3) if move is None else move
        cloud = Cloud(points + move)
        scene = (
            prepare_scene(cloud, self.z_up, "auto") if level else prepare_scene(cloud, self.settings, "none")
        )
        unmoved = np.eye(4)
        unmoved[:3, 3] = -move
        guess = room_from_input @ unmoved @ np.linalg.inv(scene.alignment.world_from_input)
        room_from_world, rmse = icp(scene.cloud.points, self.room, guess)
        maps = map_affordances(scene.fields, scene.layout, self.models, self.settings)
        return {n: places(self.labels, n, m.skeletons, room_from_world) for n, m in maps.items()}, rmse


def places(
    labels, affordance: str, skeletons: np.ndarray, room_from_world: np.ndarray
) -> tuple[int, int, int, int]:
    """(found, labelled, false, found with the loose tolerances) of skeleton rows (x, y, z, theta, ...) in a
    world frame, in the room's."""
    xy = skeletons[:, :2] @ room_from_world[:2, :2].T + room_from_world[:2, 3]
    theta = skeletons[:, 3] + np.arctan2(room_from_world[1, 0], room_from_world[0, 0])
    rows = np.column_stack([xy, theta])
    match = match_places(labels, affordance, rows)
    loose = match_places(labels, affordance, rows, **LOOSE_TOLERANCES)  # seen, if 0.15-0.3 m off its label
    return int(match.found.sum()), len(match.found), int(match.false.sum()), int(loose.found.sum())


def offline(source: Source, settings: Settings, models: list) -> dict[str, tuple[int, int, int, int]]:
    """`afford map` of the fused room (stored z-up: no levelling), scored in its own frame."""
    labels = load_labels(source.room.with_suffix(".labels.json"))
    scene = prepare_scene(load_cloud(source.room.with_suffix(".ply")), settings, "none")
    maps = map_affordances(scene.fields, scene.layout, models, settings)
    return {name: places(labels, name, amap.skeletons, np.eye(4)) for name, amap in maps.items()}


# -- where the live path could lose places ----------------------------------------------------------------


def voxel_means(clouds: list[np.ndarray], poses, voxel: float) -> np.ndarray:
    """Clouds (sensor frame) at their poses, made into one as the assembler's map step makes its map: the
    mean of every point per `voxel` cell."""
    from affordcore.assembly.voxelmap import VoxelMeans

    voxel_map = VoxelMeans(voxel)
    for cloud, pose in zip(clouds, poses):
        voxel_map.add_points(cloud @ pose[:3, :3].T + pose[:3, 3])
    return voxel_map.point_cloud()


def where(source: Source, indices: list[int], settings: Settings, models: list) -> dict[str, dict]:
    """The same frames made into a room five ways, in this process (every frame taken), each mapped and
    scored: the live path's steps one at a time, from true poses and every pixel to the assembler's map."""
    from kiss_icp.voxelization import voxel_down_sample

    from affordcore.assembly.assembler import Assembler, SensorFrame, within_range
    from affordcore.assembly.depth import DepthImage, back_project

    sequence, a = read_sequence(source.sequence), settings.assembler
    images = [DepthImage(sequence.depth(i), sequence.intrinsics, 0.001, 65535) for i in indices]
    every_pixel = [back_project(image, 1, a.min_range, a.max_range) for image in images]
    blocks = [back_project(image, a.pixel_step, a.min_range, a.max_range) for image in images]
    map_blocks = [  # what a keyframe adds to the map (Assembler.depth_points, then the range filter)
        within_range(
            back_project(image, a.pixel_step, a.min_range, a.max_range, max_spread=a.map_edge_spread), a
        )
        for image in images
    ]
    assembler = Assembler(a)
    for index, image in zip(indices, images):
        stamp = 1.0 + index / 30
        frame = SensorFrame(
            "camera", stamp, depth=image, gravity=sequence.gravity(index), pose_guess=sequence.odometry(index)
        )
        assembler.add(frame, stamp)  # as the service takes it: with the robot's odometry when recorded
    truth = [source.room_from_truth @ sequence.pose(i) for i in indices]
    estimated = [truth[0] @ pose for pose in assembler.trajectory.poses]

    def fused(clouds, poses):
        return np.vstack([c @ pose[:3, :3].T + pose[:3, 3] for c, pose in zip(clouds, poses)])

    score = RoomScore(source, settings, models)

    def scored(points: np.ndarray, room_from_input: np.ndarray, levelled: bool = False) -> dict | str:
        """The cloud's places. `levelled`: as published, not levelled again; else in the room's frame, z up,
        levelled as the assembler levels (`RoomScore`)."""
        try:
            return score(points, room_from_input, level=not levelled)[0]
        except ValueError as error:  # no floor: what the service would answer with no map at all
            return f"no map: {str(error)[:60]}"

    try:
        map_points, world_from_odom = assembler.aligned_map(settings)
        as_published = scored(map_points, truth[0] @ np.linalg.inv(world_from_odom), levelled=True)
    except ValueError as error:  # the assembler publishes no map until it finds a floor
        as_published = f"no map: {str(error)[:60]}"
    return {
        "true poses, every pixel": scored(fused(every_pixel, truth), np.eye(4)),
        "true poses, block means, first point per map voxel (the first-point map)": scored(
            voxel_down_sample(fused(blocks, truth), a.map_voxel), np.eye(4)
        ),
        "true poses, the map's blocks (no depth edges), mean per map voxel": scored(
            voxel_means(map_blocks, truth, a.map_voxel), np.eye(4)
        ),
        "assembler's poses, every pixel": scored(fused(every_pixel, estimated), np.eye(4)),
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


class Timeline:
    """When each output arrived (monotonic s) with the cloud it was built from: `events` rows of (time, stage,
    cloud stamp ns, scans the cloud covers), stage map/pose, map/cloud, fields or an affordance."""

    STAGES = {"map/cloud": "CloudMessage", "fields": "SceneFieldsMessage"}

    def __init__(self, keys: Keys):
        self.keys, self.events = keys, []
        self.lock = threading.Lock()

    def on_sample(self, sample) -> None:
        now = time.monotonic()
        stage = str(sample.key_expr).split("/", 3)[3]
        if stage == "map/pose":
            row = (now, stage, 0, 0)
        else:
            name = self.STAGES.get(stage, "AffordanceMapMessage" if stage.startswith("affordance/") else None)
            cls = getattr(messages, name) if name else None
            if cls is None or schema_of(sample) != messages.schema_name(cls):
                return
            message = messages.parse(cls, sample.payload.to_bytes())
            stamp = message.timestamp if cls is messages.CloudMessage else message.cloud_timestamp
            stage = stage.removeprefix("affordance/")
            row = (now, stage, messages.nanoseconds(stamp), message.scans_received)
        with self.lock:
            self.events.append(row)

    def breakdown(self, last_scan: float, affordances: list[str]) -> dict[str, float | int | None]:
        """Seconds from the last scan to the last pose, to the last map cloud, and from that cloud to its
        fields and to each of its maps; and how many clouds, fields and maps came after the last scan (each
        one the services worked on while the final one waited)."""
        with self.lock:
            events = list(self.events)
        after = [e for e in events if e[0] >= last_scan]
        poses = [e[0] for e in events if e[1] == "map/pose"]
        clouds = [e for e in events if e[1] == "map/cloud"]
        result: dict[str, float | int | None] = {
            "last pose": (poses[-1] - last_scan) if poses else None,
            "clouds after": sum(e[1] == "map/cloud" for e in after),
            "fields after": sum(e[1] == "fields" for e in after),
            "maps after": sum(e[1] in affordances for e in after),
        }
        if not clouds:
            return result
        final_at, _, final, _ = clouds[-1]
        result["last map cloud"] = final_at - last_scan
        for stage in ["fields", *affordances]:
            arrivals = [e[0] for e in events if e[1] == stage and e[2] == final]
            result[f"cloud to {stage}"] = (arrivals[0] - final_at) if arrivals else None
        return result


class CpuMeter:
    """CPU seconds each process (with its children: inference's mapping workers) used between laps, as
    shares of one core over the lap's wall time."""

    def __init__(self, pids: dict[str, int]):
        import psutil

        self.processes = {name: psutil.Process(pid) for name, pid in pids.items()}
        self.last, self.at = self._cpu(), time.monotonic()

    def _cpu(self) -> dict[str, float]:
        totals = {}
        for name, process in self.processes.items():
            try:
                family = [process, *process.children(recursive=True)]
                totals[name] = sum(sum(p.cpu_times()[:2]) for p in family)
            except Exception:  # noqa: BLE001 - a process that ended counts as nothing more
                totals[name] = getattr(self, "last", {}).get(name, 0.0)
        return totals

    def lap(self) -> dict[str, float]:
        """{process: cores' worth of CPU it used since the last lap}."""
        now, at = self._cpu(), time.monotonic()
        shares = {name: (now[name] - self.last[name]) / (at - self.at) for name in now}
        self.last, self.at = now, at
        return shares


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


def live(
    source: Source,
    indices: list[int],
    rate: float,
    hogs: int,
    workdir: Path,
    models: list,
    env: dict[str, str] | None = None,
) -> dict:
    sequence = read_sequence(source.sequence)
    with cpu_hogs(hogs) as hog_processes, Stack(workdir, env=env) as stack:
        keys = Keys(stack.robot)
        listener = Listener(keys)
        watcher = MapWatcher(keys, [m.affordance for m in models], len(indices), None, lambda line: None)
        pids = {name: p.pid for name, p in stack.processes.items()}
        pids |= {f"hog {k}": hog.pid for k, hog in enumerate(hog_processes)}
        timeline, meter = Timeline(keys), CpuMeter(pids)
        session = open_session([stack.endpoint])
        subscribers = [
            session.declare_subscriber(keys.key("**"), listener.on_sample),
            session.declare_subscriber(keys.key("**"), timeline.on_sample),
            session.declare_subscriber(keys.key("affordance", "*"), watcher.on_sample),
        ]
        sent: dict[float, int] = {}
        last_sent = [0.0]

        def on_frame(_: int) -> None:
            last_sent[0] = time.monotonic()

        try:
            meter.lap()
            frames = stamped(sequence, indices, sent)
            publish_sequence(session, keys, frames, "camera", rate, wait=60, on_frame=on_frame)
            last_scan = last_sent[0]
            cpu_stream = meter.lap()
            # None: no map covers every scan (the assembler found no floor in its drifting map)
            lag = time.monotonic() - last_scan if watcher.done.wait(180) else None
            cpu_tail = meter.lap()  # from the last scan to the last map: what the services got of the CPU
        finally:
            for subscriber in subscribers:
                subscriber.undeclare()
            session.close()
    taken = frames_of(listener.poses, sent)
    truth = [source.room_from_truth @ sequence.pose(index) for index, _ in taken]
    errors = trajectory_errors([pose for _, pose in taken], truth)
    timing = {
        **timeline.breakdown(last_scan, [m.affordance for m in models]),
        "cpu stream": cpu_stream,
        "cpu tail": cpu_tail,
    }
    cloud = listener.cloud
    if lag is None or cloud is None:
        return {"taken": len(taken), "errors": errors, "lag": None, "places": None, "icp": "no map", **timing}
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
        **timing,
    }


def add_source_arguments(parser: argparse.ArgumentParser) -> None:
    """The sequences a run streams (`sources`): how many generated rooms, their seed, every n-th frame."""
    parser.add_argument("--generated", type=int, default=3, help="generated rooms with sequences (0: none)")
    parser.add_argument("--seed", type=int, default=11, help="their seed (the models never saw it)")
    parser.add_argument("--step", type=int, default=3, help="every n-th frame of the sequence")


def sources(args, folder: Path) -> list[Source]:
    """The real kitchen (when ../shared is there) and `args.generated` generated rooms made into `folder`."""
    return ([kitchen_source()] if KITCHEN.is_dir() else []) + generated_sources(
        args.generated, args.seed, folder
    )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    add_source_arguments(parser)
    parser.add_argument("--rate", type=float, default=15.0, help="frames per second published")
    parser.add_argument(
        "--loads", default=f"0,{os.cpu_count()}", help="CPU hogs beside the services, per run"
    )
    parser.add_argument("--no-where", action="store_true", help="skip the in-process steps of the live path")
    parser.add_argument("--repeats", type=int, default=1, help="live runs per source and load")
    parser.add_argument(
        "--against",
        default="",
        help="settings to compare with, side by side: KEY=VALUE,... (e.g. "
        "AFFORD_SERVICE__DOWNSTREAM_NICE=10); each live run is made with the defaults and with these in turn",
    )
    args = parser.parse_args()
    against = dict(pair.split("=", 1) for pair in args.against.split(",") if pair)
    settings_runs = [("defaults", None)] + ([(args.against, against)] if against else [])
    settings = Settings()
    models = [load_model(path) for path in shipped_models().values()]
    names = [m.affordance for m in models]
    loads = [int(v) for v in args.loads.split(",")]
    print(
        f"One frame in {args.step} at {args.rate:g} Hz, {os.cpu_count()} cores; places live / offline "
        "(found of labelled, + false skeletons; in brackets, found with DESIGN.md's loose tolerances, 0.3 m "
        "and 0.5 rad)\n"
    )
    print(
        "| source | CPU hogs | frames taken | trajectory error mean / worst (cm) "
        "| last scan to every map (s) | " + " | ".join(names) + " |"
    )
    print("|---|---:|---:|---:|---:|" + "---|" * len(names), flush=True)
    steps, timings = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for number, source in enumerate(sources(args, Path(tmp) / "generated")):
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
                for repeat in range(args.repeats):
                    for label, env in settings_runs:
                        workdir = Path(tmp) / f"run-{number}-{hogs}-{repeat}-{len(timings)}"
                        run = live(source, indices, args.rate, hogs, workdir, models, env)
                        print(live_row(source, len(indices), hogs, run, reference, names), flush=True)
                        timings.append(timing_row(source, hogs, run, names, label))
                        print(f"{source.name}, {hogs} hogs: {run['icp']}", file=sys.stderr, flush=True)
    print_timings(timings, names)
    if steps:
        print("\nThe live path's steps in this process, every frame taken (found of labelled, + false):\n")
        print("| source | made from | " + " | ".join(names) + " |\n|---|---|" + "---|" * len(names))
        for source, variants in steps:
            for made, result in variants.items():
                print(f"| {source.name} | {made} | " + " | ".join(cells_of(result, names)) + " |")


def cells_of(result: dict | str | None, names: list[str]) -> list[str]:
    """A table's cells of places (found/labelled +false, then in brackets those found with the loose
    tolerances) per affordance, or why there is no map."""
    if not isinstance(result, dict):
        return [result or "no map"] * len(names)
    return [f"{r[0]}/{r[1]} +{r[2]} ({r[3]})" for r in (result.get(n, (0, 0, 0, 0)) for n in names)]


def timing_row(source: Source, hogs: int, run: dict, names: list[str], label: str) -> str:
    def seconds(key: str) -> str:
        value = run.get(key)
        return "-" if value is None else f"{value:.1f}"

    def cores(shares: dict[str, float], *names: str) -> str:
        return f"{sum(v for k, v in shares.items() if k.startswith(names)):.2f}"

    stream, tail = run["cpu stream"], run["cpu tail"]
    return (
        f"| {source.name} | {label} | {hogs} | {run['taken']} | {seconds('last pose')} | "
        f"{seconds('last map cloud')} | "
        f"{seconds('cloud to fields')} | "
        + " / ".join(seconds(f"cloud to {name}") for name in names)
        + f" | {run['clouds after']} / {run['fields after']} / {run['maps after']} | "
        + " / ".join(cores(shares, "assembler") for shares in (stream, tail))
        + " | "
        + " / ".join(cores(shares, "features", "inference") for shares in (stream, tail))
        + " | "
        + " / ".join(cores(shares, "hog") for shares in (stream, tail))
        + " |"
    )


def print_timings(rows: list[str], names: list[str]) -> None:
    print(
        "\nWhere the time goes: from the last scan sent to the assembler's last pose and last map cloud; from"
        " that cloud to its fields and to each map (" + " / ".join(names) + "); outputs after the last scan"
        " (clouds / fields / maps: each one worked on while the last waited); CPU in cores, while streaming"
        " / from the last scan to the last map\n"
    )
    print(
        "| source | settings | CPU hogs | frames taken | last pose (s) | last map cloud (s) "
        "| cloud to fields (s) | cloud to maps (s) | after the last scan | assembler cores "
        "| features + inference cores | hogs' cores |"
    )
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for row in rows:
        print(row)


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
