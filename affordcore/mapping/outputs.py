"""What `afford map` hands to people and robots: per affordance a JSON map and a plan-view PNG, and one Rerun
recording of the room with every map.

`map_and_write` is the command's last stage. With workers (Linux, 2 cores or more) each model's scores and map
come from a worker process of their own (forked once the fields exist, so nothing is copied to them), and an
`OutputWriter`, a process forked when the command starts, writes the recording, the JSONs and the PNGs: it
imports matplotlib and rerun (1-1.3 s of CPU) while this process loads and levels the room, logs the cloud
while the fields are computed, and has each map drawn as it comes, by a process forked from it (maps that
come together are drawn side by side). On 2 cores that keeps the imports, three plans and a recording off
the path from the cloud to the maps (benchmarks/bench_map.py, docs/maps.md).
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from pathlib import Path

from ..learn.model import AffordanceModel

_JOB: tuple | None = None  # (scene, models, settings): what forked workers read, never pickled


def write_map_outputs(
    scene,
    maps: dict,
    models: list[AffordanceModel],
    out: Path,
    rrd: Path | None,
    labels=None,
    png: bool = True,
) -> list[Path]:
    """DIR/<affordance>.json and (with `png`) .png for every map of a `PreparedScene`, and the recording
    (unless `rrd` is None); returns the paths. `labels` (a `LabelSet` in the world frame): drawn on the
    PNGs."""
    out.mkdir(parents=True, exist_ok=True)
    ids = {model.affordance: model.id for model in models}
    plan = _plan(scene.cloud.points, png)
    written = []
    for affordance, amap in maps.items():
        written += _json_and_png(
            scene.cloud.points, scene.alignment.world_from_input, amap, ids[affordance], out, plan, labels
        )
    if rrd is not None:
        recording = _open_with_cloud(rrd, list(maps), scene.cloud.points, scene.cloud.source, labels)
        _close_with_maps(recording, maps.values())
        written.append(rrd)
    return written


def map_and_write(
    scene,
    models: list[AffordanceModel],
    settings,
    out: Path,
    rrd: Path | None,
    workers: int | None = None,
    on_map: Callable[[str, object], None] | None = None,
    timings: dict[str, float] | None = None,
    writer: OutputWriter | None = None,
    labels=None,
    png: bool = True,
) -> tuple[dict, list[Path]]:
    """Every model's map of a `PreparedScene` (`pipeline.map_affordances`, one model at a time) and the
    outputs of `write_map_outputs`; returns ({affordance: map} in the models' order, the paths written).

    With ``workers`` > 1 (default: one per model when the machine has two cores or more, on Linux) each
    model is scored and mapped in a forked worker process, and the outputs are written by ``writer`` (an
    `OutputWriter` started early; one is started here when not given) meanwhile; ``on_map(affordance,
    map)`` hears of each map as it comes back. ``timings`` gets each stage's seconds: per affordance its
    scoring and map (in its worker) and its JSON and PNG (in the writer), and the recording's. `labels` (a
    `LabelSet` in the world frame) are drawn on the PNGs; `png` False: JSON only (and the recording unless
    `rrd` is None), and matplotlib is never imported."""
    global _JOB

    from .workers import mapping_workers

    out.mkdir(parents=True, exist_ok=True)
    timings = {} if timings is None else timings
    workers = mapping_workers(len(models), workers or 0)
    if workers == 1:
        return _map_and_write_here(scene, models, settings, out, rrd, on_map, timings, labels, png)
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    from .pipeline import preload

    preload()  # the scoring modules imported once here, not once in every worker
    own_writer = writer is None
    writer = writer or OutputWriter(png, rrd is not None)
    _JOB = (scene, models, settings)
    maps: dict[int, object] = {}
    try:
        with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork")) as pool:
            futures = {pool.submit(_map_one, index): index for index in range(len(models))}
            if not writer.has_scene:
                writer.start_scene(scene, [m.affordance for m in models], out, rrd)
            if labels is not None:
                writer.set_labels(labels)
            for future in as_completed(futures):
                index = futures[future]
                amap, seconds = future.result()
                maps[index] = amap
                timings[f"score + map {amap.affordance}"] = seconds
                writer.write_map(amap, models[index].id)
                if on_map:
                    on_map(amap.affordance, amap)
        ordered = [maps[index] for index in range(len(models))]
        written, seconds = writer.finish([amap.affordance for amap in ordered])
        timings.update(seconds)
    finally:
        _JOB = None
        if own_writer:
            writer.close()
    return {amap.affordance: amap for amap in ordered}, written


def _map_and_write_here(
    scene, models, settings, out, rrd, on_map, timings, labels=None, png: bool = True
) -> tuple[dict, list[Path]]:
    """`map_and_write` in this process alone, model after model."""
    from .pipeline import map_affordances

    plan = _plan(scene.cloud.points, png)
    maps, written = {}, []
    for model in models:
        start = time.perf_counter()
        amap = map_affordances(scene.fields, scene.layout, [model], settings)[model.affordance]
        mapped = time.perf_counter()
        written += _json_and_png(
            scene.cloud.points, scene.alignment.world_from_input, amap, model.id, out, plan, labels
        )
        timings[f"score + map {model.affordance}"] = mapped - start
        timings[f"JSON + PNG {model.affordance}"] = time.perf_counter() - mapped
        maps[model.affordance] = amap
        if on_map:
            on_map(model.affordance, amap)
    if rrd is not None:
        start = time.perf_counter()
        recording = _open_with_cloud(rrd, list(maps), scene.cloud.points, scene.cloud.source, labels)
        _close_with_maps(recording, maps.values())
        timings["recording"] = time.perf_counter() - start
        written.append(rrd)
    return maps, written


def _map_one(index: int) -> tuple:
    """In a worker: model `index`'s map; (map, seconds)."""
    from .pipeline import map_affordances

    scene, models, settings = _JOB
    model = models[index]
    start = time.perf_counter()
    amap = map_affordances(scene.fields, scene.layout, [model], settings)[model.affordance]
    return amap, time.perf_counter() - start


