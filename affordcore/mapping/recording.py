"""Rerun recordings: one place that knows the entity paths, the z-up frame and the default blueprint.

What opens is the answer: a 3D view of the room seen from above (its points above ``CEILING_CUT`` left out
of it) with the skeletons as bones in their affordance's colour, beside a plan view and the places as text;
the fields and the scans have a tab of their own. A recording without a time (``afford map``) is one static
snapshot; the services stamp what they log on the ``stamp`` timeline (``set_time``).

Entity paths (3D under ``world/``, gravity-aligned, z up, metres; the plan under ``plan/``, x right and y up
on screen, metres):

* ``world``: the z-up view coordinates (static, with the room) and, once a map is logged, the skeletons'
  AnnotationContext (static): class i + 1 per affordance (its name and a colour, tab10 in the order the
  recording was opened with; an affordance not in that list is appended), each naming the 15 joints as
  keypoints 0..14 (``skeleton.JOINTS``) and connecting them by ``skeleton.BONES``;
* ``world/cloud``: the room's points up to ``plots.CEILING_CUT``; ``world/cloud/above``: the points above it
  (the ceiling, shown only in the "fields and scans" tab);
* ``plan/room``: the room from above, an image of the highest point up to ``plots.CEILING_CUT`` per 8 cm cell
  (darker = higher);
* ``world/<affordance>/confidence``: the confidence map, one point per floor cell above the model's threshold,
  coloured from pale (the threshold) to the affordance's colour (the map's best value); the cells' values
  themselves and that range are on the same entity (``affordmap.Confidence:value`` / ``:value_range``),
  shown when a cell or the entity is selected; ``plan/<affordance>/confidence``: the same colours as an
  image over the plan;
* ``plan/<affordance>/legend/bar``: the colour bar of that map, below the plan and centred under it (one row
  per affordance, rows apart in proportion to the room); ``plan/<affordance>/legend/range``: its name and
  range, hanging below the bar (a point label is drawn under its point), clear of the next row;
* ``world/<affordance>/skeletons/<rank>``: each skeleton of the skeleton map (0 the best) as 15 keypoints with
  the affordance's class id: the viewer draws the bones in the affordance's colour and names the joints when
  a keypoint is hovered or selected. One entity per skeleton, as the viewer joins keypoints by (class id,
  keypoint id) within an entity. A map with fewer skeletons than the last one clears the extra entities;
  ``plan/<affordance>/skeletons``: their bones from above;
* ``world/<affordance>/skeletons``: how many skeletons the map has, their scores and probabilities and the
  place threshold (``affordmap.SkeletonMap:count`` / ``:scores`` / ``:probabilities`` / ...);
* ``world/<affordance>/places`` and ``plan/<affordance>/places``: each skeleton's torso, in the affordance's
  colour, labelled with its rank and probability (or score);
* ``places``: a markdown table of every affordance's places, their probabilities, positions and facings, or
  "no place found", and how many more a map at p >= 0.1 would keep;
* ``world/<affordance>/labels/places`` and ``.../labels/facing``, and the same under ``plan/``
  (``afford map --labels``): the room's labelled places of that affordance, each its segment (or point) on
  the floor in near-white, with an arrow along its facing, so a skeleton can be checked against the place it
  should stand on.

The services add (all on the ``stamp`` timeline, the time of the message logged, so the recordings of
different processes line up; each entity is logged by one service only):

* ``world/odom``: world_from_odom, the gravity alignment of the assembler's odometry frame (the first
  sensor frame), updated at each map it publishes;
* ``world/odom/sensor``: the sensor's pose per frame; ``world/odom/sensor/scan``: each frame once, as the
  points KISS-ICP registered (thinned), in the sensor frame;
* ``world/odom/trajectory``: the sensor's path so far, in white (no affordance's colour);
* ``world/fields/occupied``: occupied voxel centres; ``world/fields/normals``: their surface normals.
"""

from __future__ import annotations

import time
import weakref
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..geometry.skeleton import BONE_ENDS, JOINTS

