"""The walk of a cloud: any cloud -> the world frame (`to_world`: thinned when huge, gravity-aligned) -> its
voxel fields (`prepare_scene`) -> every model's scores and maps (`map_affordances`). `afford map`,
`afford publish --as-map`, the assembler and the features service all take this one path."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..geometry.features import FeatureLayout
from ..geometry.fields import SceneFields, compute_fields
from ..geometry.gravity import Alignment, align_to_gravity
from ..geometry.grid import PoseGrid
from ..geometry.scene import Cloud, thin_huge_cloud
from ..geometry.skeleton import Skeleton
from ..settings import Settings


@dataclass
class WorldCloud:
    cloud: Cloud  # in the world frame: z up, floor at z = 0
    alignment: Alignment  # how it got there (world_from_input and the evidence)
    warnings: list[str]  # what was done to it that a person should hear of (thinning)


@dataclass
class PreparedScene(WorldCloud):
    fields: SceneFields
    layout: FeatureLayout

    def pose_grid(self, skeleton: Skeleton, settings: Settings) -> PoseGrid:
        return pose_grid(self.fields, skeleton, settings)


def pose_grid(fields: SceneFields, skeleton: Skeleton, settings: Settings) -> PoseGrid:
    """The poses a skeleton is tried at over a room's floor footprint."""
    return PoseGrid.over_footprint(
        fields.footprint,
        skeleton.torso_height,
        fields.lattice.resolution,
        settings.grid,
        skeleton.torso_reach_above,
    )


def pose_grids_for_footprint(
    footprint: tuple[float, float, float, float], settings: Settings | None = None
) -> dict[str, PoseGrid]:
    """One pose grid per affordance type (they differ in their torso heights) over a floor footprint."""
    from ..geometry.skeleton import all_skeletons

    settings = settings or Settings()
    return {
        skeleton.affordance: PoseGrid.over_footprint(
            footprint,
            skeleton.torso_height,
            settings.voxel.resolution,
            settings.grid,
            skeleton.torso_reach_above,
        )
        for skeleton in all_skeletons(settings.skeleton_dirs)
    }


def parse_gravity(text: str) -> str | np.ndarray:
    """'auto', 'none', or 'X,Y,Z' (the direction of gravity, i.e. down, in the input frame)."""
    text = text.strip().lower()
    if text in ("auto", "none"):
        return text
    try:
        vector = np.array([float(v) for v in text.split(",")])
    except ValueError:
        vector = np.array([])
    if vector.shape != (3,):
        raise ValueError(f"gravity must be 'auto', 'none' or three numbers X,Y,Z, not {text!r}")
    return vector


def to_world(
    cloud: Cloud, settings: Settings | None = None, gravity: str | np.ndarray = "auto"
) -> WorldCloud:
    """Any cloud in the world frame: thinned when over `map.max_points`, then gravity-aligned (`gravity`:
    "auto", "none" or the direction of gravity in the cloud's frame). Raises `NoFloorError` when no floor is
    found."""
    settings = settings or Settings()
    cloud, warning = thin_huge_cloud(cloud, settings.map.max_points, settings.map.thin_voxel)
    alignment = align_to_gravity(cloud.points, gravity, settings.gravity, cloud.origins)
    if alignment.method != "none":  # "none" is the identity: no copy of every point for nothing
        cloud = cloud.transformed(alignment.world_from_input)
    notes = [warning] if warning else []
    if alignment.floor_note:
        notes.append(f"the floor is {alignment.floor_note}: heights above it may be off")
    return WorldCloud(cloud, alignment, notes)


def prepare_scene(
    cloud: Cloud,
    settings: Settings | None = None,
    gravity: str | np.ndarray = "auto",
    timings: dict[str, float] | None = None,
    normals=None,
    on_world: Callable[[WorldCloud], None] | None = None,
) -> PreparedScene:
    """`to_world`, then the voxel fields every affordance is scored on; `timings` gets each one's seconds;
    `normals`: how the fields get the cloud's normals (`compute_fields`' estimator: an `updates.NormalCache`
    for a room mapped again and again); `on_world(world)` hears of the world cloud before the fields are
    computed (afford map's writer records it meanwhile)."""
    settings = settings or Settings()
    start = time.perf_counter()
    world = to_world(cloud, settings, gravity)
    if on_world is not None:
        on_world(world)
    aligned = time.perf_counter()
    fields = compute_fields(world.cloud.points, settings.voxel, settings.normals, estimator=normals)
    computed = time.perf_counter()
    if world.cloud.origins is not None:
        from ..geometry.visibility import voxel_states

        fields.visibility = voxel_states(
            fields.occupancy, fields.lattice, world.cloud.origins, settings.visibility
        )
    if timings is not None:
        timings["gravity alignment"] = aligned - start
        timings["voxel fields"] = computed - aligned
        if fields.visibility is not None:
            timings["visibility (free and unknown space)"] = time.perf_counter() - computed
    return PreparedScene(
        world.cloud,
        world.alignment,
        world.warnings,
        fields,
        FeatureLayout.from_settings(settings),
    )


