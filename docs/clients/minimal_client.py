"""A complete affordmap client that needs only zenoh, protobuf, numpy and the code protoc generates from
schemas/ (docs/clients.md): it publishes a room's points on map/cloud, waits for the affordance maps that
answer that cloud, and prints each map's places.

    protoc -I schemas --python_out=gen schemas/afford/v1/*.proto   # or: python -m grpc_tools.protoc ...
    PYTHONPATH=gen python minimal_client.py room.ply --connect tcp/127.0.0.1:7447 --robot robot1

Without a file it builds a small room. The points go out in the frame --frame names ("map" unless told):
the features service levels them (finds the floor and the up direction) and every map says how in its
world_from_input. Exit status: 0 once a map of every expected affordance has arrived, 1 when a service
refused the cloud (the reason is printed), 3 on timeout.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

from afford.v1 import geometry_pb2, maps_pb2, service_pb2

SHIPPED = ["sitting-relaxing", "sitting-working", "standing-working"]  # one map per model the inference runs
PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4", "uint": "u4"}
PLY_TYPES |= {"int8": "i1", "uint8": "u1", "int16": "i2", "uint16": "u2", "int32": "i4", "uint32": "u4"}
PLY_TYPES |= {"float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def read_ply(path: Path) -> np.ndarray:
    """x, y, z of the vertices of a PLY file (ascii or binary; the vertex element must come first)."""
    with open(path, "rb") as file:
        if file.readline().strip() != b"ply":
            raise ValueError(f"{path} is not a PLY file")
        form, count, names, types, elements = "", 0, [], [], 0
        while (line := file.readline().decode("ascii").split()) != ["end_header"]:
            if not line and not file.peek(1):
                raise ValueError(f"{path}: the header has no end_header")
            if line[:1] == ["format"]:
                form = line[1]
            elif line[:1] == ["element"]:
                elements += 1
                if line[1] == "vertex" and elements == 1:
                    count = int(line[2])
            elif line[:1] == ["property"] and elements == 1:
                if line[1] == "list":
                    raise ValueError(f"{path}: list properties of vertices are not read here")
                types.append(PLY_TYPES[line[1]])
                names.append(line[2])
        if not count or not {"x", "y", "z"} <= set(names):
            raise ValueError(f"{path}: the first element must be vertices with x, y and z")
        if form == "ascii":
            columns = [names.index(axis) for axis in "xyz"]
            return np.loadtxt(file, usecols=columns, max_rows=count, ndmin=2)
        order = {"binary_little_endian": "<", "binary_big_endian": ">"}[form]
        dtype = np.dtype([(name, order + kind) for name, kind in zip(names, types)])
        vertices = np.frombuffer(file.read(dtype.itemsize * count), dtype=dtype, count=count)
        return np.column_stack([vertices[axis].astype(np.float64) for axis in "xyz"])


def read_points(path: Path) -> np.ndarray:
    """(n, 3) points of a PLY file, or of a text file of x y z lines (XYZ, PTS, TXT; more columns ignored)."""
    if path.suffix.lower() == ".ply":
        return read_ply(path)
    return np.loadtxt(path, usecols=(0, 1, 2), ndmin=2)


def built_room(rng: np.random.Generator) -> np.ndarray:
    """A 4 m x 3 m room, 2.5 m high, with a 0.75 m table: points on its surfaces, z up, floor at 0."""

    def patch(low, high, n):
        return low + rng.random((n, 3)) * (np.array(high) - np.array(low))

    return np.vstack(
        [
            patch([0, 0, 0], [4, 3, 0], 40_000),  # floor
            patch([0, 0, 0], [4, 0, 2.5], 20_000),  # four walls
            patch([0, 3, 0], [4, 3, 2.5], 20_000),
            patch([0, 0, 0], [0, 3, 2.5], 15_000),
            patch([4, 0, 0], [4, 3, 2.5], 15_000),
            patch([1.5, 1.0, 0.75], [2.7, 1.8, 0.75], 4_000),  # table top
        ]
    )


def cloud_message(points: np.ndarray, frame_id: str, source: str) -> maps_pb2.Cloud:
    """A Cloud of packed little-endian float32 x, y, z, stamped now (the stamp identifies it)."""
    cloud = maps_pb2.Cloud(frame_id=frame_id, source=source, point_stride=12)
    for offset, name in enumerate("xyz"):
        cloud.fields.add(name=name, offset=4 * offset, type=geometry_pb2.PackedElementField.FLOAT32)
    cloud.data = np.ascontiguousarray(points, dtype="<f4").tobytes()
    cloud.timestamp.GetCurrentTime()
    return cloud


def rotation(q: geometry_pb2.Quaternion) -> np.ndarray:
    """The rotation matrix of a unit quaternion; an unset one (all zero) is the identity."""
    x, y, z, w = (q.x, q.y, q.z, q.w) if (q.x, q.y, q.z, q.w) != (0, 0, 0, 0) else (0, 0, 0, 1)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def print_map(amap: maps_pb2.AffordanceMap, frame_id: str) -> None:
    """Each place: torso in the world frame and in the client's own frame (world_from_input inverted)."""
    pose = amap.world_from_input
    world_from_input = (
        rotation(pose.orientation),
        np.array([pose.position.x, pose.position.y, pose.position.z]),
    )
    print(f"{amap.affordance}: {len(amap.skeletons)} places (model {amap.model}, {amap.frames} frames)")
    for number, place in enumerate(amap.skeletons, 1):
        torso = np.array([place.x, place.y, place.z])
        mine = world_from_input[0].T @ (torso - world_from_input[1])  # input_from_world * torso
        head = np.array(place.joints[0:3])  # joint 0 is HEAD (the order is in maps.proto)
        print(
            f"  place {number}: score {place.score:.3f}, facing {np.degrees(place.theta):.0f} deg, "
            f"torso world ({torso[0]:.3f}, {torso[1]:.3f}, {torso[2]:.3f}), "
            f"{frame_id} ({mine[0]:.3f}, {mine[1]:.3f}, {mine[2]:.3f}), head at z {head[2]:.2f}"
        )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("points", nargs="?", type=Path, help="PLY or XYZ file (default: a built room)")
    parser.add_argument("--connect", action="append", default=[], help="router endpoint, e.g. tcp/HOST:7447")
    parser.add_argument("--robot", default="robot1")
    parser.add_argument("--frame", default="map", help='the points\' frame; "world" only if already levelled')
    parser.add_argument("--affordance", action="append", help="maps to wait for (default: the shipped three)")
    parser.add_argument("--timeout", type=float, default=300.0, help="seconds to wait for the maps")
    parser.add_argument("--zenoh-config", type=Path, help="a zenoh JSON5 config (TLS: docs/security.md)")
    args = parser.parse_args()
    expected = set(args.affordance or SHIPPED)

    points = read_points(args.points) if args.points else built_room(np.random.default_rng(0))
    cloud = cloud_message(points, args.frame, args.points.name if args.points else "minimal_client")
    print(f"{len(points):,} points in frame {args.frame!r}, cloud {cloud.timestamp.ToJsonString()}")

    config = zenoh.Config.from_file(str(args.zenoh_config)) if args.zenoh_config else zenoh.Config()
    config.insert_json5("mode", '"client"')  # through the router; it holds the site's access control
    if args.connect or not args.zenoh_config:
        config.insert_json5("connect/endpoints", json.dumps(args.connect or ["tcp/127.0.0.1:7447"]))
    config.insert_json5("scouting/multicast/enabled", "false")  # talk to the router named, nothing else

    prefix = f"afford/@v1/{args.robot}"
    maps: dict[str, maps_pb2.AffordanceMap] = {}
    refusals: list[service_pb2.Error] = []
    answered, lock = threading.Event(), threading.Lock()

    def on_map(sample: zenoh.Sample) -> None:
        if str(sample.encoding) != "application/protobuf;afford.v1.AffordanceMap":
            return
        amap = maps_pb2.AffordanceMap.FromString(sample.payload.to_bytes())
        if amap.cloud_timestamp == cloud.timestamp:  # a map of our cloud, not of an earlier one
            with lock:
                maps[amap.affordance] = amap
                if expected <= maps.keys():
                    answered.set()

    def on_error(sample: zenoh.Sample) -> None:
        if str(sample.encoding) != "application/protobuf;afford.v1.Error":
            return
        error = service_pb2.Error.FromString(sample.payload.to_bytes())
        if error.input_timestamp == cloud.timestamp and error.input_source == cloud.source:  # of our cloud
            refusals.append(error)
            answered.set()
        elif error.HasField("input_timestamp"):  # another client's input: shown, not our answer
            print(f"(another input refused, {error.input_source!r} on {error.key}: {error.reason})")

    deadline = time.monotonic() + args.timeout
    with zenoh.open(config) as session:
        subscribers = [  # declared before the cloud goes out, so no answer can be missed
            session.declare_subscriber(f"{prefix}/affordance/*", on_map),
            session.declare_subscriber(f"{prefix}/error/*", on_error),
        ]
        publisher = session.declare_publisher(
            f"{prefix}/map/cloud",
            encoding=zenoh.Encoding("application/protobuf;afford.v1.Cloud"),
            congestion_control=zenoh.CongestionControl.BLOCK,  # the default, DROP, loses big samples
        )
        while not publisher.matching_status.matching:  # a put before the features service listens is lost
            if time.monotonic() > deadline:
                print(f"timed out: nothing subscribes to {prefix}/map/cloud", file=sys.stderr)
                return 3
            time.sleep(0.1)
        publisher.put(cloud.SerializeToString())
        answered.wait(max(0.0, deadline - time.monotonic()))
        for declared in (*subscribers, publisher):
            declared.undeclare()
        with lock:
            got = dict(maps)

    if refusals:
        for error in refusals:
            print(f"refused by {error.service}: {error.reason}", file=sys.stderr)
        return 1
    for name in sorted(got):
        print_map(got[name], args.frame)
    missing = sorted(expected - got.keys())
    if missing:
        print(f"timed out after {args.timeout:g} s waiting for {', '.join(missing)}", file=sys.stderr)
        return 3
    return 0


if __name__ == "__main__":
    sys.exit(main())
