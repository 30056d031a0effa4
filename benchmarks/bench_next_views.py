"""Where to look next, as a robot uses it: from one depth frame of a generated room, the robot takes up to
`--views` more frames, each from the pose a policy picks, and the maps are scored after each against the
room's labels.

Rooms are `afford synth`'s room i of `--seed` (default: `benchmarks/accuracy.py`'s unseen seed, which no
data set of the project uses; the shipped models were trained on seed 1), made by the generator
(`synth.rooms.generate_room`, kinds dealt in turn) and seen only through the virtual scanner: a VGA Kinect
frame with the full noise model (`DepthCamera().with_kinect_noise()`, `scanner.depth_frame`), placed with the
frames style's small registration error, its sensor position kept as the frames style keeps it. The first
frame is taken where the frames style stands (`styles._piece_and_spot`: 1-2.5 m from a labelled piece),
facing the piece; every frame is taken with the robot's camera: `NextViewSettings.height` up, tilted
`--pitch` degrees (the next views are planned with the same tilt, `next_views.pitch_deg`).

After each frame the cloud so far (every frame's points, every frame's sensor position) is mapped as
`afford map --origins` maps it: `prepare_scene` with gravity "none" (the generator's world frame is already
levelled) and a `RoomMapper` per policy (each map updated from the last, as a robot's maps are), the three
shipped models. Then each policy picks the next pose:

* suggested: the best next view over the three maps' candidates together (`next_views.suggest_views`, as
  the inference service pools a robot's affordances);
* frontier: nearest-frontier exploration: of the positions where the robot can stand (`next_views._standable`,
  the same rule the views stand by), the nearest to the camera that lies within a grid step of a voxel column
  never seen (most of it unknown, none of it occupied; outside the fields' lattice counts as never seen),
  facing the mean direction of the never-seen columns within 2 m; a pose within 0.3 m and 45 degrees of one
  taken before is skipped;
* random: a random standable position and a random heading (seeded per room).

A policy with no pose to offer (no view gains 0.01 bits, no standable position) takes no frame: its maps stay
as they were. Places are counted as `afford map --labels` and `benchmarks/accuracy.py` count them
(`labels.match_places` on each map's skeletons: DESIGN.md's tolerances, 0.15 m and 0.4 rad; a skeleton in an
unlabelled region counts neither way; the accuracy benchmark's `PlaceCandidates.places` is the same rule
over the same candidates), against the labels of the whole room (`Room.labels()` without the scanned points:
every labelled place of the room, seen or not, so recall is of the room, not of what was scanned).

Prints per policy, per number of views taken and per affordance: places found / labelled, recall and false
skeletons per room; the seconds the next views take per map (the views of the three maps, apart from the
mapping); and the targets: after 3 suggested views place recall >= 0.8 per affordance, at least 1.5x the
places nearest-frontier finds after its 3, and the views within 1 s of a map. Then where the poses went: per
policy, how many were taken, none offered, the very pose of an earlier frame, outside the room's outline, or
where a robot of the footprint's radius (a square of that half-width, 15 cm up to the camera) would overlap
the true room's furniture; for the suggested views, why none was offered, and of the targets each view was
meant to see (by weight): inside a solid of the true room, outside the real camera's image, behind a
surface of the true room (seen or not), in sight, and next to a surface voxel of the fields; and how much of
that weight the frame taken there left unknown. Writes every result to --out/results.json (each room's
labels beside it).

    taskset -c 1 .venv/bin/python benchmarks/bench_next_views.py       # 64 rooms: about 15 min on one core
    taskset -c 1 .venv/bin/python benchmarks/bench_next_views.py --rooms 24 --pitch 0   # a level camera
    taskset -c 1 .venv/bin/python benchmarks/bench_next_views.py --rooms 2 --views 2    # a quick look
    taskset -c 1 .venv/bin/python benchmarks/bench_next_views.py --policies suggested+frontier

The loops are over rooms, policies and views; everything per pose is the library's (or vectorised here).
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from accuracy import UNSEEN_SEED  # noqa: E402  (the seed no data set of the project uses)

ROOT = Path(__file__).resolve().parents[1]
POLICIES = ("suggested", "frontier", "random", "suggested+frontier")
SUGGESTING = ("suggested", "suggested+frontier")  # the policies that ask for next views
FRAME_ERROR = (0.002, 0.1)  # m, degrees: a frame's registration error, as the frames style places its frames
FRONTIER_LOOK = 2.0  # m: a frontier view faces the never-seen columns within this distance
REVISIT = (0.3, np.radians(45))  # m, radians: a frontier pose this close to one taken before is skipped
TARGET_VIEWS, TARGET_RECALL, TARGET_RATIO, TARGET_SECONDS = 3, 0.8, 1.5, 1.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rooms", type=int, default=64, help="generated rooms (room 0, 1, ... of the seed)")
    parser.add_argument("--seed", type=int, default=UNSEEN_SEED, help="the rooms' seed (not 1: trained on)")
    parser.add_argument("--views", type=int, default=5, help="frames each policy takes after the first")
    parser.add_argument(
        "--suggest", type=int, default=3, help="next views each map suggests (the best is taken)"
    )
    parser.add_argument(
        "--pitch", type=float, default=-20.0, help="the camera's tilt (degrees, negative: down)"
    )
    parser.add_argument(
        "--policies",
        default=",".join(POLICIES[:3]),
        help=f"of {', '.join(POLICIES)} (the last: the suggested view, else the frontier's)",
    )
    parser.add_argument("--out", type=Path, default=ROOT / "bench-data" / "next-views")
    args = parser.parse_args()
    policies = args.policies.split(",")
    if set(policies) - set(POLICIES):
        raise SystemExit(f"--policies: choose from {', '.join(POLICIES)}")

    from threadpoolctl import threadpool_limits

    from affordcore.geometry.features import FeatureLayout
    from affordcore.learn.model import choose_models
    from affordcore.mapping.pipeline import preload
    from affordcore.settings import Settings

    started = time.perf_counter()
    settings = Settings()
    settings.next_views.pitch_deg = args.pitch
    # the maps are made without views; the views are asked for (and timed) apart
    settings.next_views.count = 0
    layout = FeatureLayout.from_settings(settings)
    models = choose_models([], [], layout)
    args.out.mkdir(parents=True, exist_ok=True)
    print(
        f"{args.rooms} rooms of seed {args.seed}, {args.views} views per policy ({', '.join(policies)}), "
        f"camera {settings.next_views.height} m up, {args.pitch:+.0f} deg; {os.cpu_count()} cores"
    )
    rooms = []
    with threadpool_limits(1):
        preload()
        for index in range(args.rooms):
            t0 = time.perf_counter()
            rooms.append(run_room(index, args, settings, layout, models, policies))
            print(
                f"  {rooms[-1]['room']}: {time.perf_counter() - t0:.0f} s; {room_line(rooms[-1])}", flush=True
            )
    wall = time.perf_counter() - started
    affordances = [model.affordance for model in models]
    table = summary(rooms, policies, affordances, args.views)
    view_seconds = [s for room in rooms for s in room["view_seconds"]]
    map_seconds = [s for room in rooms for p in room["policies"].values() for s in p["map_seconds"]]
    print_table(table, policies, affordances, args.views, len(rooms))
    timing = {
        "views_median_s": statistics.median(view_seconds) if view_seconds else None,
        "views_max_s": max(view_seconds) if view_seconds else None,
        "map_median_s": statistics.median(map_seconds) if map_seconds else None,
    }
    print(
        f"\nnext views per map (over the three maps' candidates, apart from mapping): median "
        f"{timing['views_median_s']:.3f} s, max {timing['views_max_s']:.3f} s over {len(view_seconds)} maps; "
        f"the mapping itself "
        f"(fields + three maps): median {timing['map_median_s']:.2f} s; {os.cpu_count()} cores"
    )
    targets = print_targets(table, affordances, timing)
    print(f"\n{len(rooms)} rooms in {wall / 60:.1f} min wall")
    notes = diagnostics(rooms)
    print_diagnostics(notes)
    document = {
        "command": " ".join(sys.argv),
        "seed": args.seed,
        "views": args.views,
        "suggest": args.suggest,
        "pitch_deg": args.pitch,
        "cores": os.cpu_count(),
        "wall_s": wall,
        "settings": {
            "next_views": settings.next_views.model_dump(),
            "visibility": settings.visibility.model_dump(),
        },
        "models": {model.affordance: model.id for model in models},
        "table": table,
        "timing": timing,
        "targets": targets,
        "diagnostics": notes,
        "rooms": rooms,
    }
    path = args.out / "results.json"
    path.write_text(json.dumps(document, indent=1, default=_jsonable) + "\n")
    print(f"wrote {path}")


def _jsonable(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"{type(value)} is not JSON")


# ---------------------------------------------------------------------------------------------- one room


def run_room(index: int, args, settings, layout, models, policies: list[str]) -> dict:
    """One room: its first frame mapped once, then each policy's views from there."""
    from affordcore.labels import load_labels
    from affordcore.mapping.pipeline import RoomMapper
    from affordcore.mapping.updates import NormalCache
    from affordcore.synth.dataset import SynthOptions
    from affordcore.synth.rooms import generate_room
    from affordcore.synth.scanner import DepthCamera, Raycaster
    from affordcore.synth.styles import _piece_and_spot

    options = SynthOptions(rooms=args.rooms, seed=args.seed)
    name = options.room_name(index)
    rng = np.random.default_rng(np.random.SeedSequence(args.seed).spawn(index + 1)[index])
    room = generate_room(options.kinds[index % len(options.kinds)], rng, name)
    labels_path = args.out / f"{name}.labels.json"
    labels_path.write_text(json.dumps(room.labels(), indent=1) + "\n")  # every place of the room, seen or not
    labels = load_labels(labels_path)
    raycaster = Raycaster(room.shell_boxes() + room.furniture_boxes())
    camera = DepthCamera().with_kinect_noise()
    piece, spot = _piece_and_spot(room, rng)
    if piece is not None:
        lo, hi = piece.local_bounds()
        aim = piece.world_point((lo + hi) / 2) - spot
    else:
        aim = rng.normal(size=2)
    first = (float(spot[0]), float(spot[1]), settings.next_views.height, float(np.arctan2(aim[1], aim[0])))

    start = Exploration(settings, layout, RoomMapper(models, layout, settings), NormalCache())
    start.take(first, raycaster, camera, rng, settings.next_views.pitch_deg)
    start.map()
    result = {
        "room": name,
        "kind": room.kind,
        "size_m": np.ptp(room.polygon, axis=0).round(2).tolist(),
        "labels": {a: len(labels.of(a)) for a in start.maps},
        "first": first,
        "policies": {},
        "view_seconds": [],
    }
    for policy in policies:
        explore = copy.deepcopy(start, {id(model): model for model in models})  # the models are shared
        choose = np.random.default_rng([args.seed, index, POLICIES.index(policy)])  # random's draws
        frame_rng = np.random.default_rng([args.seed, index, 99])  # the same sensor noise for every policy
        steps = [explore.record(labels, room, None)]
        for _ in range(args.views):
            aimed = policy in SUGGESTING
            if aimed:
                suggested, seconds = explore.suggest(args.suggest, room, raycaster, camera)
                result["view_seconds"].append(seconds)
                steps[-1]["suggested"] = suggested
                pose = pose_of_view(suggested)
                aimed = pose is not None
                if pose is None and policy == "suggested+frontier":
                    pose = frontier_view(explore.fields, settings.next_views, explore.poses)
            elif policy == "frontier":
                pose = frontier_view(explore.fields, settings.next_views, explore.poses)
            else:
                pose = random_view(explore.fields, settings.next_views, choose)
            if pose is not None:
                explore.take(pose, raycaster, camera, frame_rng, settings.next_views.pitch_deg)
                explore.map()
            steps.append(explore.record(labels, room, pose))
            if aimed:
                steps[-2]["suggested"].update(explore.seen_after())
        result["policies"][policy] = {"steps": steps, "map_seconds": explore.map_seconds}
    return result