APPLICATION_ID = "affordmap"
CONFIDENCE_ARCHETYPE = "affordmap.Confidence"  # the confidence cells' scalar values and range
SKELETONS_ARCHETYPE = "affordmap.SkeletonMap"  # how many skeletons the map has, their scores
PLAN_CELL = 0.08  # m: the plan's room image
LEGEND_OFFSET = (
    0.5  # m: each affordance's colour bar runs below the grid's low-y edge, at least this far apart
)
LEGEND_ROW_SHARE = 0.15  # of the room's span: the rows' spacing in a larger room, so labels keep their room
LEGEND_HEIGHT = 0.12  # m
LEGEND_LABEL_GAP = 0.04  # m between a colour bar and its label below it
LEGEND_STEPS = 64
REFRAME_MARGIN = 0.5  # m a map's floor may reach beyond the one the view frames before it is framed anew
TRAJECTORY_COLOR = (255, 255, 255)  # white: tab10 has no white, and a pale tint of a colour bar is not white
SKELETON_RADIUS = 0.03
TAB10_NAMES = ("blue", "orange", "green", "red", "purple", "brown", "pink", "grey", "olive", "cyan")
LABEL_COLOR = (245, 245, 245)  # the labels in near-white: not an affordance's colour, readable on the cloud
LABEL_ARROW = 0.3  # m: a label's facing arrow
# the plan's layers, bottom to top
DRAW_ORDER = {
    "room": 0.0,
    "confidence": 1.0,
    "bar": 1.0,
    "labels": 1.5,
    "skeletons": 2.0,
    "places": 3.0,
    "next_views": 3.5,
}
VIEW_COLOR = (65, 105, 225)  # royal blue, as the PNGs draw the next views
VIEW_FRUSTUM = 0.6  # m: how deep a next view's frustum is drawn (its range would hide the room)


_STATE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # recording -> _State


@dataclass
class _State:
    """Per recording: the affordances in class-id order, whether the context holding them is logged, how
    many skeleton entities each affordance's last map left (so a smaller map clears the rest), each mapped
    affordance's rows of the places table, whether a time was set (until then all is static) and
    whether the view was framed on the room."""

    affordances: list[str] = field(default_factory=list)
    logged: bool = False
    skeletons: dict[str, int] = field(default_factory=dict)
    sections: dict[str, list[str]] = field(default_factory=dict)
    notes: dict[str, str] = field(default_factory=dict)  # under the table: what a lower probability would add
    timed: bool = False
    framed: tuple[np.ndarray, np.ndarray, int] | None = None  # the floor's (low, high) (x, y) corners, bars
    views: int = 0  # next views the last call logged (so fewer clear the rest)


def _state(recording) -> _State:
    return _STATE.setdefault(recording, _State())


def recording_name(subject: str) -> str:
    """What the viewer lists a recording as: its robot or room and when it was made (local time)."""
    return f"{subject} {time.strftime('%Y-%m-%d %H:%M:%S')}"


def open_recording(
    path: str | Path,
    affordances: list[str],
    recording_id: str | None = None,
    viewer: str | None = None,
    name: str | None = None,
):
    """A recording that streams to an .rrd file with the default blueprint and, given a viewer URL
    (rerun+http://HOST:9876/proxy), to that viewer too. The file never waits for the viewer. `name` (what
    the viewer lists it as, `recording_name`) is also its id when no id is given: recordings of several
    processes that share an id open as one."""
    import rerun as rr

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    name = name or recording_name(Path(path).stem)
    recording = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id or name)
    sinks = [rr.FileSink(str(path))] + ([rr.GrpcSink(viewer)] if viewer else [])
    recording.set_sinks(*sinks, default_blueprint=blueprint())
    recording.send_recording_name(name)
    _STATE[recording] = _State(list(affordances))  # class ids in the order of the tabs
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
    """Stamp what follows at `seconds`; from the first call on, nothing the recording logs is static."""
    _state(recording).timed = True
    recording.set_time("stamp", timestamp=seconds)


def _log(recording, entity: str, *archetypes) -> None:
    """Log at the recording's time, or as static data when it has none (an offline map)."""
    recording.log(entity, *archetypes, static=not _state(recording).timed)