def _plan(points, png: bool):
    """The room from above for the PNGs (`plots.plan_heights`), or None when none is drawn."""
    from .plots import plan_heights

    return plan_heights(points) if png else None


def _json_and_png(points, world_from_input, amap, model_id: str, out: Path, plan, labels=None) -> list[Path]:
    """The map's JSON, and its PNG unless `plan` is None (no PNGs asked for)."""
    document = amap.to_json(model_id, world_from_input)
    path = out / f"{amap.affordance}.json"
    path.write_text(json.dumps(document) + "\n")
    if plan is None:
        return [path]
    from .plots import plot_map

    return [path, plot_map(points, amap, out / f"{amap.affordance}.png", labels=labels, plan=plan)]


def _open_with_cloud(rrd: Path, affordances: list[str], points, source: str, labels=None):
    """The recording, named after the cloud's file and the time, with the cloud (and `labels`) in it."""
    from .recording import log_cloud, log_labels, open_recording, recording_name

    recording = open_recording(rrd, affordances, name=recording_name(f"{Path(source).stem} map"))
    log_cloud(recording, points)
    if labels is not None:
        log_labels(recording, labels, affordances)
    return recording


def _close_with_maps(recording, maps) -> None:
    from .recording import close_recording, log_map

    for amap in maps:
        log_map(recording, amap)
    close_recording(recording)


def summary_line(amap) -> str:
    """One line per map for people: places, poses above the threshold, the best score, and the places a lower
    place probability would add (how to ask for them)."""
    count = len(amap.skeletons)
    best = f", best {amap.place_labels()[0]}" if count else ""
    unsure = f"; {amap.unsure_note()}" if amap.unsure_places else ""
    return (
        f"{amap.affordance:<18} {count:>3} {'place, ' if count == 1 else 'places,'} "
        f"{len(amap.positives):>7,} poses above the threshold{best}{unsure}"
    )


