"""From a cloud to what every affordance is scored on (the aligned cloud, its voxel fields, pose grids), and to
the affordance maps."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .features import FeatureLayout
from .fields import SceneFields, compute_fields, observed_floor
from .gravity import Alignment, align_to_gravity
from .grid import PoseGrid
from .scene import Cloud
from .settings import Settings
from .skeleton import Skeleton


@dataclass
class PreparedScene:
    cloud: Cloud  # in the world frame
    alignment: Alignment
    fields: SceneFields
    layout: FeatureLayout

    def pose_grid(self, skeleton: Skeleton, settings: Settings) -> PoseGrid:
        return pose_grid(self.fields, skeleton, settings)


def pose_grid(fields: SceneFields, skeleton: Skeleton, settings: Settings) -> PoseGrid:
    """The poses a skeleton is tried at over a room's floor footprint."""
    return PoseGrid.over_footprint(fields.footprint, skeleton.torso_height, fields.lattice.resolution, settings.grid)


def pose_grids_for_footprint(footprint: tuple[float, float, float, float], settings: Settings | None = None) -> dict[str, PoseGrid]:
    """One pose grid per affordance type (they differ in their torso heights) over a floor footprint."""
    from .skeleton import all_skeletons

    settings = settings or Settings()
    return {
        skeleton.affordance: PoseGrid.over_footprint(footprint, skeleton.torso_height, settings.voxel.resolution, settings.grid)
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


def prepare_scene(cloud: Cloud, settings: Settings | None = None, gravity: str | np.ndarray = "auto") -> PreparedScene:
    settings = settings or Settings()
    alignment = align_to_gravity(cloud.points, gravity, settings.gravity)
    world = cloud.transformed(alignment.world_from_input)
    fields = compute_fields(world.points, settings.voxel, settings.normals)
    return PreparedScene(world, alignment, fields, FeatureLayout.from_settings(settings.features, settings.voxel))


def map_affordances(fields: SceneFields, layout: FeatureLayout, models: list, settings: Settings | None = None,
                    on_map: Callable[[str, object], None] | None = None) -> dict:
    """Every model's affordance map of a room's fields: {affordance: AffordanceMap}; `on_map(affordance, map)`
    hears of each as soon as it is done. Models must match the feature layout (a `ModelError` names the model
    otherwise); each places the skeleton it was trained with."""
    from .inference import score_poses
    from .maps import build_map

    settings = settings or Settings()
    maps = {}
    for model in models:
        model.check_layout(layout, f"model {model.id}")
        skeleton = model.as_skeleton()
        grid = pose_grid(fields, skeleton, settings)
        scores = score_poses(fields, skeleton, grid, layout, model.weights, model.bias)
        allowed = observed_floor(fields, grid.x, grid.y, settings.map.floor_margin) if settings.map.floor_margin >= 0 else None
        maps[model.affordance] = build_map(model.affordance, scores, grid, skeleton, model.threshold, settings.map.nms_radius, allowed)
        if on_map:
            on_map(model.affordance, maps[model.affordance])
    return maps
