"""Where the CPU of a live map's last round goes: the steps of the features and inference services
in one process, without transport or load, so that a change to one step is measured on its own.

For each source of benchmarks/bench_live.py (the real 7-Scenes kitchen and generated `afford synth
--sequences` walks), every --step-th depth frame goes through the assembler in this process; its map cloud
(with the sensor positions the assembler sends) after --earlier of the frames and after the last one are the
two last map clouds of a walk. Each goes through what the services do with it, in order: the features
service's `prepare_scene` with its `NormalCache` (the fields of the second reuse the first's normals where the
cloud did not change) and the inference service's `RoomMapper` (the second maps update the first). The
second round is timed, CPU seconds, medians over --repeats: the fields; each affordance's maps and, of them,
the linear stage (`score_poses`), the second stage's features (`features_at`) and its trees
(`TreeEnsemble.log_odds`); and the share of the poses the update rescored.

    .venv/bin/python benchmarks/bench_round.py                  # the kitchen + 3 generated walks, ~3 min
    .venv/bin/python benchmarks/bench_round.py --generated 0    # the kitchen only
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections import defaultdict
from contextlib import contextmanager
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_live import ROOT, add_source_arguments, sources  # noqa: E402

sys.path.insert(0, str(ROOT))

from affordcore.assembly.assembler import Assembler, SensorFrame  # noqa: E402
from affordcore.assembly.depth import DepthImage  # noqa: E402
from affordcore.assembly.sequence import read_sequence  # noqa: E402
from affordcore.geometry.scene import Cloud  # noqa: E402
from affordcore.learn import trees  # noqa: E402
from affordcore.learn.model import load_model, shipped_models  # noqa: E402
from affordcore.mapping import inference, updates  # noqa: E402
from affordcore.mapping.pipeline import RoomMapper, prepare_scene  # noqa: E402
from affordcore.settings import Settings  # noqa: E402

STEPS = ("linear stage", "second stage's features", "trees")


def map_clouds(source, step: int, earlier: float, settings: Settings) -> list[Cloud]:
    """The assembler's map clouds after `earlier` of the frames and after the last, with the sensor positions
    it sends beside them (services/assembler.py)."""
    sequence = read_sequence(source.sequence)
    indices = list(range(0, len(sequence.frames), step))
    keep = {max(1, round(earlier * len(indices))), len(indices)}
    assembler, clouds = Assembler(settings.assembler), []
    for count, index in enumerate(indices, 1):
        image = DepthImage(sequence.depth(index), sequence.intrinsics, 0.001, 65535)
        stamp = 1.0 + index / 30
        frame = SensorFrame(
            "camera", stamp, depth=image, gravity=sequence.gravity(index), pose_guess=sequence.odometry(index)
        )
        assembler.add(frame, stamp)
        if count in keep:
            points, world_from_odom = assembler.aligned_map(settings)
            origins = assembler.sensor_origins(world_from_odom, settings.visibility.max_origins)
            clouds.append(Cloud(points, origins=origins))
    return clouds


class StepClock:
    """CPU seconds spent in the timed functions, by step, while `timing` is on."""

    def __init__(self):
        self.seconds: dict[str, float] = defaultdict(float)
        self.on = False

    def wrap(self, module, name: str, step: str) -> None:
        plain = getattr(module, name)

        def timed(*args, **kwargs):
            if not self.on:
                return plain(*args, **kwargs)
            start = time.process_time()
            try:
                return plain(*args, **kwargs)
            finally:
                self.seconds[step] += time.process_time() - start

        setattr(module, name, timed)

    @contextmanager
    def timing(self):
        self.seconds.clear()
        self.on = True
        try:
            yield self.seconds
        finally:
            self.on = False


def last_round(clouds: list[Cloud], models: list, settings: Settings, clock: StepClock) -> dict:
    """CPU seconds of the second cloud's fields and of each affordance's maps (and its steps), and the share
    of the poses the maps' update rescored."""
    normals, mapper, result = updates.NormalCache(), None, {}
    for last, cloud in zip((False, True), clouds):
        start = time.process_time()
        scene = prepare_scene(cloud, settings, gravity="none", normals=normals)
        fields = time.process_time() - start
        mapper = mapper or RoomMapper(models, scene.layout, settings)
        for model in models:
            with clock.timing() as steps:
                start = time.process_time()
                mapper.maps(scene.fields, models=[model])
                total = time.process_time() - start
            if last:
                result[model.affordance] = {"maps": total, **steps}
        if last:
            result["fields"] = fields
            result["rescored"] = mapper.reports[models[0].affordance].fraction
    return result


def median(runs: list[dict], *keys: str) -> float:
    """The median over runs of the value at `keys` (0 where a step did not run)."""
    values = []
    for run in runs:
        value = run
        for key in keys:
            value = value.get(key, 0.0)
        values.append(value)
    return float(np.median(values))


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    add_source_arguments(parser)
    parser.add_argument(
        "--earlier", type=float, default=0.7, help="the map cloud before the last, share of frames"
    )
    parser.add_argument("--repeats", type=int, default=3, help="rounds per source (medians)")
    args = parser.parse_args()
    settings = Settings()
    models = [load_model(path) for path in shipped_models().values()]
    clock = StepClock()
    # the names as model_scores and updated_scores look them up at each call
    clock.wrap(inference, "score_poses", STEPS[0])
    clock.wrap(inference, "features_at", STEPS[1])
    clock.wrap(trees.TreeEnsemble, "log_odds", STEPS[2])
    print(f"{os.cpu_count()} cores; CPU seconds of the last round, medians of {args.repeats}\n")
    names = [model.affordance for model in models]
    print(
        "| source | points (earlier, last) | fields | "
        + " | ".join(f"{name}: maps (linear / features / trees)" for name in names)
        + " | rescored |"
    )
    print("|---|---:|---:|" + "---:|" * len(names) + "---:|")
    with tempfile.TemporaryDirectory() as folder:
        for source in sources(args, Path(folder)):
            clouds = map_clouds(source, args.step, args.earlier, settings)
            runs = [last_round(clouds, models, settings, clock) for _ in range(args.repeats)]

            cells = []
            for name in names:
                steps = " / ".join(f"{median(runs, name, step):.2f}" for step in STEPS)
                cells.append(f"{median(runs, name, 'maps'):.2f} ({steps})")
            counts = ", ".join(f"{len(cloud.points):,}" for cloud in clouds)
            print(
                f"| {source.name} | {counts} | {median(runs, 'fields'):.2f} | "
                + " | ".join(cells)
                + f" | {100 * median(runs, 'rescored'):.0f} % |",
                flush=True,
            )


if __name__ == "__main__":
    main()