class Exploration:
    """One policy's robot: the frames so far, their sensor positions, and the maps of them."""

    def __init__(self, settings, layout, mapper, normals):
        self.settings, self.layout, self.mapper, self.normals = settings, layout, mapper, normals
        self.points: list[np.ndarray] = []
        self.origins: list[np.ndarray] = []
        self.poses: list[tuple] = []  # (x, y, z, heading) of each frame
        self.fields = None
        self.maps: dict = {}
        self.map_seconds: list[float] = []

    def take(self, pose: tuple, raycaster, camera, rng, pitch_deg: float) -> None:
        """A frame from the pose (x, y, z, heading) at the camera's tilt, added to the cloud."""
        from affordcore.synth.scanner import backproject, depth_frame, look_at, perturbed

        x, y, z, heading = pose
        pitch = np.radians(pitch_deg)
        eye = np.array([x, y, z])
        ahead = np.array([np.cos(heading) * np.cos(pitch), np.sin(heading) * np.cos(pitch), np.sin(pitch)])
        cam_to_world = look_at(eye, eye + ahead)
        depth, _ = depth_frame(raycaster, camera, cam_to_world, rng)
        self.points.append(backproject(depth, camera, perturbed(cam_to_world, rng, FRAME_ERROR)))
        self.origins.append(eye)
        self.poses.append(tuple(float(v) for v in pose))

    def map(self) -> None:
        """The cloud so far mapped as afford map --origins maps it, updated from the last maps."""
        from affordcore.geometry.scene import Cloud
        from affordcore.mapping.pipeline import prepare_scene

        t0 = time.perf_counter()
        cloud = Cloud(np.concatenate(self.points), origins=np.array(self.origins))
        scene = prepare_scene(cloud, self.settings, "none", normals=self.normals)
        self.fields = scene.fields
        self.maps = self.mapper.maps(scene.fields)
        self.map_seconds.append(time.perf_counter() - t0)

    def suggest(self, count: int, room, raycaster, camera) -> tuple[dict | None, float]:
        """The best next view over the three maps' candidates (as the inference service asks for them) and
        the seconds the views took; with what the view was meant to see, or why there was none."""
        from affordcore.mapping.next_views import suggest_views

        settings = self.settings.model_copy(deep=True)
        settings.next_views.count = count
        t0 = time.perf_counter()
        views = suggest_views(self.fields, list(self.maps.values()), settings)
        seconds = time.perf_counter() - t0
        if not views:
            self.expected = None
            return {"none": self.why_none()}, seconds
        best = {"affordances": views[0].affordances, **views[0].to_json()}
        best.update(self.aimed_at(room, raycaster, camera, views[0]))
        return best, seconds

    def targets(self):
        """The maps' targets as `suggest_views` takes them: (never-seen voxel centres, their weights) of
        the three maps' candidates together, and of the never-seen room no candidate stands in."""
        from affordcore.mapping import next_views as nv

        maps = [m.candidates for m in self.maps.values() if len(m.candidates)]
        c = np.concatenate(maps) if maps else np.zeros((0, 6))
        wanted, body = self.settings.next_views, self.settings.visibility
        targets, _, weight = nv.view_targets(self.fields, c[:, :2], c[:, 5], wanted, body)
        return targets, weight

    def why_none(self) -> str:
        """Why no map suggested a view: nowhere to stand, nothing unsure is unseen (no candidate and nothing
        of the unseen room worth a view, candidates sure, or their body space seen), or every target out of
        sight of every standable pose."""
        from affordcore.mapping import next_views as nv

        if not len(nv._standable(self.fields, self.settings.next_views, self.settings.next_views.height)):
            return "nowhere to stand"
        if not any(len(m.candidates) for m in self.maps.values()):
            return "no candidate place, and no view of the unseen room worth the drive"
        if self.targets()[1].sum() < nv._MIN_GAIN:
            return "nothing unsure is unseen"
        return "targets out of sight"

    def aimed_at(self, room, raycaster, camera, view) -> dict:
        """What the view is meant to see (its targets, kept for `seen_after`; their bits against the view's
        gain) and, in the true room, what of it the frame cannot see, by weight: targets inside a solid
        (a sofa's base, a cabinet: unknown whatever looks at them), outside the camera's image (the views'
        angular field of view against the pinhole's), or behind a surface (the room's, seen or not: the
        views count unknown voxels as clear)."""
        from scipy import ndimage

        from affordcore.mapping import next_views as nv
        from affordcore.synth.scanner import look_at

        targets, weight = self.targets()
        settings = self.settings.next_views
        heading = int(round(view.heading / (2 * np.pi / settings.headings))) % settings.headings
        eye = np.array([view.x, view.y, view.z])
        seen = nv.seen_by_view(self.fields, eye, heading, targets, settings)
        targets, weight = targets[seen], weight[seen]
        total = float(weight.sum())
        lattice = self.fields.lattice
        index = np.clip(np.rint((targets - lattice.origin) / lattice.resolution).astype(int), 0, None)
        grown = ndimage.binary_dilation(self.fields.occupancy > 0, np.ones((3, 3, 3), bool))
        near = grown[index[:, 0], index[:, 1], index[:, 2]]  # a surface voxel among its 26 neighbours
        self.expected = (targets, weight, near)
        solid = np.zeros(len(targets), bool)
        for box in room.furniture_boxes() + room.walls:
            low, high = box.z_range
            solid |= box.contains_xy(targets[:, :2]) & (targets[:, 2] >= low) & (targets[:, 2] <= high)
        pitch = np.radians(settings.pitch_deg)
        ahead = np.array(
            [np.cos(view.heading) * np.cos(pitch), np.sin(view.heading) * np.cos(pitch), np.sin(pitch)]
        )
        pose = look_at(eye, eye + ahead)
        local = (targets - eye) @ pose[:3, :3]  # the camera frame: x right, y down, z forward
        depth = np.maximum(local[:, 2], 1e-9)
        u, v = camera.fx * local[:, 0] / depth + camera.cx, camera.fy * local[:, 1] / depth + camera.cy
        in_image = (local[:, 2] >= camera.min_range) & (local[:, 2] <= camera.max_range)
        in_image &= (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height)
        offset = targets - eye
        hit, _, _ = raycaster.cast(np.broadcast_to(eye, offset.shape), offset)
        length = np.linalg.norm(offset, axis=1)
        behind = hit < 1 - 1.5 * self.fields.lattice.resolution / length  # as the views spare the end

        def share(mask):
            return float(weight[mask].sum() / total) if total else 0.0

        return {
            "targets": int(len(targets)),
            "target_bits": total,
            "inside_solids": share(solid),
            "outside_image": share(~solid & ~in_image),
            "behind_surface": share(~solid & in_image & behind),
            "in_sight": share(~solid & in_image & ~behind),
            "next_to_surface": share(near),
        }

    def seen_after(self) -> dict:
        """Of the weight the last suggested view was meant to see, the share no longer unknown now: of all of
        it, of the targets next to a surface voxel when the view was chosen, and of the rest."""
        from affordcore.geometry.visibility import UNKNOWN

        targets, weight, near = self.expected
        lattice = self.fields.lattice
        index = np.rint((targets - lattice.origin) / lattice.resolution).astype(int)
        inside = ((index >= 0) & (index < np.array(lattice.shape))).all(axis=1)
        index = np.clip(index, 0, np.array(lattice.shape) - 1)
        known = inside & (self.fields.visibility[index[:, 0], index[:, 1], index[:, 2]] != UNKNOWN)

        def share(mask):
            return float(weight[known & mask].sum() / weight[mask].sum()) if weight[mask].sum() else None

        everything = np.ones(len(weight), bool)
        return {
            "seen_after": share(everything),
            "seen_after_near": share(near),
            "seen_after_clear": share(~near),
        }

    def record(self, labels, room, pose: tuple | None) -> dict:
        """The maps now against the room's labels, and what the pose that led here was."""
        from affordcore.labels import match_places
        from affordcore.mapping.next_views import _standable, entropy_bits

        step = {"frames": len(self.points), "points": int(sum(len(p) for p in self.points)), "pose": pose}
        standable = _standable(self.fields, self.settings.next_views, self.settings.next_views.height)
        here = np.array(self.poses[-1][:2])
        step["standable"] = len(standable)
        step["standable_within_1m"] = int((np.linalg.norm(standable - here, axis=1) <= 1.0).sum())
        if pose is not None:
            step.update(where(room, pose, self.settings.next_views.footprint))
        for affordance, amap in self.maps.items():
            match = match_places(labels, affordance, amap.skeletons[:, [0, 1, 3]])
            p = amap.candidates[:, 5] if len(amap.candidates) else np.empty(0)
            step[affordance] = {
                "found": int(match.found.sum()),
                "labelled": len(match.found),
                "false": int(match.false.sum()),
                "skeletons": len(amap.skeletons),
                "candidates": len(p),
                "candidate_bits": float(entropy_bits(p).sum()) if len(p) else 0.0,
            }
        return step