def blueprint(room: tuple[np.ndarray, np.ndarray, int] | None = None):
    """The first tab answers "where can a person sit, work, stand?": the room in 3D from above (without the
    points above ``CEILING_CUT``, the fields and the scans) beside the plan and the places, at the latest
    time the recording holds; the second shows everything. `room`: the floor's (low, high) (x, y) corners
    and how many colour bars run below it, which the 3D eye and the plan frame (else the viewer's own
    choice)."""
    import rerun.blueprint as rrb

    eye, bounds = _framing(*room) if room is not None else (None, None)
    answer = rrb.Horizontal(
        rrb.Spatial3DView(
            origin="world",
            contents=["+ world/**", "- world/cloud/above", "- world/fields/**", "- world/odom/sensor/**"],
            name="room from above",
            eye_controls=eye,
        ),
        rrb.Vertical(
            rrb.Spatial2DView(origin="plan", name="plan", visual_bounds=bounds),
            rrb.TextDocumentView(origin="places", name="places"),
            row_shares=[3, 2],
        ),
        column_shares=[3, 2],
        name="places",
    )
    everything = rrb.Spatial3DView(origin="world", name="fields and scans")
    # a recording opened after the run starts at its latest time, where the final maps are: played from the
    # start, a service run's first view is its first scan's empty room
    time = rrb.TimePanel(state="collapsed", play_state="following")
    return rrb.Blueprint(rrb.Tabs(answer, everything, active_tab=0), time, collapse_panels=True)


def _framing(low: np.ndarray, high: np.ndarray, bars: int):
    """The 3D eye, in orbit above the room's low-y side looking down at its middle about 30 degrees from
    the vertical (so the plan's "up" is the 3D view's too), and the plan's bounds: the floor and its
    colour bars, with a margin."""
    import rerun.blueprint as rrb

    centre, span = (low + high) / 2, float(np.max(high - low))
    eye = rrb.EyeControls3D(
        kind=rrb.Eye3DKind.Orbital,
        position=[centre[0], centre[1] - 0.6 * span, 1.1 * span + 1.0],
        look_target=[centre[0], centre[1], 0.3],
        eye_up=[0.0, 0.0, 1.0],
    )
    margin = 0.4
    bounds = rrb.VisualBounds2D(
        x_range=[low[0] - margin, high[0] + margin],
        y_range=[-high[1] - margin, -low[1] + legend_row(span) * (bars + 1)],  # and the last bar's label
    )
    return eye, bounds


def legend_row(span: float) -> float:
    """How far apart the colour bars' rows are below a floor `span` metres across: a label is drawn at a
    fixed size on screen, so in a larger room (seen smaller) it covers more metres."""
    return max(LEGEND_OFFSET, LEGEND_ROW_SHARE * span)


def _frame_room(recording, grid) -> None:
    """Make the default blueprint frame the map's floor (the pose grid's) and the colour bars of the
    affordances it knows: at the first map, and again whenever a map's floor reaches more than
    `REFRAME_MARGIN` beyond the floor framed (a robot's room grows as it walks: a view framed on its first
    map would show the last one cut off, from too close) or an affordance's colour bar is new. Each framing
    holds every floor framed before."""
    state = _state(recording)
    low, high = np.array([grid.x[0], grid.y[0]]), np.array([grid.x[-1], grid.y[-1]])
    bars = len(state.affordances)
    if state.framed is not None:
        framed_low, framed_high, framed_bars = state.framed
        grown = max((framed_low - low).max(), (high - framed_high).max()) > REFRAME_MARGIN
        if not grown and bars == framed_bars:
            return
        low, high = np.minimum(low, framed_low), np.maximum(high, framed_high)
    recording.send_blueprint(blueprint((low, high, bars)), make_active=True, make_default=True)
    state.framed = (low, high, bars)


