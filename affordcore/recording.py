"""Rerun recordings: one place that knows the entity paths, the z-up frame and the default blueprint.

Entity paths (everything under ``world/``, gravity-aligned, z up, metres):

* ``world/cloud``: the room's points;
* ``world/<affordance>/confidence``: the confidence map, one point per floor cell coloured by its decision
  value (cells below the model's threshold are left out);
* ``world/<affordance>/skeletons``: each skeleton of the skeleton map as line strips between its joints;
* ``world/<affordance>/places``: each skeleton's torso, labelled with its score.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .skeleton import BONES, JOINTS

APPLICATION_ID = "affordmap"


def open_recording(path: str | Path, affordances: list[str], recording_id: str | None = None):
    """A recording that streams to an .rrd file (never blocks on a viewer), with the default blueprint."""
    import rerun as rr

    recording = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id)
    recording.save(str(path), default_blueprint=blueprint(affordances))
    recording.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    return recording


def blueprint(affordances: list[str]):
    import rerun.blueprint as rrb

    views = [rrb.Spatial3DView(origin="world", name="room and every affordance")]
    views += [rrb.Spatial3DView(origin="world", contents=["world/cloud", f"world/{name}/**"], name=name) for name in affordances]
    return rrb.Blueprint(rrb.Tabs(*views), collapse_panels=True)


def log_cloud(recording, points: np.ndarray, max_points: int = 2_000_000) -> None:
    import rerun as rr

    if len(points) > max_points:
        points = points[:: int(np.ceil(len(points) / max_points))]
    heights = np.clip(points[:, 2] / 2.5, 0, 1)
    colors = (np.column_stack([0.35 + 0.4 * heights] * 3) * 255).astype(np.uint8)
    recording.log("world/cloud", rr.Points3D(points.astype(np.float32), colors=colors, radii=0.01))


def log_map(recording, amap) -> None:
    import matplotlib
    import rerun as rr

    grid = amap.grid
    ix, iy = np.nonzero(amap.confidence > amap.threshold)
    values = amap.confidence[ix, iy]
    span = max(float(values.max() - amap.threshold), 1e-9) if len(values) else 1.0
    colors = (matplotlib.colormaps["viridis"]((values - amap.threshold) / span)[:, :3] * 255).astype(np.uint8)
    cells = np.column_stack([grid.x[ix], grid.y[iy], np.full(len(ix), 0.02)])
    recording.log(f"world/{amap.affordance}/confidence", rr.Points3D(cells, colors=colors, radii=grid.step / 2,
                                                                       labels=[f"{v:.2f}" for v in values]))
    bones = [(JOINTS.index(a), JOINTS.index(b)) for a, b in BONES]
    strips = [joints[[i, j]] for joints in amap.joints for i, j in bones]
    recording.log(f"world/{amap.affordance}/skeletons", rr.LineStrips3D(strips, radii=0.015, colors=[220, 40, 60]))
    torsos = amap.joints[:, JOINTS.index("TORSO")] if len(amap.joints) else np.empty((0, 3))
    recording.log(f"world/{amap.affordance}/places", rr.Points3D(torsos, radii=0.04, colors=[220, 40, 60],
                                                                 labels=[f"{score:.2f}" for score in amap.skeletons[:, 4]]))


def recorded_entities(path: str | Path) -> set[str]:
    """Entity paths that hold data in an .rrd file (for tests and for people checking a recording)."""
    from rerun.chunk import RrdReader

    return {str(chunk.entity_path) for chunk in RrdReader(str(path)).stream().to_chunks() if not chunk.is_empty}
