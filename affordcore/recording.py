"""Rerun recordings: one place that knows the entity paths, the z-up frame and the default blueprint.

Entity paths (everything under ``world/``, gravity-aligned, z up, metres):

* ``world/cloud``: the room's points;
* ``world/<affordance>/confidence``: the confidence map, one point per floor cell coloured by its decision
  value (cells below the model's threshold are left out);
* ``world/<affordance>/skeletons``: each skeleton of the skeleton map as line strips between its joints;
* ``world/<affordance>/places``: each skeleton's torso, labelled with its score.

The services add (all on the ``stamp`` timeline, the time of the message logged, so the recordings of
different processes line up):

* ``world/odom``: world_from_odom, the gravity alignment of the assembler's odometry frame (the first
  sensor frame), updated at each map it publishes;
* ``world/odom/sensor``: the sensor's pose per frame; ``world/odom/sensor/scan``: each frame once, as the
  points KISS-ICP registered (thinned), in the sensor frame;
* ``world/odom/trajectory``: the sensor's path so far;
* ``world/fields/occupied``: occupied voxel centres; ``world/fields/normals``: their surface normals.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .skeleton import BONE_ENDS, JOINTS

APPLICATION_ID = "affordmap"


def open_recording(
    path: str | Path, affordances: list[str], recording_id: str | None = None, viewer: str | None = None
):
    """A recording that streams to an .rrd file with the default blueprint and, given a viewer URL
    (rerun+http://HOST:9876/proxy), to that viewer too. The file never waits for the viewer."""
    import rerun as rr

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    recording = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id)
    sinks = [rr.FileSink(str(path))] + ([rr.GrpcSink(viewer)] if viewer else [])
    recording.set_sinks(*sinks, default_blueprint=blueprint(affordances))
    recording.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    return recording


def close_recording(recording, timeout: float = 5.0) -> str | None:
    """Flush and close; returns a warning when a viewer could not be reached (the file is complete anyway)."""
    warning = None
    try:
        recording.flush(timeout_sec=timeout)
    except RuntimeError as error:  # only the viewer's gRPC sink fails this way
        warning = f"recording viewer unreachable: {error}"
    recording.disconnect()
    return warning


def set_time(recording, seconds: float) -> None:
    recording.set_time("stamp", timestamp=seconds)


def blueprint(affordances: list[str]):
    import rerun.blueprint as rrb

    views = [rrb.Spatial3DView(origin="world", name="room and every affordance")]
    views += [
        rrb.Spatial3DView(origin="world", contents=["world/cloud", f"world/{name}/**"], name=name)
        for name in affordances
    ]
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
    recording.log(
        f"world/{amap.affordance}/confidence",
        rr.Points3D(cells, colors=colors, radii=grid.step / 2, labels=[f"{v:.2f}" for v in values]),
    )
    strips = [joints[ends] for joints in amap.joints for ends in BONE_ENDS]
    recording.log(
        f"world/{amap.affordance}/skeletons", rr.LineStrips3D(strips, radii=0.015, colors=[220, 40, 60])
    )
    torsos = amap.joints[:, JOINTS.index("TORSO")] if len(amap.joints) else np.empty((0, 3))
    recording.log(
        f"world/{amap.affordance}/places",
        rr.Points3D(
            torsos,
            radii=0.04,
            colors=[220, 40, 60],
            labels=[f"{score:.2f}" for score in amap.skeletons[:, 4]],
        ),
    )


def log_scan(recording, points: np.ndarray, odom_from_sensor: np.ndarray) -> None:
    import rerun as rr

    recording.log(
        "world/odom/sensor",
        rr.Transform3D(translation=odom_from_sensor[:3, 3], mat3x3=odom_from_sensor[:3, :3]),
    )
    recording.log(
        "world/odom/sensor/scan",
        rr.Points3D(np.asarray(points, dtype=np.float32), radii=0.01, colors=[70, 140, 230]),
    )


def log_trajectory(recording, positions: np.ndarray, world_from_odom: np.ndarray) -> None:
    import rerun as rr

    recording.log(
        "world/odom", rr.Transform3D(translation=world_from_odom[:3, 3], mat3x3=world_from_odom[:3, :3])
    )
    recording.log(
        "world/odom/trajectory",
        rr.LineStrips3D([np.asarray(positions, dtype=np.float32)], radii=0.01, colors=[240, 160, 30]),
    )


def log_fields(recording, fields, max_normals: int = 20_000) -> None:
    """Occupied voxels (coloured by height) and a thinned set of their normals."""
    import rerun as rr

    index = np.argwhere(fields.occupancy > 0)
    centres = fields.lattice.centres(index).astype(np.float32)
    heights = np.clip(centres[:, 2] / 2.5, 0, 1)
    colors = (
        np.column_stack([0.3 + 0.5 * heights, 0.45 * np.ones_like(heights), 0.8 - 0.5 * heights]) * 255
    ).astype(np.uint8)
    recording.log(
        "world/fields/occupied", rr.Points3D(centres, colors=colors, radii=fields.lattice.resolution / 3)
    )
    normals = fields.normals[tuple(index.T)]
    keep = np.flatnonzero(np.any(normals != 0, axis=1))[:: max(1, int(np.ceil(len(index) / max_normals)))]
    recording.log(
        "world/fields/normals",
        rr.Arrows3D(
            origins=centres[keep], vectors=normals[keep] * fields.lattice.resolution, colors=[120, 200, 120]
        ),
    )


def recorded_entities(path: str | Path) -> set[str]:
    """Entity paths that hold data in an .rrd file (for tests and for people checking a recording)."""
    from rerun.chunk import RrdReader

    return {
        str(chunk.entity_path) for chunk in RrdReader(str(path)).stream().to_chunks() if not chunk.is_empty
    }