def pose_of_view(view: dict) -> tuple | None:
    return None if "none" in view else (view["x"], view["y"], view["z"], view["heading"])


def where(room, pose: tuple, footprint: float) -> dict:
    """Where a pose stands in the true room: inside its outline, and whether a robot of the footprint there
    would overlap furniture or a wall."""
    from affordcore.synth.rooms import inside_polygon
    from affordcore.synth.shapes import Box, overlaps_any

    x, y, z, _ = pose
    body = Box((x, y, z / 2 + 0.075), (2 * footprint, 2 * footprint, z - 0.15))  # 15 cm up to the camera
    return {
        "inside_room": bool(inside_polygon(room.polygon, np.array([[x, y]]))[0]),
        "collides": bool(overlaps_any([body], room.furniture_boxes() + room.walls)[0]),
    }


# ---------------------------------------------------------------------------------------------- policies


def _columns(fields, eye_z: float) -> np.ndarray:
    """(nx, ny) bool: voxel columns never seen, from two layers above the floor to the camera (where
    `_standable` looks): most voxels unknown and none occupied."""
    from affordcore.geometry.visibility import OCCUPIED, UNKNOWN
    from affordcore.mapping.next_views import _floor_layer

    lattice, state = fields.lattice, fields.visibility
    floor = _floor_layer(fields)
    top = min(int(np.ceil((eye_z - lattice.origin[2]) / lattice.resolution)), lattice.shape[2] - 1)
    column = state[:, :, floor + 2 : top + 1]
    return ((column == UNKNOWN).mean(axis=2) >= 0.5) & ~(column == OCCUPIED).any(axis=2)