def log_cloud(recording, points: np.ndarray, max_points: int = 2_000_000) -> None:
    """The room's points (those above ``plots.CEILING_CUT`` apart) and the plan's room image."""
    import rerun as rr

    from .plots import CEILING_CUT, plan_heights

    if len(points) > max_points:
        points = points[:: int(np.ceil(len(points) / max_points))]
    points = points.astype(np.float32)
    heights = np.clip(points[:, 2] / 2.5, 0, 1)
    colors = (np.column_stack([0.35 + 0.4 * heights] * 3) * 255).astype(np.uint8)
    below = points[:, 2] <= CEILING_CUT
    recording.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    _log(recording, "world/cloud", rr.Points3D(points[below], colors=colors[below], radii=0.01))
    _log(recording, "world/cloud/above", rr.Points3D(points[~below], colors=colors[~below], radii=0.01))
    if below.any():
        top, corner = plan_heights(points[below], PLAN_CELL)
        grey = 235 - 150 * np.clip(np.nan_to_num(top, nan=0.0) / CEILING_CUT, 0, 1)
        rgba = np.stack([grey, grey, grey, np.where(np.isnan(top), 0, 255)], axis=-1).astype(np.uint8)
        _log_plan_image(recording, "plan/room", rgba, corner, PLAN_CELL)


def _log_plan_image(recording, entity: str, rgba: np.ndarray, corner, cell) -> None:
    """An (nx, ny, 4) image of floor cells, [ix, iy] covering corner + (ix, iy) * cell onward, on the plan
    (whose v axis is -y: image rows run from the room's high-y side down)."""
    import rerun as rr

    cell = np.broadcast_to(np.asarray(cell, dtype=np.float64), (2,))
    height = rgba.shape[1] * cell[1]
    _log(
        recording,
        entity,
        rr.Image(
            np.ascontiguousarray(rgba.transpose(1, 0, 2)[::-1]),
            color_model="RGBA",
            draw_order=DRAW_ORDER[entity.split("/")[-1]],
        ),
        rr.Transform3D(translation=[corner[0], -(corner[1] + height), 0.0], scale=[cell[0], cell[1], 1.0]),
    )


def _plan(xy: np.ndarray) -> np.ndarray:
    """World (x, y) to the plan's (u, v): v is -y, as the 2D view's v axis points down the screen."""
    return np.asarray(xy)[..., :2] * np.array([1.0, -1.0])


def import_rerun() -> None:
    """Import rerun now: 0.6-0.8 s of CPU (its blueprint and arrow modules), which `open_recording` would
    otherwise pay for at the first recording."""
    import rerun  # noqa: F401
    import rerun.blueprint  # noqa: F401


def preload() -> None:
    """Import now what logging the first map imports (matplotlib's colour maps for the affordances' colours:
    0.15-0.45 s), so that a service does not pay for it between its first map and the next."""
    import matplotlib  # noqa: F401


def affordance_colors(affordances: list[str]) -> np.ndarray:
    """(n, 3) uint8: one colour per affordance, matplotlib's qualitative tab10 in list order (repeating after
    ten), so any set of skeleton files gets distinct colours and the same list always the same ones."""
    import matplotlib

    tab10 = matplotlib.colormaps["tab10"]
    return (np.array([tab10(i % 10)[:3] for i in range(len(affordances))]).reshape(-1, 3) * 255).astype(
        np.uint8
    )


def confidence_colors(values: np.ndarray, low: float, high: float, color: np.ndarray) -> np.ndarray:
    """(n, 3) uint8: each value's colour on an affordance's colour bar, from a pale tint of `color` at `low`
    to `color` itself at `high` (one hue per affordance, so maps drawn together stay apart)."""
    t = np.clip((np.asarray(values, dtype=np.float64) - low) / (high - low), 0, 1)[:, None]
    pale = 0.25 * color + 0.75 * 255.0
    return np.round(pale + t * (np.asarray(color, dtype=np.float64) - pale)).astype(np.uint8)


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
    state = _state(recording)
    if affordance not in state.affordances:
        state.affordances.append(affordance)
        state.logged = False
    if not state.logged:
        recording.log("world", annotation_context(state.affordances), static=True)
        state.logged = True
    return state.affordances.index(affordance) + 1


def confidence_range(amap) -> tuple[float, float]:
    """What the confidence colour bar spans: the model's threshold (the lowest value shown) to the map's best
    value; threshold to threshold + 1 when no cell is above the threshold."""
    low = float(amap.threshold)
    best = float(amap.confidence.max()) if amap.confidence.size else low
    return low, best if best > low else low + 1.0


