"""Affordance maps as ROS 2 messages: an `afford.v1.AffordanceMap` to CDR bytes of
`geometry_msgs/msg/PoseArray` (the places), `visualization_msgs/msg/MarkerArray` (the places for RViz2, with
their probabilities) and `nav_msgs/msg/OccupancyGrid` (the confidence map). Message in, bytes out, no
transport: the inference service publishes them (services/ros_maps.py, docs/ros.md).

Encoded by rosbags with its ROS 2 Jazzy type store, as affordwire.ros decodes the robots' clouds: the same
definitions give the RIHS01 type hashes that rmw_zenoh puts in its keys (`type_hash`).

Conventions:

* a place's pose is its (x, y, z) with the yaw `theta` (about z, the map's up) as a quaternion;
* the OccupancyGrid has one cell per (x, y) position of the map's pose grid (`resolution` = the grid's step,
  origin at the low corner of cell (0, 0), x along the width); a cell is the map's confidence scaled to
  0 (the model's threshold or below) ... 100 (the map's best), -1 where no pose was tried. It is a picture
  of where the model is confident, not occupancy: it is no costmap for Nav2's planners.
"""

from __future__ import annotations

import math

import numpy as np

from . import ros
from .messages import AffordanceMapMessage, NextViewsMessage, nanoseconds

PLACES = "geometry_msgs/msg/PoseArray"
VIEWS = "geometry_msgs/msg/PoseArray"
GOAL = "geometry_msgs/msg/PoseStamped"
MARKERS = "visualization_msgs/msg/MarkerArray"
CONFIDENCE = "nav_msgs/msg/OccupancyGrid"
NOT_TRIED = -1e30  # the map's confidence is float32's lowest (-3.4e38) where no pose was tried

ARROW_LENGTH = 0.4  # m: an arrow per place, pointing where a person at the place faces
TEXT_HEIGHT = 0.15  # m: the probability's letters, this far above the arrow


def type_hash(typename: str) -> str:
    """The RIHS01 hash of a ROS 2 type (Jazzy's definition), as rmw_zenoh writes it in its keys."""
    return ros.typestore().hash_rihs01(typename)


def _types():
    return ros.typestore().types