def frontier_view(fields, settings, taken: list[tuple]) -> tuple | None:
    """Nearest-frontier exploration: the standable position nearest the last camera that lies within a grid
    step of a never-seen column (outside the lattice counts as never seen), facing the never-seen columns
    within FRONTIER_LOOK; None when there is none."""
    from scipy import ndimage

    from affordcore.geometry.fields import disc
    from affordcore.mapping.next_views import _standable

    eye_z = settings.height
    positions = _standable(fields, settings, eye_z)
    if not len(positions):
        return None
    lattice = fields.lattice
    res = lattice.resolution
    pad = int(np.ceil(FRONTIER_LOOK / res)) + 1
    unknown = np.pad(_columns(fields, eye_z), pad, constant_values=True)  # beyond the lattice: never seen
    reach = max(1, int(round(settings.step / res)))
    border = ndimage.binary_dilation(unknown, disc(reach))
    index = np.rint((positions - lattice.origin[:2]) / res).astype(int) + pad
    frontier = positions[border[index[:, 0], index[:, 1]] & ~unknown[index[:, 0], index[:, 1]]]
    if not len(frontier):
        return None
    here = np.array(taken[-1][:2])
    looked = np.array([pose[:2] for pose in taken]), np.array([pose[3] for pose in taken])
    ui, uj = np.nonzero(unknown)
    unknown_xy = lattice.origin[:2] + (np.column_stack([ui, uj]) - pad) * res
    for xy in frontier[np.argsort(np.linalg.norm(frontier - here, axis=1), kind="stable")]:
        offset = unknown_xy - xy
        distance = np.linalg.norm(offset, axis=1)
        near = (distance > 0) & (distance <= FRONTIER_LOOK)
        direction = (offset[near] / distance[near, None]).sum(axis=0)
        heading = float(np.arctan2(direction[1], direction[0]))
        close = np.linalg.norm(looked[0] - xy, axis=1) <= REVISIT[0]
        turned = np.abs(np.angle(np.exp(1j * (looked[1] - heading)))) <= REVISIT[1]
        if not (close & turned).any():
            return (float(xy[0]), float(xy[1]), eye_z, heading)
    return None