class OutputWriter:
    """A forked process that writes `map_and_write`'s outputs: started before the room is loaded, it imports
    matplotlib and rerun meanwhile; then it gets the room (`start_scene`: it logs the cloud to the
    recording), each map (`write_map`: its JSON and PNG, written by a `_Drawer`) and the order of the maps
    (`finish`: they go into the recording, which is closed; returns the paths written and each stage's
    seconds). An error in it is raised here, at `finish`. A context manager; `close` ends it if it is still
    running."""

    def __init__(self, png: bool = True, recording: bool = True):
        """`png`, `recording`: whether it will draw PNGs and write a recording (it imports matplotlib and
        rerun only for them)."""
        import multiprocessing

        context = multiprocessing.get_context("fork")
        self._connection, theirs = context.Pipe()
        self._process = context.Process(target=_writer_main, args=(theirs, png, recording), daemon=True)
        self._process.start()
        theirs.close()
        self.has_scene, self._sending, self._send_error = False, None, None
        self._finished = False  # `finish` answered: what it wrote is all there is

    def __enter__(self) -> OutputWriter:
        return self

    def __exit__(self, *_) -> None:
        self.close()

    def start_scene(self, world, affordances: list[str], out: Path, rrd: Path | None) -> None:
        """The room (a `pipeline.WorldCloud` or `PreparedScene`): the writer records its cloud. As soon as the
        world cloud exists (`prepare_scene`'s `on_world`), the recording is made while the fields are.

        Sent by a thread: the pipe holds 64 KB of the cloud's 11 MB and the writer reads only once its
        imports are done, so a plain send would hold this process, and the fields it computes next, until
        then (on a busy machine, seconds)."""
        import threading

        points, source = world.cloud.points, world.cloud.source
        message = ("scene", points, source, world.alignment.world_from_input, affordances, out, rrd)
        self._sending = threading.Thread(target=self._send, args=(message,), daemon=True)
        self._sending.start()
        self.has_scene = True

    def _send(self, message) -> None:
        try:
            self._connection.send(message)
        except Exception as error:  # raised by _sent, in the caller's thread
            self._send_error = error

    def _sent(self) -> None:
        """Wait for the scene to be sent (messages keep their order); raise what went wrong sending it."""
        if self._sending is not None:
            self._sending.join()
            self._sending = None
        if self._send_error is not None:
            raise self._send_error

    def set_labels(self, labels) -> None:
        """Labels (a `LabelSet` in the world frame) to draw on the PNGs of the maps sent after them."""
        self._sent()
        self._connection.send(("labels", labels))

    def write_map(self, amap, model_id: str) -> None:
        from dataclasses import replace

        self._sent()
        # without its every pose's scores (8-13 MB through the pipe), which no output reads
        self._connection.send(("map", replace(amap, scores=None), model_id))

    def finish(self, order: list[str]) -> tuple[list[Path], dict[str, float]]:
        self._sent()
        self._connection.send(("finish", order))
        try:
            outcome, value = self._connection.recv()
        except EOFError:
            raise RuntimeError("the process writing the map outputs ended without a word") from None
        self._finished = True
        if outcome == "error":
            raise value
        return value

    def close(self) -> None:
        """End the writer. Closed before `finish` (the command failed: a bad cloud, a map that raised),
        nothing it would still write is wanted, so it is killed at once rather than left to finish its
        imports first: waiting for them delayed a bad input's one-line error by seconds (docs/maps.md)."""
        if not self._finished:
            self._process.kill()  # a scene still being sent fails, and its thread ends
            if self._sending is not None:
                self._sending.join()
        self._connection.close()  # the writer reads the end of its input and stops
        self._process.join(timeout=5)
        if self._process.is_alive():
            self._process.kill()
            self._process.join()


def _writer_main(connection, png: bool = True, recording: bool = True) -> None:
    """The `OutputWriter` process: import what drawing and recording need (only what is asked for), then
    serve the requests; after an error, only `finish` is answered (with the error)."""
    start = time.perf_counter()
    if png:
        from .plots import pyplot

        pyplot()
    if recording:  # now, while the command loads and levels the room, not once the maps are scored
        from .recording import import_rerun

        import_rerun()
    state = {"seconds": {"writer: importing matplotlib and rerun": time.perf_counter() - start}, "png": png}
    error = None
    while True:
        try:
            request = connection.recv()
        except EOFError:  # the command ended (or failed) before finishing: nothing more to write
            return
        if request[0] == "finish":
            break
        if error is None:
            try:
                _serve(state, request)
            except Exception as caught:  # raised again in the command's process, at finish
                error = caught
    if error is None:
        try:
            connection.send(("done", _finished(state, request[1])))
            return
        except Exception as caught:
            error = caught
    try:
        connection.send(("error", error))
    except Exception:  # an error that cannot be pickled: its text
        connection.send(("error", RuntimeError(f"writing the map outputs: {error!r}")))


