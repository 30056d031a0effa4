"""What `afford map` (and the inference service) hand to people and robots: per affordance a JSON map and a
plan-view PNG, and one Rerun recording of the room with every map."""

from __future__ import annotations

import json
from pathlib import Path

from .learn.model import AffordanceModel, ModelError, load_model
from .scene import Cloud, voxel_thin
from .settings import MapSettings

MODELS_DIR = Path(__file__).parent / "data" / "models"


def shipped_models() -> dict[str, Path]:
    """{affordance: model file} of the default models inside the package."""
    return {path.name.removesuffix(".model.json"): path for path in sorted(MODELS_DIR.glob("*.model.json"))}


def choose_models(model_files: list[Path], affordances: list[str], layout) -> list[AffordanceModel]:
    """The given model files, else the shipped models of the named affordances, else every shipped model."""
    if model_files:
        models = [load_model(path, layout) for path in model_files]
    else:
        shipped = shipped_models()
        unknown = [name for name in affordances if name not in shipped]
        if unknown:
            raise ModelError(f"no shipped model for {', '.join(unknown)}; shipped: {', '.join(shipped) or 'none'} (or pass --model FILE)")
        models = [load_model(shipped[name], layout) for name in (affordances or list(shipped))]
    wanted = [m for m in models if not affordances or m.affordance in affordances]
    if not wanted:
        raise ModelError(f"none of the models is for {', '.join(affordances)}")
    return wanted


def thin_huge_cloud(cloud: Cloud, settings: MapSettings) -> tuple[Cloud, str | None]:
    """A cloud over `max_points` is voxel-thinned (1 cm, doubled until it fits); returns it and a warning."""
    if len(cloud) <= settings.max_points:
        return cloud, None
    voxel = settings.thin_voxel
    points, colors = voxel_thin(cloud.points, voxel, cloud.colors)
    while len(points) > settings.max_points:
        voxel *= 2
        points, colors = voxel_thin(cloud.points, voxel, cloud.colors)
    warning = (f"{cloud.source}: {len(cloud):,} points is over the {settings.max_points:,} limit; thinned to {len(points):,} "
               f"at {voxel * 100:.0f} mm voxels (AFFORD_MAP__MAX_POINTS raises the limit)")
    return Cloud(points, colors, source=cloud.source), warning


def write_map_outputs(scene, maps: dict, models: list[AffordanceModel], out: Path, rrd: Path | None) -> list[Path]:
    """DIR/<affordance>.json and .png for every map, and the recording; returns the paths written."""
    from .plots import plot_map
    from .recording import close_recording, log_cloud, log_map, open_recording

    out.mkdir(parents=True, exist_ok=True)
    ids = {model.affordance: model.id for model in models}
    written = []
    for affordance, amap in maps.items():
        document = amap.to_json(ids[affordance], scene.alignment.world_from_input)
        written.append(out / f"{affordance}.json")
        written[-1].write_text(json.dumps(document) + "\n")
        written.append(plot_map(scene.cloud.points, amap, out / f"{affordance}.png"))
    if rrd is not None:
        recording = open_recording(rrd, list(maps))
        log_cloud(recording, scene.cloud.points)
        for amap in maps.values():
            log_map(recording, amap)
        close_recording(recording)
        written.append(rrd)
    return written


def summary_line(amap) -> str:
    best = f", best {amap.skeletons[0, 4]:.2f}" if len(amap.skeletons) else ""
    return f"{amap.affordance:<18} {len(amap.skeletons):>3} places, {len(amap.positives):>7,} poses above the threshold{best}"


__all__ = ["shipped_models", "choose_models", "thin_huge_cloud", "write_map_outputs", "summary_line"]