def random_view(fields, settings, rng: np.random.Generator) -> tuple | None:
    """A random standable position, a random heading."""
    from affordcore.mapping.next_views import _standable

    positions = _standable(fields, settings, settings.height)
    if not len(positions):
        return None
    x, y = positions[int(rng.integers(len(positions)))]
    return (float(x), float(y), settings.height, float(rng.uniform(-np.pi, np.pi)))


# ---------------------------------------------------------------------------------------------- tables


def summary(rooms: list[dict], policies: list[str], affordances: list[str], views: int) -> dict:
    """{policy: {views taken: {affordance: found, labelled, recall, false per room}}}."""
    table: dict = {}
    for policy in policies:
        table[policy] = {}
        for v in range(views + 1):
            row = {}
            for a in affordances:
                steps = [room["policies"][policy]["steps"][v][a] for room in rooms]
                found, labelled = sum(s["found"] for s in steps), sum(s["labelled"] for s in steps)
                false = sum(s["false"] for s in steps)
                row[a] = {
                    "found": found,
                    "labelled": labelled,
                    "recall": found / labelled if labelled else float("nan"),
                    "false_per_room": false / len(rooms),
                }
            table[policy][v] = row
    return table


def print_table(table: dict, policies: list[str], affordances: list[str], views: int, rooms: int) -> None:
    print(f"\nplaces found / labelled, recall, false skeletons per room ({rooms} rooms):")
    print("| policy | views | " + " | ".join(affordances) + " |")
    print("|---|---:|" + "---|" * len(affordances))
    for policy in policies:
        for v in range(views + 1):
            cells = [
                f"{c['found']}/{c['labelled']}, {c['recall']:.2f}, {c['false_per_room']:.2f}"
                for c in (table[policy][v][a] for a in affordances)
            ]
            print(f"| {policy} | {v} | " + " | ".join(cells) + " |")


