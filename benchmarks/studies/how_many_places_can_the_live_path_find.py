"""How many of a room's places the live path could find at best, each figure a mean over grid placements.

The target: the live maps of a stream to find 90 % of the places `afford map` finds in the room's fused
cloud. One map's count moves by a place or two with where the 10 cm pose grid happens to fall on the room
(docs/accuracy.md): so every cloud below is mapped `--shifts` times, moved by a different sub-cell amount
each time (the first not at all), and the places are the mean over those maps. The clouds, from the offline
reference down to what the assembler publishes:

* the fused room (`afford map`'s input, the offline path);
* the fused room's own frames at their true poses, every pixel, 1.5 cm means (as its README says it was made);
* the streamed frames (every `--step`-th) that the assembler keeps as keyframes, at their true poses, through
  the assembler's map step (block means without depth edges, 2 cm means): in the room's frame, then levelled
  on their own floor as the assembler levels its map;
* the same keyframes at the assembler's poses (registered in this process, every frame taken), as published;
* and at those poses refined by a pose graph over the keyframes (open3d: point-to-plane ICP between every
  pair of keyframes that see each other, Levenberg-Marquardt over the graph): whether a better trajectory
  without odometry would close the gap. Not part of the assembler: a measurement of what it could give.

Every map is placed on the labels by ICP of its cloud onto the fused room (bench_live's scoring). The
trajectory errors are against the true poses, anchored at the first frame.

    .venv/bin/python benchmarks/studies/how_many_places_can_the_live_path_find.py   # the kitchen, ~10 min
    .venv/bin/python benchmarks/studies/how_many_places_can_the_live_path_find.py --generated 2   # + 2 walks
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_live import RoomScore, Source, add_source_arguments, sources, voxel_means  # noqa: E402

from affordcore.assembly.assembler import Assembler, SensorFrame, trajectory_errors, within_range  # noqa: E402
from affordcore.assembly.depth import DepthImage, back_project  # noqa: E402
from affordcore.assembly.sequence import read_sequence  # noqa: E402
from affordcore.geometry.scene import load_cloud  # noqa: E402
from affordcore.learn.model import load_model, shipped_models  # noqa: E402
from affordcore.settings import Settings  # noqa: E402

# the room's README: its frames "fused at 1 to 1.5 cm"
FUSED_VOXEL = 0.015
# every 10th frame of the sequence made the fused kitchen
FUSED_EVERY = 10
# keyframes further apart than this (m) are not paired in the pose graph (a depth camera's few metres)
PAIR_REACH = 1.5


def grid_shifts(count: int) -> np.ndarray:
    """`count` horizontal moves of a cloud within one 10 cm grid cell, the first none (a fixed draw)."""
    rng = np.random.default_rng(0)
    moves = np.zeros((count, 3))
    moves[1:, :2] = rng.uniform(0.0, 0.1, size=(count - 1, 2))
    return moves


class Scorer:
    """Maps a cloud at each grid placement and counts its places against the room's labels."""

    def __init__(self, source: Source, settings: Settings, models: list, shifts: np.ndarray):
        self.score, self.shifts = RoomScore(source, settings, models), shifts

    def __call__(self, points: np.ndarray, room_from_input: np.ndarray, level: bool) -> dict:
        """{affordance: (mean found, labelled, mean false, mean found within DESIGN.md's loose tolerances)}
        over the placements, and the mean ICP RMSE onto the room (m). `level`: levelled on the floor found
        along +z (as the assembler levels its map under the frames' gravity); else mapped as it is (already
        z up, floor at 0)."""
        counts, rmses = zip(*(self.score(points, room_from_input, level, move) for move in self.shifts))
        means = {
            name: (
                float(np.mean([c[name][0] for c in counts])),
                counts[0][name][1],
                float(np.mean([c[name][2] for c in counts])),
                float(np.mean([c[name][3] for c in counts])),
            )
            for name in counts[0]
        }
        totals = [sum(c[name][0] for name in c) for c in counts]
        return {"places": means, "totals": totals, "rmse": float(np.mean(rmses))}


def refined_keyframes(clouds: list[np.ndarray], poses: list[np.ndarray], voxel: float = 0.03) -> np.ndarray:
    """Keyframe poses (odom_from_sensor) after a pose graph over the keyframes' clouds (sensor frame):
    consecutive pairs as odometry edges, and every other pair within `PAIR_REACH` whose clouds overlap (a
    30 % of one's points within the ICP's reach of the other) as a loop edge that the optimisation may prune
    (open3d's multiway registration)."""
    import open3d as o3d

    registration = o3d.pipelines.registration

    def cloud(points):
        made = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points)).voxel_down_sample(voxel)
        made.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=3 * voxel, max_nn=30))
        return made

    made = [cloud(c) for c in clouds]
    graph = registration.PoseGraph()
    for pose in poses:
        graph.nodes.append(registration.PoseGraphNode(pose))
    positions = np.array([pose[:3, 3] for pose in poses])
    for i in range(len(made)):
        for j in range(i + 1, len(made)):
            if j > i + 1 and np.linalg.norm(positions[i] - positions[j]) > PAIR_REACH:
                continue
            transform = np.linalg.inv(poses[j]) @ poses[i]
            for distance in (4 * voxel, 2 * voxel, voxel):
                result = registration.registration_icp(
                    made[i], made[j], distance, transform, registration.TransformationEstimationPointToPlane()
                )
                transform = result.transformation
            if j > i + 1 and result.fitness < 0.3:
                continue
            information = registration.get_information_matrix_from_point_clouds(
                made[i], made[j], voxel, transform
            )
            graph.edges.append(registration.PoseGraphEdge(i, j, transform, information, uncertain=j > i + 1))
    option = registration.GlobalOptimizationOption(
        max_correspondence_distance=voxel, edge_prune_threshold=0.25, reference_node=0
    )
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    registration.global_optimization(
        graph,
        registration.GlobalOptimizationLevenbergMarquardt(),
        registration.GlobalOptimizationConvergenceCriteria(),
        option,
    )
    return np.array([node.pose for node in graph.nodes])