def log_map(recording, amap) -> None:
    """One affordance map: its confidence (3D and plan) and colour bar, its skeletons (one keypoint entity
    per skeleton, and their bones on the plan), its places and its rows of the places table."""
    class_id = _class_id(recording, amap.affordance)
    color = affordance_colors(_state(recording).affordances)[class_id - 1]
    _log_confidence(recording, amap, color)
    _log_skeletons(recording, amap, class_id, color)
    _log_places_document(recording, amap, class_id)
    _frame_room(recording, amap.grid)


def log_views(recording, views: list, camera) -> None:
    """A robot's next views (`next_views.NextView`, best first) for a camera of `camera` (NextViewSettings):
    each a frustum in 3D at its pose, tilted by the camera's pitch; on the plan its field of view as two
    rays of a metre, a line to each of the places it would settle most, and its rank and gain."""
    import rerun as rr
    from scipy.spatial.transform import Rotation

    from ..geometry.skeleton import rotation_z
    from .next_views import DRAWN_LOOKS

    state = _state(recording)
    half, vertical = np.radians(camera.fov_horizontal_deg) / 2, np.radians(camera.fov_vertical_deg)
    # tilted up by the pitch: about the camera's y (left) axis, a positive turn takes x (forward) down
    pitch = Rotation.from_euler("y", -camera.pitch_deg, degrees=True).as_matrix()
    for rank, view in enumerate(views):
        _log(
            recording,
            f"world/next_views/{rank}",
            rr.Transform3D(translation=[view.x, view.y, view.z], mat3x3=rotation_z(view.heading) @ pitch),
            rr.Pinhole(
                fov_y=float(vertical),
                aspect_ratio=float(np.tan(half) / np.tan(vertical / 2)),
                camera_xyz=rr.ViewCoordinates.FLU,
                image_plane_distance=VIEW_FRUSTUM,
                color=VIEW_COLOR,
            ),
        )
    for rank in range(len(views), state.views):
        _log(recording, f"world/next_views/{rank}", rr.Clear(recursive=True))
    state.views = len(views)
    labels = [f"view {rank}: {view.gain:.2f} bits" for rank, view in enumerate(views, 1)]
    eyes = np.array([[view.x, view.y] for view in views]).reshape(-1, 2)
    rays, looks = [], []
    for view in views:
        for side in (-half, half):
            edge = view.heading + side
            rays.append([[view.x, view.y], [view.x + np.cos(edge), view.y + np.sin(edge)]])
        looks += [[[view.x, view.y], [x, y]] for x, y, _ in view.looks_at[:DRAWN_LOOKS]]
    order = DRAW_ORDER["next_views"]
    _log(
        recording,
        "plan/next_views",
        rr.Points2D(_plan(eyes), radii=0.08, colors=VIEW_COLOR, labels=labels, draw_order=order),
    )
    _log(
        recording,
        "plan/next_views/fov",
        rr.LineStrips2D(
            _plan(np.array(rays).reshape(-1, 2, 2)), radii=0.015, colors=VIEW_COLOR, draw_order=order
        ),
    )
    _log(
        recording,
        "plan/next_views/looks",
        rr.LineStrips2D(
            _plan(np.array(looks).reshape(-1, 2, 2)), radii=0.006, colors=VIEW_COLOR, draw_order=order
        ),
    )


def log_labels(recording, labels, affordances: list[str]) -> None:
    """A `LabelSet`'s places of each of `affordances` (in the world frame): segments on the floor and arrows
    along their facing, in 3D and on the plan."""
    import rerun as rr

    floor, order = 0.03, DRAW_ORDER["labels"]  # just above the confidence cells
    for name in affordances:
        chosen = labels.of(name)
        if not chosen:
            continue
        ends = [np.array([x.at, x.at] if x.at is not None else [x.start, x.end]) for x in chosen]
        middles = np.array([e.mean(axis=0) for e in ends])
        facing = np.array([[np.cos(x.facing), np.sin(x.facing)] for x in chosen]) * LABEL_ARROW
        lifted = [np.column_stack([e, np.full(2, floor)]) for e in ends]
        _log(
            recording, f"world/{name}/labels/places", rr.LineStrips3D(lifted, radii=0.02, colors=LABEL_COLOR)
        )
        _log(
            recording,
            f"world/{name}/labels/facing",
            rr.Arrows3D(
                origins=np.column_stack([middles, np.full(len(middles), floor)]),
                vectors=np.column_stack([facing, np.zeros(len(facing))]),
                radii=0.015,
                colors=LABEL_COLOR,
            ),
        )
        flat = [_plan(e) for e in ends]
        _log(
            recording,
            f"plan/{name}/labels/places",
            rr.LineStrips2D(flat, radii=0.03, colors=LABEL_COLOR, draw_order=order),
        )
        _log(
            recording,
            f"plan/{name}/labels/facing",
            rr.Arrows2D(
                origins=_plan(middles),
                vectors=_plan(facing),
                radii=0.02,
                colors=LABEL_COLOR,
                draw_order=order,
            ),
        )