def print_targets(table: dict, affordances: list[str], timing: dict) -> dict:
    targets: dict = {}
    print("\ntargets:")
    if "suggested" in table and TARGET_VIEWS in table["suggested"]:
        after = table["suggested"][TARGET_VIEWS]
        recall = {a: after[a]["recall"] for a in affordances}
        met = all(r >= TARGET_RECALL for r in recall.values())
        targets["recall"] = {"per_affordance": recall, "met": met}
        print(
            f"* after {TARGET_VIEWS} suggested views, place recall >= {TARGET_RECALL} per affordance: "
            + ", ".join(f"{a} {r:.2f}" for a, r in recall.items())
            + f": {'met' if met else 'NOT met'}"
        )
        if "frontier" in table:
            frontier = table["frontier"][TARGET_VIEWS]
            ratios = {
                a: after[a]["found"] / frontier[a]["found"] if frontier[a]["found"] else float("inf")
                for a in affordances
            }
            total = sum(after[a]["found"] for a in affordances) / max(
                sum(frontier[a]["found"] for a in affordances), 1
            )
            met = all(r >= TARGET_RATIO for r in ratios.values())
            targets["versus_frontier"] = {"per_affordance": ratios, "all": total, "met": met}
            print(
                f"* at least {TARGET_RATIO}x the places nearest-frontier finds after {TARGET_VIEWS} views: "
                + ", ".join(
                    f"{a} {after[a]['found']} vs {frontier[a]['found']} ({r:.2f}x)" for a, r in ratios.items()
                )
                + f"; all {total:.2f}x: {'met' if met else 'NOT met'}"
            )
    seconds = timing["views_median_s"]
    if seconds is not None:
        met = seconds <= TARGET_SECONDS
        targets["seconds"] = {"median": seconds, "max": timing["views_max_s"], "met": met}
        print(
            f"* next views within {TARGET_SECONDS} s of a map: median {seconds:.3f} s, max "
            f"{timing['views_max_s']:.3f} s: {'met' if met else 'NOT met'}"
        )
    return targets


