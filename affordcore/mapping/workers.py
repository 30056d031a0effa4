"""`RoomMapper` on every core: a room's models scored in worker processes, for a service that maps fields
message after fields message.

A `RoomMapper` scores its models one after another, on one core; on the 2-core robot computer the second
core idles meanwhile, and a finished room's three maps come 3 x one map's time after its fields. A
`ForkedRoomMapper` forks its workers when it is made (a service makes it before it opens its session and
starts threads, so a fork copies no lock held by a thread), deals the models out to them, and each worker
keeps a `RoomMapper` of its own: the scores an update starts from stay in the worker that made them. `maps`
sends the fields to every worker whose models are asked for and hands each map on as it comes back, so a
map is published as soon as it is done. The maps are the `RoomMapper`'s (tests/test_workers.py).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable

import numpy as np

from ..geometry.features import FeatureLayout
from ..geometry.fields import SceneFields
from ..settings import Settings
from .pipeline import RoomMapper, preload


def mapping_workers(n_models: int, asked: int = 0) -> int:
    """Worker processes for `n_models` models: `asked` when given (1: none, map in this process), else one
    per model where fork exists (Linux) and there are two cores or more."""
    if asked:
        return max(1, min(asked, n_models))
    if not sys.platform.startswith("linux") or (os.cpu_count() or 1) < 2:
        return 1
    return max(1, min(n_models, 8))


FORGET = "forget"  # what a worker is sent to forget its room (`RoomMapper.forget`)


class ForkedRoomMapper:
    """`RoomMapper`'s `maps`, `describe` and `reports`, with the models scored in `workers` forked processes
    (dealt out in turn: with as many workers as models, one each). `close` ends the workers (they also end
    with this process)."""

    def __init__(
        self, models: list, layout: FeatureLayout, settings: Settings | None = None, workers: int = 2
    ):
        import multiprocessing

        preload()  # once here, not once per worker at its first map
        for model in models:  # what a model makes once, made here for every worker to share
            model.trees, model.places  # noqa: B018
        context = multiprocessing.get_context("fork")
        self.models, self.reports, self.settings = list(models), {}, settings or Settings()
        # `cancel` writes the call to give up here; the workers read it at their checkpoints (shared memory,
        # no lock: one writer, and a stale read only gives up a checkpoint later)
        self.call, self.cancelled_through = 0, context.RawValue("q", -1)
        workers = max(1, min(workers, len(self.models)))
        self.shares = [self.models[k::workers] for k in range(workers)]
        self.connections, self.processes = [], []
        for share in self.shares:
            ours, theirs = context.Pipe()
            # the child keeps no parent's end of a pipe (its own, its elder siblings'): if it did, a parent
            # killed outright would leave the workers waiting for input that never ends, running for ever
            elders = [*self.connections, ours]
            process = context.Process(
                target=_worker,
                args=(theirs, share, layout, self.settings, elders, self.cancelled_through),
                daemon=True,
            )
            process.start()
            theirs.close()
            self.connections.append(ours)
            self.processes.append(process)

    def warm_up(self) -> None:
        """Map a small made-up room once, and forget it: a fresh worker's first map pays for its first
        allocations, which a service would otherwise add to its first robot's first maps."""
        self.maps(_warm_up_fields(self.settings))
        self.forget()

    def describe(self, affordances) -> str:
        return RoomMapper.describe(self, affordances)  # it reads only `reports`, which the workers fill

    def forget(self) -> None:
        """`RoomMapper.forget`, in every worker."""
        self.reports = {}
        for connection in self.connections:
            connection.send(FORGET)

    def cancel(self) -> None:
        """`RoomMapper.cancel`: every worker gives up the call in hand at its next checkpoint."""
        self.cancelled_through.value = self.call

    def maps(
        self,
        fields: SceneFields,
        on_map: Callable[[str, object], None] | None = None,
        models: list | None = None,
    ) -> dict:
        """{affordance: AffordanceMap} of every model (or of `models`, some of them) on the fields now, in the
        models' order; `on_map(affordance, map)` hears of each as it comes back. An error in a worker (or in
        `on_map`) is raised once every worker has answered, so the next call starts clean; so is `Superseded`
        when `cancel` gave the call up."""
        from multiprocessing.connection import wait

        wanted = [m.affordance for m in (self.models if models is None else models)]
        self.call += 1
        busy = []
        for connection, share in zip(self.connections, self.shares):
            asked = [m.affordance for m in share if m.affordance in wanted]
            if asked:
                connection.send((fields, asked, self.call))
                busy.append(connection)
        maps, error = {}, None
        while busy:
            for connection in wait(busy):
                try:
                    answer = connection.recv()
                except EOFError:
                    answer = ("error", RuntimeError("a mapping worker process ended unexpectedly"))
                if answer[0] == "map":
                    _, affordance, amap, report = answer
                    maps[affordance], self.reports[affordance] = amap, report
                    if on_map is not None and error is None:
                        try:
                            on_map(affordance, amap)
                        except Exception as caught:  # raised below, once the workers are drained
                            error = caught
                    continue
                if answer[0] == "error":
                    error = error or answer[1]
                busy.remove(connection)
        if error is not None:
            raise error
        return {affordance: maps[affordance] for affordance in wanted}

    def close(self) -> None:
        for connection in self.connections:
            connection.close()  # a worker reads the end of its input and returns
        for process in self.processes:
            process.join(timeout=5)
            if process.is_alive():
                process.kill()
                process.join()


def _worker(
    connection, models: list, layout: FeatureLayout, settings: Settings, elders: list, cancelled_through
) -> None:
    """A `ForkedRoomMapper` worker: (fields, affordances asked, call) in, ("map", affordance, map, report) out
    for each, then ("done",); ("error", exception) instead when one fails, ("error", Superseded) when the
    parent gave the call up (`cancelled_through`, shared). `elders`: the parent's ends of this worker's pipe
    and of those forked before it, closed here so that only the parent holds them."""
    for elder in elders:
        elder.close()
    mapper = RoomMapper(models, layout, settings)
    by_name = {model.affordance: model for model in models}
    call = 0
    mapper.superseded = lambda: cancelled_through.value >= call
    while True:
        try:
            asked_for = connection.recv()
        except EOFError:
            return
        if asked_for == FORGET:
            mapper.forget()
            continue
        fields, asked, call = asked_for
        try:
            for affordance in asked:
                amap = mapper.maps(fields, models=[by_name[affordance]])[affordance]
                connection.send(("map", affordance, amap, mapper.reports[affordance]))
            connection.send(("done",))
        except Exception as error:
            try:
                connection.send(("error", error))
            except Exception:  # an exception that does not pickle: its text
                connection.send(("error", RuntimeError(f"mapping in a worker process: {error!r}")))


def _warm_up_fields(settings: Settings) -> SceneFields:
    """The fields of a 2.5 m square of floor with a seat-high and a table-high box on it."""
    from ..example import box_surface_points
    from ..geometry.scene import Cloud
    from .pipeline import prepare_scene

    rng = np.random.default_rng(0)
    boxes = [
        ((0.0, 0.0, 0.0), (2.5, 2.5, 0.0)),
        ((0.4, 0.4, 0.0), (0.9, 0.9, 0.45)),
        ((1.4, 1.4, 0.0), (2.2, 2.2, 0.75)),
    ]
    points = np.vstack([box_surface_points(np.array(low), np.array(high), 2500, rng) for low, high in boxes])
    return prepare_scene(Cloud(points, source="warm-up"), settings, gravity="none").fields
