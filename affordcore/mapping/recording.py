"""Rerun recordings: one place that knows the entity paths, the z-up frame and the default blueprint.

Entity paths (everything under ``world/``, gravity-aligned, z up, metres):

* ``world/cloud``: the room's points;
* ``world``: the z-up view coordinates and, once a map is logged, the skeletons' AnnotationContext (static):
  class i + 1 per affordance (its name and a colour, tab10 in the order the recording was opened with; an
  affordance not in that list is appended), each naming the 15 joints as keypoints 0..14 (``skeleton.JOINTS``)
  and connecting them by ``skeleton.BONES``;
* ``world/<affordance>/confidence``: the confidence map, one point per floor cell above the model's threshold,
  coloured by viridis over [threshold, the map's best value]; the cells' values themselves, that range and
  the colormap are on the same entity (``affordmap.Confidence:value`` / ``:value_range`` / ``:colormap``),
  shown when a cell or the entity is selected;
* ``world/<affordance>/legend``: the colormap's legend in the scene, five points along the grid's low-y edge
  labelled with the values their colours stand for;
* ``world/<affordance>/skeletons/<rank>``: each skeleton of the skeleton map (0 the best) as 15 keypoints with
  the affordance's class id: the viewer draws the bones, colours them by affordance and names the joints.
  One entity per skeleton, as the viewer joins keypoints by (class id, keypoint id) within an entity. A map
  with fewer skeletons than the last one clears the extra entities;
* ``world/<affordance>/skeletons``: how many skeletons the map has, their scores and the place threshold
  (``affordmap.SkeletonMap:count`` / ``:scores`` / ``:place_threshold``);
* ``world/<affordance>/places``: each skeleton's torso, in the affordance's colour, labelled with its score.

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

import weakref
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..geometry.skeleton import BONE_ENDS, JOINTS

APPLICATION_ID = "affordmap"
CONFIDENCE_COLORMAP = "viridis"  # matplotlib's and Rerun's (rr.components.Colormap.Viridis) alike
CONFIDENCE_ARCHETYPE = "affordmap.Confidence"  # the confidence cells' scalar values, range and colormap
SKELETONS_ARCHETYPE = "affordmap.SkeletonMap"  # how many skeletons the map has, their scores
LEGEND_TICKS = 5
LEGEND_OFFSET = 0.3  # m: each affordance's legend runs along the grid's low-y edge, this far apart
LEGEND_RADIUS = 0.05
SKELETON_RADIUS = 0.03


_CLASSES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # recording -> _Classes


@dataclass
class _Classes:
    """Per recording: the affordances in class-id order, whether the context holding them is logged, and
    how many skeleton entities each affordance's last map left (so a smaller map clears the rest)."""

    affordances: list[str] = field(default_factory=list)
    logged: bool = False
    skeletons: dict[str, int] = field(default_factory=dict)


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
    _CLASSES[recording] = _Classes(list(affordances))  # class ids in the order of the tabs
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


def affordance_colors(affordances: list[str]) -> np.ndarray:
    """(n, 3) uint8: one colour per affordance, matplotlib's qualitative tab10 in list order (repeating after
    ten), so any set of skeleton files gets distinct colours and the same list always the same ones."""
    import matplotlib

    tab10 = matplotlib.colormaps["tab10"]
    return (np.array([tab10(i % 10)[:3] for i in range(len(affordances))]).reshape(-1, 3) * 255).astype(
        np.uint8
    )


def annotation_context(affordances: list[str]):
    """The skeletons' AnnotationContext: class i + 1 is affordances[i] (its label and colour); every class
    names the 15 joints as keypoints 0..14 (skeleton.JOINTS order) and connects them by skeleton.BONES."""
    import rerun as rr

    keypoints = [rr.AnnotationInfo(id=j, label=name) for j, name in enumerate(JOINTS)]
    connections = [(int(a), int(b)) for a, b in BONE_ENDS]
    return rr.AnnotationContext(
        [
            rr.ClassDescription(
                info=rr.AnnotationInfo(id=i + 1, label=name, color=color.tolist()),
                keypoint_annotations=keypoints,
                keypoint_connections=connections,
            )
            for i, (name, color) in enumerate(zip(affordances, affordance_colors(affordances)))
        ]
    )