def room_line(room: dict) -> str:
    """A room's places found after its last view, per policy."""
    parts = []
    for policy, result in room["policies"].items():
        last = result["steps"][-1]
        found = sum(last[a]["found"] for a in room["labels"])
        parts.append(f"{policy} {found}")
    first = room["policies"][next(iter(room["policies"]))]["steps"][0]
    labelled = sum(room["labels"].values())
    return f"{labelled} labelled, first frame {sum(first[a]['found'] for a in room['labels'])}; " + ", ".join(
        parts
    )


def diagnostics(rooms: list[dict]) -> dict:
    """Where the poses went: per policy, poses taken, none offered, outside the room, overlapping the room's
    furniture; and for the suggested views, why none was offered, their gains, how much of what each was meant
    to see lay inside solids, and how much of it the frame taken there saw."""
    notes: dict = {}
    for policy in POLICIES:
        steps = [
            s for room in rooms if policy in room["policies"] for s in room["policies"][policy]["steps"][1:]
        ]
        if not steps:
            continue
        taken = [s for s in steps if s["pose"] is not None]
        repeats = 0
        for room in rooms:
            poses = [s["pose"] for s in room["policies"].get(policy, {"steps": []})["steps"][1:] if s["pose"]]
            repeats += sum(
                any(np.allclose(pose, earlier, atol=1e-6) for earlier in poses[:k])
                for k, pose in enumerate(poses)
            )
        notes[policy] = {
            "repeats": repeats,
            "steps": len(steps),
            "taken": len(taken),
            "none_offered": len(steps) - len(taken),
            "outside_room": sum(not s["inside_room"] for s in taken),
            "collides": sum(s["collides"] for s in taken),
        }
    for policy in SUGGESTING:
        asked = [
            s["suggested"]
            for room in rooms
            if policy in room["policies"]
            for s in room["policies"][policy]["steps"]
            if "suggested" in s
        ]
        if not asked:
            continue
        views = [a for a in asked if "none" not in a]
        reasons: dict = {}
        for a in asked:
            if "none" in a:
                reasons[a["none"]] = reasons.get(a["none"], 0) + 1
        notes[policy]["why_none"] = reasons
        if views:
            notes[policy]["gain_bits"] = _spread([v["gain"] for v in views])
            for key in ("inside_solids", "outside_image", "behind_surface", "in_sight", "next_to_surface"):
                notes[policy][key] = _spread([v[key] for v in views])
            for key in ("seen_after", "seen_after_near", "seen_after_clear"):
                seen = [v[key] for v in views if v.get(key) is not None]
                notes[policy][key] = _spread(seen) if seen else None
            notes[policy]["seen_pooled"] = _pooled([v for v in views if v.get("seen_after") is not None])
    return notes