def _log_confidence(recording, amap, color: np.ndarray) -> None:
    import rerun as rr

    name, grid = amap.affordance, amap.grid
    low, high = confidence_range(amap)
    above = amap.confidence > amap.threshold
    ix, iy = np.nonzero(above)
    values = amap.confidence[ix, iy].astype(np.float64)
    colors = confidence_colors(values, low, high, color)
    cells = np.column_stack([grid.x[ix], grid.y[iy], np.full(len(ix), 0.02)])
    _log(
        recording,
        f"world/{name}/confidence",
        rr.Points3D(cells, colors=colors, radii=grid.step / 2),
        rr.DynamicArchetype(
            CONFIDENCE_ARCHETYPE,
            components={
                "value": rr.components.ScalarBatch(values),
                "value_range": rr.components.ValueRangeBatch([low, high]),
            },
        ),
    )
    rgba = np.zeros((*amap.confidence.shape, 4), dtype=np.uint8)
    rgba[ix, iy, :3], rgba[ix, iy, 3] = colors, 200
    corner = np.array([grid.x[0], grid.y[0]]) - grid.step / 2
    _log_plan_image(recording, f"plan/{name}/confidence", rgba, corner, grid.step)

    # the colour bar: below the grid and centred under it, one row per affordance in class order, named with
    # its range below it. The label is the bar's sibling, not its child: the bar's image transform (its
    # scale, one pixel per step) would move and shrink anything below it.
    rank = _state(recording).affordances.index(name)
    span = float(max(grid.x[-1] - grid.x[0], grid.y[-1] - grid.y[0]))
    width = max(float(grid.x[-1] - grid.x[0]) / 2, 1.0)
    bar = confidence_colors(np.linspace(low, high, LEGEND_STEPS), low, high, color)
    start = np.array([(grid.x[0] + grid.x[-1] - width) / 2, grid.y[0] - legend_row(span) * (rank + 1)])
    rgba = np.concatenate([bar, np.full((LEGEND_STEPS, 1), 255, np.uint8)], axis=1)
    rgba = np.repeat(rgba[:, None], 2, axis=1)  # two rows: the SDK reads a one-row image as a column
    _log_plan_image(
        recording, f"plan/{name}/legend/bar", rgba, start, [width / LEGEND_STEPS, LEGEND_HEIGHT / 2]
    )
    _log(
        recording,
        f"plan/{name}/legend/range",
        rr.Points2D(
            _plan(start + [width / 2, -LEGEND_LABEL_GAP]),  # the label hangs below its point
            radii=0.001,
            colors=color,
            labels=f"{name}: {low:.2f} (pale) to {high:.2f}",
            draw_order=DRAW_ORDER["places"],
        ),
    )