def preload() -> None:
    """Import now what the fields and the maps import when first needed (scipy's ndimage and spatial, the
    scoring modules: 0.3-1 s on a busy 2-core machine), so that a service's first answer does not wait for
    it, and workers forked afterwards share it; and compile the kernels of the fields' range images, of
    the next views and of the second stage (its features' reads and its trees' walk)."""
    import scipy.ndimage  # noqa: F401
    import scipy.spatial  # noqa: F401
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1, user_api="blas"):  # the first limit finds the BLAS libraries (15 ms)
        pass

    from ..geometry.features import compile_reads
    from ..geometry.visibility import compile_range_images
    from ..learn.trees import compile_walk
    from . import inference, maps, places, updates  # noqa: F401
    from .next_views import compile_sight_lines

    compile_range_images()
    compile_sight_lines()
    compile_reads()
    compile_walk()


def map_affordances(
    fields: SceneFields,
    layout: FeatureLayout,
    models: list,
    settings: Settings | None = None,
    on_map: Callable[[str, object], None] | None = None,
) -> dict:
    """Every model's affordance map of a room's fields: {affordance: AffordanceMap}; `on_map(affordance, map)`
    hears of each as soon as it is done. Models must match the feature layout (a `ModelError` names the model
    otherwise); each places the skeleton it was trained with, and carries its own next views
    (`next_views.suggest_views`, with `settings.next_views.count` and the sensor positions)."""
    from .next_views import suggest_views

    settings = settings or Settings()

    def with_views(affordance: str, amap) -> None:
        amap.next_views = suggest_views(fields, [amap], settings)
        if on_map:
            on_map(affordance, amap)

    return RoomMapper(models, layout, settings).maps(fields, with_views)


class Superseded(Exception):
    """The maps in hand were given up for a newer map (`RoomMapper.cancel`); the maps already handed on stay
    valid maps of the older fields, and the room's state is that of the last map finished."""


class RoomMapper:
    """Maps one room again and again as it changes (a robot's map growing): each time, only the poses within
    reach of a field that changed since the last maps are scored afresh (affordcore.mapping.updates), and the
    maps equal those of a mapping from scratch. `reports` says, per affordance, how much the last call
    rescored. `cancel` (from another thread) gives up the call in hand at its next checkpoint: before each
    model, and between a model's first stage and its second."""

    def __init__(self, models: list, layout: FeatureLayout, settings: Settings | None = None):
        self.models, self.layout, self.settings = models, layout, settings or Settings()
        self.states: dict = {}  # {affordance: updates.ModelState}
        self.scanned: dict = {}  # {affordance: (nx, ny) bool, the pose grid's cells the sensor saw}
        self.reports: dict = {}  # {affordance: updates.UpdateReport}
        self.call = 0  # calls of `maps` so far: the one in hand, while one runs
        self.cancelled_through = -1  # `cancel` gave up every call up to this one
        # whether the call in hand was given up: a forked worker asks its parent's shared flag instead
        self.superseded: Callable[[], bool] = lambda: self.cancelled_through >= self.call

    def forget(self) -> None:
        """Keep nothing of the room mapped so far: the next call scores every pose afresh."""
        self.states, self.scanned, self.reports = {}, {}, {}

    def cancel(self) -> None:
        """Give up the call of `maps` in hand, if any (it raises `Superseded`); the next call is not
        affected."""
        self.cancelled_through = self.call

    def _checkpoint(self) -> None:
        if self.superseded():
            raise Superseded("the maps in hand were given up for a newer map")

    def describe(self, affordances) -> str:
        """What the last maps of these affordances rescored, for a status line."""
        reports = [self.reports[a] for a in affordances if a in self.reports]
        if not reports:
            return ""
        if any(r.reason for r in reports):
            return "scored in full (" + "; ".join(sorted({r.reason for r in reports if r.reason})) + ")"
        rescored = sum(r.rescored_poses for r in reports) / max(sum(r.total_poses for r in reports), 1)
        return f"updated: {100 * rescored:.0f} % of the poses rescored"

    def maps(
        self,
        fields: SceneFields,
        on_map: Callable[[str, object], None] | None = None,
        models: list | None = None,
    ) -> dict:
        """{affordance: AffordanceMap} of every model (or of `models`, some of them) on the fields now."""
        from .maps import build_map

        if fields.steep_facing != self.layout.steep_facing:
            raise ValueError(
                f"fields with steep normals facing '{fields.steep_facing}' for a layout of "
                f"'{self.layout.steep_facing}' (compute them with the layout's NormalSettings.steep_facing)"
            )
        if fields.normal_estimator != self.layout.normal_estimator:
            raise ValueError(
                f"fields with normals by '{fields.normal_estimator}' for a layout of "
                f"'{self.layout.normal_estimator}' (compute them with the layout's NormalSettings.estimator)"
            )
        if (fields.soft_occupancy is not None) != self.layout.soft_fields:
            kind = "soft" if self.layout.soft_fields else "binary"
            raise ValueError(f"fields of the other kind for a layout of {kind} fields (VoxelSettings.fields)")
        self.call += 1
        maps = {}
        for model in self.models if models is None else models:
            model.check_layout(self.layout)
            self._checkpoint()
            grid, scores = self.scores(model, fields)
            maps[model.affordance] = build_map(
                model.affordance,
                scores,
                grid,
                model.as_skeleton(),
                model.threshold,
                self.settings.map.nms_radius,
                place_threshold=model.place_cut(scores),
                place_model=model.places,
                place_probability=self.settings.map.place_probability,
                scanned=self.scanned[model.affordance],
            )
            if on_map:
                on_map(model.affordance, maps[model.affordance])
        return maps

    def scores(self, model, fields: SceneFields) -> tuple[PoseGrid, np.ndarray]:
        """A model's pose grid over the room and its score of every pose (`inference.model_scores`); only
        cells near scanned floor or under a scanned surface are scored (`fields.mapped_cells`), the rest hold
        float32's lowest."""
        from ..geometry.fields import mapped_cells, scanned_cells
        from .inference import model_scores
        from .updates import ModelState, known_second_stage, updated_scores

        settings, skeleton = self.settings, model.as_skeleton()
        grid = pose_grid(fields, skeleton, settings)
        scanned = scanned_cells(fields, grid.x, grid.y)
        hidden = scanned if settings.map.hidden_floor else None
        allowed = (
            mapped_cells(fields, grid.x, grid.y, settings.map.floor_margin, hidden)
            if settings.map.floor_margin >= 0
            else None
        )
        unseen = unseen_cells(fields, grid, settings)
        if unseen is not None:
            allowed = ~unseen if allowed is None else allowed & ~unseen
        previous = self.states.get(model.affordance)
        linear, stale, report = updated_scores(
            previous, fields, grid, skeleton, self.layout, model.weights, model.bias
        )
        known = None if report.reason else known_second_stage(previous, grid, stale)
        self._checkpoint()  # nothing is kept yet: the state below is set only once both stages are done
        cap = settings.map.rescore_max_poses
        scores = model_scores(model, fields, grid, self.layout, allowed, linear, known, cap)
        self.states[model.affordance] = ModelState(fields, grid, linear, scores)
        self.scanned[model.affordance] = scanned
        self.reports[model.affordance] = report
        return grid, scores


