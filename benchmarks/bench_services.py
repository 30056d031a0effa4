"""Latency of the services: from the last scan published to the map, the fields and every affordance map built
from all the scans, with the router and the three services as separate processes on this machine.

    .venv/bin/python benchmarks/bench_services.py [--frames 100] [--step 3] [--rate 30] [--repeats 3]
        [--hogs 2]
    .venv/bin/python benchmarks/bench_services.py --as-map [--repeats 5] [--hogs 2]

Streams the real 7-Scenes kitchen frames (../shared) when present, else a generated living room's. Each
repeat starts a fresh stack. Prints per-stage latency medians and the assembler's own frame rate.

With ``--as-map``: a finished room, the built-in 6 m x 5 m example room as `afford publish --as-map` sends it
(levelled by the client), put on map/cloud of a fresh stack, timed from the put to the fields and to each
affordance map (first maps: every map of that cloud). Then where the time goes: the services' steps one by
one in this process (decoding, the levelling check, the fields, encoding; per affordance the scoring and
map and its message; the recordings' logging), medians over the repeats; and the three maps of the same
fields made in turn, on threads and in forked workers (the service's way), side by side.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from affordcore.assembly.sequence import read_sequence  # noqa: E402
from affordcore.learn.model import shipped_models  # noqa: E402
from affordwire import messages  # noqa: E402
from services.clients import publish_sequence, sequence_messages  # noqa: E402
from services.launch import Stack, cpu_hogs, query_status  # noqa: E402
from services.transport import Keys, open_session, schema_of  # noqa: E402

KITCHEN = ROOT.parent / "shared" / "data" / "sequences" / "7scenes_redkitchen_frames_000000-000299"


def generated_sequence(folder: Path, frames: int) -> Path:
    import numpy as np

    from affordcore.synth.dataset import write_sequence
    from affordcore.synth.rooms import generate_room

    rng = np.random.default_rng(3)
    write_sequence(generate_room("living", rng, "bench"), rng, folder, "depth", frames)
    return folder


class Arrivals:
    """When the first output built from every accepted scan arrived on each key. The assembler may pass
    over frames it cannot keep up with (AFFORD_SERVICE__MAX_LAG), so "every accepted scan" is the number of
    poses it published, known once the stream has ended."""

    def __init__(self, affordances: list[str]):
        self.wanted = {f"affordance/{name}" for name in affordances} | {"map/cloud", "fields"}
        self.poses = 0
        self.first: dict[tuple[str, int], float] = {}  # (key, frames) -> first arrival
        self.lock = threading.Lock()

    def on_sample(self, sample) -> None:
        now = time.monotonic()
        key = str(sample.key_expr).split("/", 3)[3]
        if key == "map/pose":
            with self.lock:
                self.poses += 1
            return
        classes = {"map/cloud": messages.CloudMessage, "fields": messages.SceneFieldsMessage}
        cls = classes.get(key, messages.AffordanceMapMessage if key.startswith("affordance/") else None)
        if cls is None or schema_of(sample) != messages.schema_name(cls):
            return
        frames = messages.parse(cls, sample.payload.to_bytes()).frames
        with self.lock:
            self.first.setdefault((key, frames), now)

    def wait(self, timeout: float) -> dict[str, float] | None:
        """{key: first arrival of its output from every accepted scan}, or None after `timeout` s."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self.lock:
                done = {key: self.first.get((key, self.poses)) for key in self.wanted}
            if all(done.values()):
                return done
            time.sleep(0.05)
        return None


def one_run(folder: Path, indices: list[int], rate: float, workdir: Path) -> dict[str, float]:
    sequence = read_sequence(folder)
    affordances = list(shipped_models())
    arrivals = Arrivals(affordances)
    with Stack(workdir) as stack:
        keys = Keys(stack.robot)
        session = open_session([stack.endpoint])
        subscriber = session.declare_subscriber(keys.key("**"), arrivals.on_sample)
        try:
            start = time.monotonic()
            publish_sequence(session, keys, sequence_messages(sequence, indices), "camera", rate, wait=30)
            last_scan = time.monotonic()
            arrived = arrivals.wait(600)
            if arrived is None:
                raise RuntimeError(
                    f"outputs of all {arrivals.poses} accepted scans missing after 600 s\n{stack.logs()}"
                )
        finally:
            subscriber.undeclare()
            session.close()
    result = {key: at - last_scan for key, at in arrived.items()}
    result["publishing (s)"] = last_scan - start
    result["frames taken (of those published)"] = arrivals.poses
    result["every map"] = max(v for k, v in result.items() if k.startswith("affordance/"))
    result["every map, after the last map/cloud"] = result["every map"] - result["map/cloud"]
    # where that goes, service by service (arrivals on the router, so each includes its messages)
    result["features: the last map/cloud to its fields"] = result["fields"] - result["map/cloud"]
    result["inference: those fields to every map"] = result["every map"] - result["fields"]
    return result