def _log_skeletons(recording, amap, class_id: int, color: np.ndarray) -> None:
    import rerun as rr

    name, count = amap.affordance, len(amap.joints)
    state = _state(recording)
    keypoint_ids = np.arange(len(JOINTS), dtype=np.uint16)
    # one entity per skeleton: the viewer connects keypoints by (class id, keypoint id) within an entity,
    # so two skeletons in one batch would be drawn as one; the joints' names only on hover
    for rank, joints in enumerate(amap.joints):
        _log(
            recording,
            f"world/{name}/skeletons/{rank}",
            rr.Points3D(
                joints,
                class_ids=class_id,
                keypoint_ids=keypoint_ids,
                radii=SKELETON_RADIUS,
                show_labels=False,
            ),
        )
    for rank in range(count, state.skeletons.get(name, 0)):
        _log(recording, f"world/{name}/skeletons/{rank}", rr.Clear(recursive=False))
    state.skeletons[name] = count
    _log(
        recording,
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
    bones = _plan(amap.joints[:, BONE_ENDS]).reshape(-1, 2, 2)  # (k * 15 bones, 2 ends, u v)
    _log(
        recording,
        f"plan/{name}/skeletons",
        rr.LineStrips2D(bones, radii=0.025, colors=color, draw_order=DRAW_ORDER["skeletons"]),
    )
    torsos = amap.joints[:, JOINTS.index("TORSO")] if count else np.empty((0, 3))
    labels = [f"{rank + 1}: {label}" for rank, label in enumerate(amap.place_labels())]
    _log(
        recording, f"world/{name}/places", rr.Points3D(torsos, radii=0.04, class_ids=class_id, labels=labels)
    )
    _log(
        recording,
        f"plan/{name}/places",
        rr.Points2D(_plan(torsos), radii=0.06, colors=color, labels=labels, draw_order=DRAW_ORDER["places"]),
    )


def places_rows(amap, colour: str) -> list[str]:
    """An affordance's rows of the places table: each place's rank, probability (or score, for a model
    without a place model), position and facing, or one row saying "no place found"."""
    name = f"{amap.affordance} ({colour})"
    if not len(amap.skeletons):
        return [f"| {name} | **no place found** | | | |"]
    return [
        f"| {name} | {rank + 1} | {f'{p:.2f}' if np.isfinite(p) else f'score {score:.2f}'} "
        f"| {x:.2f}, {y:.2f} | {np.degrees(theta) % 360:.0f}° |"
        for rank, (p, (x, y, _, theta, score)) in enumerate(zip(amap.probabilities, amap.skeletons))
    ]


PLACES_HEADER = "| affordance | place | probability | x, y (m) | facing |\n|---|---|---|---|---|"


def _log_places_document(recording, amap, class_id: int) -> None:
    """The ``places`` document: one table of every affordance the recording knows, mapped or not yet, in
    class order; under it, for each map that left places below its probability, how many and how to ask
    for them (a line of its own: in the table it would widen a column off the panel)."""
    import rerun as rr

    state = _state(recording)
    state.sections[amap.affordance] = places_rows(amap, TAB10_NAMES[(class_id - 1) % 10])
    state.notes[amap.affordance] = amap.unsure_note()
    rows = [
        row
        for name in state.affordances
        for row in state.sections.get(name, [f"| {name} | not mapped yet | | | |"])
    ]
    notes = [f"* {name}: {state.notes[name]}" for name in state.affordances if state.notes.get(name)]
    text = "\n".join([PLACES_HEADER, *rows]) + "\n" + ("\n" + "\n".join(notes) + "\n" if notes else "")
    _log(recording, "places", rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN))


def log_scan(recording, points: np.ndarray, odom_from_sensor: np.ndarray) -> None:
    import rerun as rr

    _log(
        recording,
        "world/odom/sensor",
        rr.Transform3D(translation=odom_from_sensor[:3, 3], mat3x3=odom_from_sensor[:3, :3]),
    )
    _log(
        recording,
        "world/odom/sensor/scan",
        rr.Points3D(np.asarray(points, dtype=np.float32), radii=0.01, colors=[70, 140, 230]),
    )


def log_trajectory(recording, positions: np.ndarray, world_from_odom: np.ndarray) -> None:
    import rerun as rr

    _log(
        recording,
        "world/odom",
        rr.Transform3D(translation=world_from_odom[:3, 3], mat3x3=world_from_odom[:3, :3]),
    )
    _log(
        recording,
        "world/odom/trajectory",
        rr.LineStrips3D([np.asarray(positions, dtype=np.float32)], radii=0.01, colors=TRAJECTORY_COLOR),
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
    _log(
        recording,
        "world/fields/occupied",
        rr.Points3D(centres, colors=colors, radii=fields.lattice.resolution / 3),
    )
    normals = fields.normals[tuple(index.T)]
    keep = np.flatnonzero(np.any(normals != 0, axis=1))[:: max(1, int(np.ceil(len(index) / max_normals)))]
    _log(
        recording,
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
