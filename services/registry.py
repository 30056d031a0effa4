"""The services, registered once: the command line (`afford serve`), the launcher, the docker files' test and
the docs read this table. A new service is a module with a class built from a `Node`, and one line here."""

from __future__ import annotations

import importlib
import os
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class ServiceSpec:
    name: str
    summary: str  # what it takes and gives, for --help and the docs
    target: str  # "module:Class"; the class takes a Node
    downstream: bool  # runs AFFORD_SERVICE__DOWNSTREAM_NICE nicer, so scan assembly keeps up with the sensor
    scores: bool = False  # scores with the robot's models, so they must match the feature settings
    shards: bool = False  # may run as one of several workers sharing many robots (services/shard.py)

    def service_class(self) -> type:
        module, name = self.target.split(":")
        return getattr(importlib.import_module(module), name)


SERVICES: dict[str, ServiceSpec] = {
    spec.name: spec
    for spec in (
        ServiceSpec(
            "assembler", "scans to a map (KISS-ICP)", "services.assembler:AssemblerService", downstream=False
        ),
        ServiceSpec("features", "map to voxel fields", "services.features:FeaturesService", downstream=True),
        ServiceSpec(
            "inference",
            "fields to affordance maps",
            "services.inference:InferenceService",
            downstream=True,
            scores=True,
            shards=True,
        ),
    )
}


def run_service(
    name: str,
    robot: str,
    endpoints: list[str],
    rrd: Path | None = None,
    viewer: str | None = None,
    listen: list[str] | None = None,
    model_files: list[Path] | None = None,
    state: Path | None = None,
    zenoh_config: Path | None = None,
    robots: list[str] | None = None,
    worker: str | None = None,
    shard_by: str = "affordance",
) -> None:
    """Run one registered service until SIGINT/SIGTERM, with the settings from the environment (`state` and
    `zenoh_config` over theirs); a service that scores uses the given models (default: the shipped
    ones). With `robots` (names or patterns such as `*`; `robot` unused), a service that shards runs as
    worker `worker` (default <host>-<pid>) of the group of workers configured alike, each owning a share of
    the units (`shard_by`: affordance or robot) and taking over the share of a worker that leaves."""
    spec = SERVICES.get(name)
    if spec is None:
        raise ValueError(f"unknown service {name!r}; choose one of {', '.join(SERVICES)}")
    if robots and not spec.shards:
        raise ValueError(f"{name} serves one robot (--robot); only {', '.join(_sharding())} shard")
    from affordcore.geometry.features import FeatureLayout
    from affordcore.learn.model import choose_models, shipped_models

    from .node import Node
    from .settings import ServiceSettings

    settings = ServiceSettings()
    settings.service.state = state or settings.service.state
    settings.service.zenoh_config = zenoh_config or settings.service.zenoh_config
    if spec.downstream:
        os.nice(settings.service.downstream_nice)
    limit_blas(settings)  # for the process's life, its mapping workers (forked below) too
    models = []
    if spec.scores:  # only a scoring service loads models, and refuses those of another feature layout
        models = choose_models(model_files or [], [], FeatureLayout.from_settings(settings))
    affordances = [model.affordance for model in models] or list(shipped_models())  # the recording's tabs
    keys = None
    if robots:
        from .shard import Selection, WorkerKeys, default_worker_id, group_of

        selection = Selection(tuple(robots))
        group = group_of(name, selection, shard_by, [model.id for model in models])
        keys = WorkerKeys(selection, group, worker or default_worker_id(), shard_by)
        name, robot = f"{name}-{keys.worker}", keys.robot  # its Status.service and error key: one per worker
    mapper = None
    if spec.scores and not robots:  # forked before the node opens its session and starts threads
        from affordcore.mapping.workers import ForkedRoomMapper, mapping_workers

        workers = mapping_workers(len(models), settings.service.map_workers)
        if workers > 1:
            mapper = ForkedRoomMapper(models, FeatureLayout.from_settings(settings), settings, workers)
            mapper.warm_up()
    node = Node(name, robot, endpoints, settings, rrd, viewer, affordances, listen, models, keys=keys)
    node.mapper = mapper
    spec.service_class()(node).run()


def limit_blas(settings):
    """BLAS threads at AFFORD_SERVICE__BLAS_THREADS (0: left alone); the limits, to restore them, or None."""
    if not settings.service.blas_threads:
        return None
    from threadpoolctl import threadpool_limits

    return threadpool_limits(settings.service.blas_threads, user_api="blas")


def _sharding() -> list[str]:
    return [spec.name for spec in SERVICES.values() if spec.shards]