def clouds_of(source: Source, step: int, settings: Settings) -> dict[str, tuple[Callable, np.ndarray, bool]]:
    """Each cloud of the table (made when asked), its guess of room_from_input, and whether to level it."""
    sequence, a = read_sequence(source.sequence), settings.assembler
    indices = list(range(0, len(sequence.frames), step))

    def image(i):
        return DepthImage(sequence.depth(i), sequence.intrinsics, 0.001, 65535)

    def map_blocks(i):  # what a keyframe adds to the assembler's map (Assembler.depth_points, range filter)
        blocks = back_project(image(i), a.pixel_step, a.min_range, a.max_range, max_spread=a.map_edge_spread)
        return within_range(blocks, a)

    assembler, keyframes = Assembler(a), []
    for i in indices:
        stamp = 1.0 + i / 30
        frame = SensorFrame(
            "camera", stamp, depth=image(i), gravity=sequence.gravity(i), pose_guess=sequence.odometry(i)
        )
        if assembler.add(frame, stamp).map_points is not None:
            keyframes.append(i)
    truth = {i: source.room_from_truth @ sequence.pose(i) for i in indices}
    estimated = dict(zip(indices, assembler.trajectory.poses))
    blocks = [map_blocks(i) for i in keyframes]
    started = time.process_time()
    refined = refined_keyframes(blocks, [estimated[i] for i in keyframes])
    refine_seconds = time.process_time() - started
    anchor = truth[indices[0]]
    published, world_from_odom = assembler.aligned_map(settings)
    fused_frames = range(0, len(sequence.frames), FUSED_EVERY)
    errors = {
        "assembler": trajectory_errors([estimated[i] for i in keyframes], [truth[i] for i in keyframes]),
        "refined": trajectory_errors(
            list(np.linalg.inv(refined[0]) @ refined), [truth[i] for i in keyframes]
        ),
    }
    registered, better = (f"{e['mean_m'] * 100:.1f} / {e['worst_m'] * 100:.1f} cm" for e in errors.values())
    print(
        f"{source.name}: {len(indices)} frames, {len(keyframes)} keyframes; keyframe trajectory error mean /"
        f" worst {registered} as registered, {better} refined ({refine_seconds:.1f} s of CPU to refine)",
        flush=True,
    )
    room_frame = np.eye(4)
    # one cloud for two rows: mapped as it is, and levelled
    at_truth = functools.cache(lambda: voxel_means(blocks, [truth[i] for i in keyframes], a.map_voxel))
    return {
        "the fused room (afford map)": (
            lambda: load_cloud(source.room.with_suffix(".ply")).points,
            room_frame,
            False,
        ),
        f"its frames (every {FUSED_EVERY}th) at the true poses, all pixels, {FUSED_VOXEL * 100:g} cm means": (
            lambda: voxel_means(
                [back_project(image(i), 1, a.min_range, a.max_range) for i in fused_frames],
                [source.room_from_truth @ sequence.pose(i) for i in fused_frames],
                FUSED_VOXEL,
            ),
            room_frame,
            False,
        ),
        "the keyframes at the true poses, the map step": (at_truth, room_frame, False),
        "... levelled on their own floor": (at_truth, room_frame, True),
        "the keyframes at the assembler's poses, as published": (
            lambda: published,
            anchor @ np.linalg.inv(world_from_odom),
            False,
        ),
        "... anchored at the first true pose, levelled on their own floor": (
            lambda: voxel_means(blocks, [anchor @ estimated[i] for i in keyframes], a.map_voxel),
            room_frame,
            True,
        ),
        "... refined by a pose graph, anchored and levelled the same way": (
            lambda: voxel_means(blocks, anchor @ refined, a.map_voxel),
            room_frame,
            True,
        ),
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    add_source_arguments(parser)
    parser.set_defaults(generated=0)
    parser.add_argument("--shifts", type=int, default=4, help="grid placements each cloud is mapped at")
    args = parser.parse_args()
    settings = Settings()
    models = [load_model(path) for path in shipped_models().values()]
    names = [m.affordance for m in models]
    print(
        f"{os.cpu_count()} cores; one frame in {args.step} streamed; means over {args.shifts} grid "
        "placements\n"
    )
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for source in sources(args, Path(tmp) / "generated"):
            score = Scorer(source, settings, models, grid_shifts(args.shifts))
            for made, (cloud, room_from_input, level) in clouds_of(source, args.step, settings).items():
                result = score(cloud(), room_from_input, level)
                cells = ["{:.2f}/{} +{:.2f} ({:.2f})".format(*result["places"][name]) for name in names]
                totals = result["totals"]
                rows.append(
                    f"| {source.name} | {made} | "
                    + " | ".join(cells)
                    + f" | {np.mean(totals):.2f} ({min(totals)}-{max(totals)}) | {result['rmse'] * 100:.2f} |"
                )
                print(rows[-1], file=sys.stderr, flush=True)
    print(
        "\n| source | made from | "
        + " | ".join(names)
        + " | places, mean (range) | ICP RMSE onto the room (cm) |"
    )
    print("|---|---|" + "---:|" * (len(names) + 2))
    for row in rows:
        print(row)


if __name__ == "__main__":
    main()
