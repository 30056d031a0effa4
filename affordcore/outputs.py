"""What `afford map` hands to people and robots: per affordance a JSON map and a plan-view PNG, and one Rerun
recording of the room with every map."""

from __future__ import annotations

import json
from pathlib import Path

from .learn.model import AffordanceModel


def write_map_outputs(
    scene, maps: dict, models: list[AffordanceModel], out: Path, rrd: Path | None
) -> list[Path]:
    """DIR/<affordance>.json and .png for every map of a `PreparedScene`, and the recording; returns the
    paths."""
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
    """One line per map for people: places, poses above the threshold, the best score."""
    best = f", best {amap.skeletons[0, 4]:.2f}" if len(amap.skeletons) else ""
    return (
        f"{amap.affordance:<18} {len(amap.skeletons):>3} places, "
        f"{len(amap.positives):>7,} poses above the threshold{best}"
    )