def _serve(state: dict, request: tuple) -> None:
    """One `OutputWriter` request: the room (the recording opened, the cloud logged) or a map (JSON, PNG)."""
    start, seconds = time.perf_counter(), state["seconds"]
    if request[0] == "scene":
        _, points, source, world_from_input, affordances, out, rrd = request
        state.update(
            points=points,
            world_from_input=world_from_input,
            out=out,
            rrd=rrd,
            affordances=affordances,
            maps={},
            drawers={},
        )
        state["recording"] = _open_with_cloud(rrd, affordances, points, source) if rrd is not None else None
        state["plan"] = _plan(points, state["png"])
        seconds["recording: the cloud"] = time.perf_counter() - start
    elif request[0] == "labels":
        from .recording import log_labels

        state["labels"] = request[1]
        if state["recording"] is not None:
            log_labels(state["recording"], state["labels"], state["affordances"])
    else:
        _, amap, model_id = request
        state["maps"][amap.affordance] = amap
        state["drawers"][amap.affordance] = _Drawer(state, amap, model_id)


class _Drawer:
    """One map's JSON and PNG, written by a process forked from the writer (matplotlib is loaded there): maps
    that come back together (the workers score side by side) are drawn side by side too, instead of one
    after the other once the scoring is over. The child leaves by os._exit: nothing of the writer's (its
    recording's sinks, its pipe to the command) is flushed or closed twice."""

    def __init__(self, state: dict, amap, model_id: str):
        import pickle

        read, write = os.pipe()
        self.pid = os.fork()
        if self.pid == 0:  # the child: whatever happens, it never returns into the writer's loop
            try:
                os.close(read)
                with os.fdopen(write, "wb") as pipe:
                    pickle.dump(_draw(state, amap, model_id), pipe)
            finally:
                os._exit(0)
        os.close(write)
        self.answer = os.fdopen(read, "rb")

    def result(self) -> tuple[list[Path], float]:
        """(the paths written, seconds), once the child is done; its error raised here."""
        import pickle

        try:
            outcome, value = pickle.load(self.answer)
        except EOFError:
            raise RuntimeError("the process drawing a map ended without a word") from None
        finally:
            self.answer.close()
            os.waitpid(self.pid, 0)
        if outcome == "error":
            raise value
        return value


def _draw(state: dict, amap, model_id: str) -> tuple[str, object]:
    """In a `_Drawer`'s child: ("done", (the paths written, seconds)) or ("error", what went wrong)."""
    start = time.perf_counter()
    try:
        paths = _json_and_png(
            state["points"],
            state["world_from_input"],
            amap,
            model_id,
            state["out"],
            state["plan"],
            state.get("labels"),
        )
        return "done", (paths, time.perf_counter() - start)
    except BaseException as error:  # raised in the command's process, at finish
        return "error", RuntimeError(f"writing the {amap.affordance} map: {error!r}")


def _finished(state: dict, order: list[str]) -> tuple[list[Path], dict[str, float]]:
    """The maps logged in `order` and the recording closed: (the paths written, each stage's seconds)."""
    paths = []
    for affordance in order:
        written, seconds = state["drawers"][affordance].result()
        state["seconds"][f"JSON + PNG {affordance}"] = seconds
        paths += written
    if state["recording"] is not None:
        start = time.perf_counter()
        _close_with_maps(state["recording"], [state["maps"][affordance] for affordance in order])
        state["seconds"]["recording: the maps"] = time.perf_counter() - start
        paths.append(state["rrd"])
    return paths, state["seconds"]