def example_room_message():
    """The built-in example room as `afford publish --as-map` sends it: levelled here, world frame."""
    from affordcore.example import example_room
    from affordcore.mapping.pipeline import to_world
    from affordcore.settings import Settings

    world = to_world(example_room(), Settings(), "auto")
    return messages.cloud_message(
        world.cloud.points.astype("float32"), world.alignment.world_from_input, source="example room"
    )


def as_map_run(workdir: Path) -> dict[str, float]:
    """A fresh stack, one finished room put on map/cloud: seconds from the put to the fields and each map."""
    from services.clients import _publisher

    cloud = example_room_message()
    stamp = messages.nanoseconds(cloud.timestamp)
    arrived: dict[str, float] = {}
    lock = threading.Lock()

    def on_sample(sample) -> None:
        now = time.monotonic()
        key = str(sample.key_expr).split("/", 3)[3]
        classes = {"fields": messages.SceneFieldsMessage}
        cls = classes.get(key, messages.AffordanceMapMessage if key.startswith("affordance/") else None)
        if cls is None or schema_of(sample) != messages.schema_name(cls):
            return
        if messages.nanoseconds(messages.parse(cls, sample.payload.to_bytes()).cloud_timestamp) == stamp:
            with lock:
                arrived.setdefault(key, now)

    wanted = {"fields"} | {f"affordance/{name}" for name in shipped_models()}
    with Stack(workdir) as stack:
        keys = Keys(stack.robot)
        session = open_session([stack.endpoint])
        subscriber = session.declare_subscriber(keys.key("**"), on_sample)
        try:
            publisher = _publisher(session, keys.cloud, messages.CloudMessage, 30)  # the service listens
            payload = cloud.SerializeToString()
            start = time.monotonic()
            publisher.put(payload)
            deadline = start + 120
            while time.monotonic() < deadline and not wanted <= set(arrived):
                time.sleep(0.01)
            if not wanted <= set(arrived):
                raise RuntimeError(f"missing after 120 s: {sorted(wanted - set(arrived))}\n{stack.logs()}")
            publisher.undeclare()
            # each service's own time on its input (Status.last_seconds): the rest is transport and queues
            handled = {}
            for _ in range(50):  # set once the handler returns, just after its last map went out
                statuses = query_status(session, keys.robot)
                handled = {name: status.last_seconds for name, status in statuses.items()}
                if handled.get("features") and handled.get("inference"):
                    break
                time.sleep(0.1)
        finally:
            subscriber.undeclare()
            session.close()
    result = {f"{key} (s)": at - start for key, at in sorted(arrived.items(), key=lambda item: item[1])}
    result["first maps: every map (s)"] = every = max(arrived.values()) - start
    result["features: its work on the cloud (s)"] = handled["features"]
    result["inference: its work on the fields, every map (s)"] = handled["inference"]
    result["the rest: messages between processes, queues (s)"] = (
        every - handled["features"] - handled["inference"]
    )
    return result


def as_map_steps(repeats: int) -> dict[str, list[float]]:
    """The services' steps for that room, one by one in this process (as each service runs them), seconds."""
    from affordcore.geometry.features import FeatureLayout
    from affordcore.geometry.gravity import check_levelled
    from affordcore.geometry.scene import Cloud
    from affordcore.learn.model import load_model
    from affordcore.mapping.pipeline import RoomMapper, prepare_scene
    from affordcore.mapping.recording import close_recording, log_fields, log_map, open_recording
    from affordcore.mapping.updates import NormalCache
    from affordcore.settings import Settings

    settings = Settings()
    models = [load_model(path) for path in shipped_models().values()]
    payload = example_room_message().SerializeToString()
    steps: dict[str, list[float]] = {}

    def timed(name: str, work, *args, **kwargs):
        start = time.perf_counter()
        value = work(*args, **kwargs)
        steps.setdefault(name, []).append(time.perf_counter() - start)
        return value

    with tempfile.TemporaryDirectory() as tmp:
        for repeat in range(repeats):
            recording = open_recording(Path(tmp) / f"r{repeat}.rrd", [m.affordance for m in models])
            cloud = timed("features: parse the cloud", messages.parse, messages.CloudMessage, payload)
            points = timed("features: unpack and check the points", messages.cloud_points, cloud)
            timed("features: check the levelling", check_levelled, points, settings.gravity)
            scene = timed(
                "features: fields (occupancy, distance, normals)",
                prepare_scene,
                Cloud(points, source="bench"),
                settings,
                "none",
                normals=NormalCache(),
            )
            fields_payload = timed(
                "features: encode the fields",
                lambda scene=scene, cloud=cloud: messages.fields_message(
                    scene.fields, cloud
                ).SerializeToString(),
            )
            timed(
                "features: log the fields (recording, after publishing)", log_fields, recording, scene.fields
            )
            message = timed(
                "inference: parse the fields", messages.parse, messages.SceneFieldsMessage, fields_payload
            )
            fields = timed("inference: check the fields", messages.scene_fields, message, settings.limits)
            mapper = RoomMapper(models, FeatureLayout.from_settings(settings), settings)
            for model in models:
                amap = timed(f"inference: score + map {model.affordance}", mapper.maps, fields, None, [model])
                amap = amap[model.affordance]
                timed(
                    f"inference: encode {model.affordance}",
                    lambda amap=amap, model=model, message=message: messages.map_message(
                        amap, model.id, message
                    ).SerializeToString(),
                )
                timed(f"inference: log {model.affordance} (recording)", log_map, recording, amap)
            close_recording(recording)
    return steps