def _pooled(views: list[dict]) -> dict:
    """Of all the weight the views were meant to see, the share no longer unknown after their frames (of
    all of it, next to a surface, the rest)."""
    bits = np.array([v["target_bits"] for v in views])
    near = bits * np.array([v["next_to_surface"] for v in views])
    seen = np.array([v["seen_after"] for v in views])
    seen_near = np.array([v["seen_after_near"] or 0.0 for v in views])
    seen_clear = np.array([v["seen_after_clear"] or 0.0 for v in views])
    return {
        "all": float((bits * seen).sum() / bits.sum()) if bits.sum() else None,
        "near": float((near * seen_near).sum() / near.sum()) if near.sum() else None,
        "clear": float(((bits - near) * seen_clear).sum() / (bits - near).sum())
        if (bits - near).sum()
        else None,
    }


def _spread(values: list[float]) -> dict:
    return {"median": statistics.median(values), "min": min(values), "max": max(values), "n": len(values)}


def print_diagnostics(notes: dict) -> None:
    print("\nwhere the poses went:")
    for policy, n in notes.items():
        print(
            f"* {policy}: {n['taken']} of {n['steps']} poses taken ({n['none_offered']} none offered, "
            f"{n['repeats']} the very pose of an earlier frame), "
            f"{n['outside_room']} outside the room, {n['collides']} where the robot would overlap furniture "
            "or a wall"
        )
    for policy in SUGGESTING:
        n = notes.get(policy, {})
        if n.get("why_none") or n.get("gain_bits"):
            print(f"  {policy}:")
        if n.get("why_none"):
            print(
                "  no suggested view: " + ", ".join(f"{why} {count}" for why, count in n["why_none"].items())
            )
        if n.get("gain_bits"):
            g = n["gain_bits"]
            print(
                f"  suggested views: best gain median {g['median']:.2f} bits ({g['min']:.2f}-{g['max']:.2f})"
            )
            print(
                "  of what each was meant to see (by weight, medians): "
                + ", ".join(
                    f"{key.replace('_', ' ')} {n[key]['median']:.2f}"
                    for key in ("inside_solids", "outside_image", "behind_surface", "in_sight")
                )
                + f" in the true room; next to a surface voxel {n['next_to_surface']['median']:.2f}"
            )
            pooled = n.get("seen_pooled", {})
            if pooled.get("all") is not None:
                print(
                    "  no longer unknown after its frame (of the weight, pooled over the views): "
                    + ", ".join(
                        f"{label} {pooled[k]:.2f}"
                        for k, label in (
                            ("all", "all of it"),
                            ("near", "next to a surface"),
                            ("clear", "the rest"),
                        )
                        if pooled.get(k) is not None
                    )
                    + f"; median per view {n['seen_after']['median']:.2f}"
                )


if __name__ == "__main__":
    main()