def unseen_cells(fields: SceneFields, grid: PoseGrid, settings: Settings) -> np.ndarray | None:
    """(nx, ny) bool: the cells whose body space the sensors saw too little of to hold a place
    (`visibility.body_seen` under `visibility.min_seen`); None when there is no such rule here (it is off,
    or the cloud came without sensor positions)."""
    if settings.visibility.min_seen <= 0 or fields.visibility is None:
        return None
    from ..geometry.visibility import body_seen

    return body_seen(fields, grid.x, grid.y, settings.visibility) < settings.visibility.min_seen


def score_model(
    model, fields: SceneFields, layout: FeatureLayout, settings: Settings
) -> tuple[PoseGrid, np.ndarray]:
    """A model's pose grid over the room and its score of every pose, from scratch (`RoomMapper.scores`)."""
    return RoomMapper([model], layout, settings).scores(model, fields)


def stream_features(
    scene: PreparedScene,
    skeleton: Skeleton,
    settings: Settings,
    out: Path | None = None,
    on_rows: Callable[[int], None] | None = None,
) -> tuple[int, int]:
    """Every grid pose's features for one skeleton, chunk by chunk (never the whole matrix in memory), written
    as a (poses x features) float32 .npy at `out` when given; `on_rows(n)` hears of each chunk. Returns
    (poses, features)."""
    from ..geometry.features import iter_features

    grid = scene.pose_grid(skeleton, settings)
    layout = scene.layout
    matrix = open_feature_matrix(out, grid.size, layout.n_features) if out else None
    for chunk in iter_features(
        scene.fields, skeleton, grid, layout, settings.features.chunk_mb, reuse_buffer=True
    ):
        if matrix is not None:
            matrix[chunk.start : chunk.stop] = chunk.values
        if on_rows:
            on_rows(chunk.stop - chunk.start)
    if matrix is not None:
        matrix.flush()
    return grid.size, layout.n_features


def open_feature_matrix(path: Path, rows: int, columns: int) -> np.ndarray:
    """A float32 .npy memory map for a feature matrix, refused up front when the disk cannot hold it."""
    import shutil

    needed = rows * columns * 4
    free = shutil.disk_usage(path.parent.resolve()).free
    if needed > free:
        raise OSError(
            f"{path}: the feature matrix needs {needed / 2**30:.1f} GiB and the disk has "
            f"{free / 2**30:.1f} GiB free"
        )
    return np.lib.format.open_memmap(path, mode="w+", dtype=np.float32, shape=(rows, columns))