def worker_rounds(repeats: int) -> dict[str, list[float]]:
    """Every map of the example room's fields, as the inference service could make them: one model after
    another in one process, the models on threads of one process, and in forked workers (the service's
    way), each from scratch, rounds alternating."""
    from concurrent.futures import ThreadPoolExecutor

    from threadpoolctl import threadpool_limits

    from affordcore.example import example_room
    from affordcore.geometry.features import FeatureLayout
    from affordcore.learn.model import load_model
    from affordcore.mapping.pipeline import RoomMapper, preload, prepare_scene
    from affordcore.mapping.workers import ForkedRoomMapper
    from affordcore.settings import Settings

    settings = Settings()
    models = [load_model(path) for path in shipped_models().values()]
    layout = FeatureLayout.from_settings(settings)
    fields = prepare_scene(example_room(), settings, "auto").fields
    with threadpool_limits(1, user_api="blas"):  # as the services run (AFFORD_SERVICE__BLAS_THREADS)
        forked = ForkedRoomMapper(models, layout, settings)
        forked.warm_up()
        preload()
        alone = [RoomMapper([model], layout, settings) for model in models]

        def afresh(mapper) -> None:
            mapper.maps(fields)
            mapper.forget()

        ways = {
            "in turn, one process": lambda: [afresh(mapper) for mapper in alone],
            "on threads, one per model": lambda: list(threads.map(afresh, alone)),
            "in forked workers, one per model": lambda: afresh(forked),
        }
        rounds: dict[str, list[float]] = {name: [] for name in ways}
        with ThreadPoolExecutor(len(models)) as threads:
            for mapper in alone:
                afresh(mapper)  # the first maps of this process, not timed
            for _ in range(repeats):
                for name, way in ways.items():
                    start = time.perf_counter()
                    way()
                    rounds[name].append(time.perf_counter() - start)
        forked.close()
    return rounds


def as_map_table(args) -> None:
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp, cpu_hogs(args.hogs):
        runs = [as_map_run(Path(tmp) / f"run{k}") for k in range(args.repeats)]
    print(
        f"\n`publish --as-map` of the 6 m x 5 m example room (levelled by the client), three shipped models: "
        f"from the put on map/cloud to each output; {args.repeats} fresh stacks, {os.cpu_count()} cores, "
        f"{args.hogs} CPU hogs, load average {load:.1f} before, {os.getloadavg()[0]:.1f} after\n"
    )
    print("| from the room put on map/cloud to ... | median (s) | runs (s) |\n|---|---:|---|")
    for key in runs[0]:
        values = [run[key] for run in runs]
        print(f"| {key} | {statistics.median(values):.2f} | {', '.join(f'{v:.2f}' for v in values)} |")
    steps = as_map_steps(args.repeats)
    print(f"\nwhere the time goes: the services' steps in one process, medians of {args.repeats}\n")
    print("| step | median (s) |\n|---|---:|")
    for name, values in steps.items():
        print(f"| {name} | {statistics.median(values):.3f} |")
    rounds = worker_rounds(max(args.repeats, 5))
    print("\nthe three maps of those fields, every pose scored, in this process's forks and threads\n")
    print("| scored | median (s) | runs (s) |\n|---|---:|---|")
    for name, values in rounds.items():
        print(f"| {name} | {statistics.median(values):.3f} | {', '.join(f'{v:.2f}' for v in values)} |")


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--step", type=int, default=3)
    parser.add_argument("--rate", type=float, default=30.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--as-map", action="store_true", help="a finished room's first maps instead")
    parser.add_argument("--hogs", type=int, default=0, help="CPU hogs beside the stack")
    args = parser.parse_args()
    if args.as_map:
        as_map_table(args)
        return
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        folder = (
            KITCHEN if KITCHEN.is_dir() else generated_sequence(Path(tmp) / "seq", args.frames * args.step)
        )
        indices = list(range(0, len(read_sequence(folder).frames), args.step))[: args.frames]
        with cpu_hogs(args.hogs):
            runs = [one_run(folder, indices, args.rate, Path(tmp) / f"run{k}") for k in range(args.repeats)]
    source = "7-Scenes redkitchen (real)" if folder == KITCHEN else "generated living room"
    print(
        f"\n{source}: {len(indices)} frames (every {args.step} of the sequence) at {args.rate:g} Hz, "
        f"{args.repeats} runs, {os.cpu_count()} cores, {args.hogs} CPU hogs, load average {load:.1f} "
        f"before, {os.getloadavg()[0]:.1f} after; services as processes on one machine\n"
    )
    print("| from the last scan published to ... | median (s) | runs (s) |\n|---|---:|---|")
    for key in runs[0]:
        values = [run[key] for run in runs]
        print(f"| {key} | {statistics.median(values):.2f} | {', '.join(f'{v:.2f}' for v in values)} |")


if __name__ == "__main__":
    main()