def _header(message: AffordanceMapMessage | NextViewsMessage, frame_id: str):
    """Stamped with the time of the cloud the map answers (the data's time, as a ROS driver stamps)."""
    t = _types()
    stamp = nanoseconds(message.cloud_timestamp)
    return t["std_msgs/msg/Header"](
        stamp=t["builtin_interfaces/msg/Time"](sec=stamp // 1_000_000_000, nanosec=stamp % 1_000_000_000),
        frame_id=frame_id,
    )


def yaw_quaternion(theta: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a turn by `theta` radians about z."""
    return 0.0, 0.0, math.sin(theta / 2), math.cos(theta / 2)


def _pose(x: float, y: float, z: float, theta: float):
    t = _types()
    qx, qy, qz, qw = yaw_quaternion(theta)
    return t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=float(z)),
        orientation=t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
    )


def pose_array(message: AffordanceMapMessage, frame_id: str) -> bytes:
    """The places, likeliest first (the map's order)."""
    poses = [_pose(s.x, s.y, s.z, s.theta) for s in message.skeletons]
    return ros.serialize(_types()[PLACES](header=_header(message, frame_id), poses=poses), PLACES)


def view_poses(message: NextViewsMessage, frame_id: str) -> bytes:
    """The next views, best first: each the camera's position (at its height) and heading."""
    poses = [_pose(v.pose.position.x, v.pose.position.y, v.pose.position.z, v.heading) for v in message.views]
    return ros.serialize(_types()[VIEWS](header=_header(message, frame_id), poses=poses), VIEWS)


def best_view_goal(message: NextViewsMessage, frame_id: str) -> bytes | None:
    """The best view as a goal for the base (on the floor, z = 0, facing the heading), ready for Nav2's
    navigate_to_pose; None without views."""
    if not message.views:
        return None
    best = message.views[0]
    pose = _pose(best.pose.position.x, best.pose.position.y, 0.0, best.heading)
    return ros.serialize(_types()[GOAL](header=_header(message, frame_id), pose=pose), GOAL)


def place_label(skeleton) -> str:
    """What RViz2 writes above a place: its probability, or its score for a model without a place model."""
    return f"p {skeleton.probability:.2f}" if skeleton.HasField("probability") else f"{skeleton.score:.2f}"


def marker_array(message: AffordanceMapMessage, frame_id: str, colour: tuple) -> bytes:
    """A DELETEALL first (a newer map with fewer places clears the old ones), then per place an arrow at its
    pose and its label above it, in the affordance's colour (r, g, b[, a], 0 ... 1); with no place, a text
    "<affordance>: no place found" over the middle of the grid, so that "none" is said, not just not drawn."""
    t = _types()
    marker_type = t["visualization_msgs/msg/Marker"]
    header = _header(message, frame_id)
    r, g, b = (float(c) for c in colour[:3])
    rgba = t["std_msgs/msg/ColorRGBA"](r=r, g=g, b=b, a=1.0)
    vector = t["geometry_msgs/msg/Vector3"]

    def marker(kind: int, marker_id: int, pose, scale, text: str = "", action: int = 0):
        return marker_type(
            header=header,
            ns=message.affordance,
            id=marker_id,
            type=kind,
            action=action,
            pose=pose,
            scale=scale,
            color=rgba,
            lifetime=t["builtin_interfaces/msg/Duration"](sec=0, nanosec=0),  # until replaced
            frame_locked=False,
            points=[],
            colors=[],
            texture_resource="",
            texture=t["sensor_msgs/msg/CompressedImage"](
                header=header, format="", data=np.zeros(0, np.uint8)
            ),
            uv_coordinates=[],
            text=text,
            mesh_resource="",
            mesh_file=t["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, np.uint8)),
            mesh_use_embedded_materials=False,
        )

    markers = [marker(0, 0, _pose(0, 0, 0, 0), vector(x=0.0, y=0.0, z=0.0), action=marker_type.DELETEALL)]
    for k, skeleton in enumerate(message.skeletons):
        arrow = vector(x=ARROW_LENGTH, y=0.08, z=0.08)
        markers.append(
            marker(marker_type.ARROW, 2 * k, _pose(skeleton.x, skeleton.y, skeleton.z, skeleton.theta), arrow)
        )
        above = _pose(skeleton.x, skeleton.y, skeleton.z + TEXT_HEIGHT + 0.1, 0.0)
        text = vector(x=0.0, y=0.0, z=TEXT_HEIGHT)
        markers.append(marker(marker_type.TEXT_VIEW_FACING, 2 * k + 1, above, text, place_label(skeleton)))
    if not message.skeletons:
        spec = message.grid
        step = spec.step if math.isfinite(spec.step) else 0.0
        middle = _pose(spec.x0 + step * (spec.nx - 1) / 2, spec.y0 + step * (spec.ny - 1) / 2, 1.0, 0.0)
        text = vector(x=0.0, y=0.0, z=2 * TEXT_HEIGHT)
        markers.append(
            marker(marker_type.TEXT_VIEW_FACING, 1, middle, text, f"{message.affordance}: no place found")
        )
    return ros.serialize(t[MARKERS](markers=markers), MARKERS)


def confidence_cells(message: AffordanceMapMessage) -> np.ndarray:
    """The map's confidence as OccupancyGrid data (int8, row-major with x along a row): 0 at the model's
    threshold or below, 100 at the map's best, linear between; -1 where no pose was tried."""
    spec = message.grid
    confidence = np.frombuffer(message.confidence, dtype="<f4").astype(np.float64)
    if confidence.size != spec.nx * spec.ny:
        raise ValueError(f"a map of {confidence.size} confidence cells on a {spec.nx} x {spec.ny} grid")
    confidence = confidence.reshape(spec.nx, spec.ny).T  # (y, x): an OccupancyGrid's rows run along y
    tried = np.isfinite(confidence) & (confidence > NOT_TRIED)
    best = float(confidence[tried].max()) if tried.any() else message.threshold
    span = best - message.threshold
    if span > 0:
        scaled = np.clip(np.round((confidence - message.threshold) / span * 100), 0, 100)
    else:  # nothing above the threshold: every tried cell is at the bottom
        scaled = np.zeros_like(confidence)
    return np.where(tried, scaled, -1).astype(np.int8).ravel()


def occupancy_grid(message: AffordanceMapMessage, frame_id: str) -> bytes:
    """The confidence map as a nav_msgs/msg/OccupancyGrid (see the module's conventions)."""
    t = _types()
    spec = message.grid
    # a grid of a single position has no step (NaN): give its one cell a nominal 10 cm
    step = spec.step if math.isfinite(spec.step) and spec.step > 0 else 0.1
    header = _header(message, frame_id)
    info = t["nav_msgs/msg/MapMetaData"](
        map_load_time=header.stamp,
        resolution=float(step),
        width=int(spec.nx),
        height=int(spec.ny),
        origin=_pose(spec.x0 - step / 2, spec.y0 - step / 2, 0.0, 0.0),  # x0, y0 are cell centres
    )
    grid = t[CONFIDENCE](header=header, info=info, data=confidence_cells(message))
    return ros.serialize(grid, CONFIDENCE)