def _class_id(recording, affordance: str) -> int:
    """The affordance's class id in this recording, logging the (static) context the first time and again
    when an affordance the recording was not opened with turns up."""
    classes = _CLASSES.setdefault(recording, _Classes())
    if affordance not in classes.affordances:
        classes.affordances.append(affordance)
        classes.logged = False
    if not classes.logged:
        recording.log("world", annotation_context(classes.affordances), static=True)
        classes.logged = True
    return classes.affordances.index(affordance) + 1


def confidence_range(amap) -> tuple[float, float]:
    """What the confidence colormap spans: the model's threshold (the lowest value shown) to the map's best
    value; threshold to threshold + 1 when no cell is above the threshold."""
    low = float(amap.threshold)
    best = float(amap.confidence.max()) if amap.confidence.size else low
    return low, best if best > low else low + 1.0


def log_map(recording, amap) -> None:
    """The confidence map, the legend of its colormap, the skeleton map (one keypoint entity per skeleton)
    and the places, under ``world/<affordance>/``."""
    import matplotlib
    import rerun as rr

    name, grid = amap.affordance, amap.grid
    class_id = _class_id(recording, name)

    low, high = confidence_range(amap)
    ix, iy = np.nonzero(amap.confidence > amap.threshold)
    values = amap.confidence[ix, iy].astype(np.float64)
    viridis = matplotlib.colormaps[CONFIDENCE_COLORMAP]
    colors = (viridis((values - low) / (high - low))[:, :3] * 255).astype(np.uint8)
    cells = np.column_stack([grid.x[ix], grid.y[iy], np.full(len(ix), 0.02)])
    recording.log(
        f"world/{name}/confidence",
        rr.Points3D(cells, colors=colors, radii=grid.step / 2),
        rr.DynamicArchetype(
            CONFIDENCE_ARCHETYPE,
            components={
                "value": rr.components.ScalarBatch(values),
                "value_range": rr.components.ValueRangeBatch([low, high]),
                "colormap": rr.components.ColormapBatch(CONFIDENCE_COLORMAP),
            },
        ),
    )
    ticks = np.linspace(low, high, LEGEND_TICKS)
    start = np.array([grid.x[0], grid.y[0] - LEGEND_OFFSET * class_id, 0.02])
    along = np.linspace(0.0, max(float(grid.x[-1] - grid.x[0]), 1.0), LEGEND_TICKS)
    recording.log(
        f"world/{name}/legend",
        rr.Points3D(
            start + np.column_stack([along, np.zeros((LEGEND_TICKS, 2))]),
            colors=(viridis(np.linspace(0, 1, LEGEND_TICKS))[:, :3] * 255).astype(np.uint8),
            radii=LEGEND_RADIUS,
            labels=[f"{name} confidence {v:.2f}" if i == 0 else f"{v:.2f}" for i, v in enumerate(ticks)],
        ),
    )

    count = len(amap.joints)
    classes = _CLASSES[recording]
    keypoint_ids = np.arange(len(JOINTS), dtype=np.uint16)
    # one entity per skeleton: the viewer connects keypoints by (class id, keypoint id) within an entity,
    # so two skeletons in one batch would be drawn as one
    for rank, joints in enumerate(amap.joints):
        recording.log(
            f"world/{name}/skeletons/{rank}",
            rr.Points3D(joints, class_ids=class_id, keypoint_ids=keypoint_ids, radii=SKELETON_RADIUS),
        )
    for rank in range(count, classes.skeletons.get(name, 0)):
        recording.log(f"world/{name}/skeletons/{rank}", rr.Clear(recursive=False))
    classes.skeletons[name] = count
    recording.log(
        f"world/{name}/skeletons",
        rr.DynamicArchetype(
            SKELETONS_ARCHETYPE,
            components={
                "count": rr.components.CountBatch(count),
                "scores": rr.components.ScalarBatch(amap.skeletons[:, 4].astype(np.float64)),
                "probabilities": rr.components.ScalarBatch(amap.probabilities.astype(np.float64)),
                "place_threshold": rr.components.ScalarBatch(float(amap.place_threshold)),
                "place_probability": rr.components.ScalarBatch(float(amap.place_probability)),
            },
        ),
    )
    torsos = amap.joints[:, JOINTS.index("TORSO")] if count else np.empty((0, 3))
    recording.log(
        f"world/{name}/places",
        rr.Points3D(
            torsos,
            radii=0.04,
            class_ids=class_id,
            labels=amap.place_labels(),
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
