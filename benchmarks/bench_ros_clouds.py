"""Dense ROS 2 clouds at a robot's rate: full-resolution sensor_msgs/PointCloud2 with Imu, on
rmw_zenoh keys, through the router and the three services, idle and with a CPU hog on each core.

The real 7-Scenes kitchen (../shared/data/sequences), --frames of its frames every --step-th (40 of every
3rd by default, as the depth-image runs), each depth image back-projected at every pixel (640 x 480: about
277,000 points with a measurement) into an unorganised PointCloud2 of float32 x, y, z (12 bytes a point,
3.3 MB), with the Imu a level IMU on the camera reads (the true gravity of the frame), published at --rate
Hz (8) as a robot's driver would: the Imu just before its cloud, BLOCK congestion control.

Two tables:

* through the services (`services.launch.Stack` with AFFORD_ROS__POINTS / AFFORD_ROS__IMU): clouds taken
  (poses the assembler published) of those sent, the assembler's decoded-cloud count, the trajectory error
  of the poses taken against the ground truth (anchored at the first), median over --repeats;
* in this process, per frame (the frames in order, as the service meets them, with the same CPU hogs):
  the decode (`affordwire.ros.pointcloud2` on the CDR bytes: deserialise, x/y/z to float64, drop NaN) of
  the whole cloud (as the service did before) and thinned as it is read to AFFORD_ASSEMBLER__MAX_FRAME_POINTS
  (as it does now: the same points the assembler kept of the whole), `Assembler.add` calm and busy (scans
  waiting: `busy_registration_voxels`) on those, and the thinned decode plus a calm frame: median / 90th
  percentile in ms. The budget at 8 Hz is 125 ms a frame.

    .venv/bin/python benchmarks/bench_ros_clouds.py               # about 5 minutes on 2 cores
    .venv/bin/python benchmarks/bench_ros_clouds.py --loads 2 --repeats 1
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from affordcore.assembly.assembler import Assembler, SensorFrame, trajectory_errors  # noqa: E402
from affordcore.assembly.depth import DepthImage, back_project  # noqa: E402
from affordcore.assembly.sequence import INVALID_DEPTH, read_sequence  # noqa: E402
from affordcore.settings import AssemblerSettings  # noqa: E402
from affordwire import messages, ros  # noqa: E402
from services.launch import Stack, cpu_hogs  # noqa: E402
from services.ros import dds_type  # noqa: E402
from services.transport import Keys, schema_of  # noqa: E402

KITCHEN = ROOT.parent / "shared" / "data" / "sequences" / "7scenes_redkitchen_frames_000000-000299"
POINTS, IMU = "/robot1/camera/points", "/robot1/imu"


def rmw_zenoh_key(topic: str, typename: str) -> str:
    """The key rmw_zenoh publishes a topic on (domain 0), with the type's RIHS01 hash."""
    return f"0/{topic.strip('/')}/{dds_type(typename)}/{ros.typestore().hash_rihs01(typename)}"


def ros_frames(indices: list[int]) -> tuple[list[tuple[float, bytes, bytes]], list[np.ndarray]]:
    """(stamp offset, PointCloud2 CDR, Imu CDR) per frame, stamped 1 / 30 s apart as the camera took them,
    and the true poses."""
    sequence = read_sequence(KITCHEN)
    types = ros.typestore().types
    field = types["sensor_msgs/msg/PointField"]
    frames, truth = [], []
    for k, index in enumerate(indices):
        image = DepthImage(sequence.depth(index), sequence.intrinsics, invalid_value=INVALID_DEPTH)
        points = back_project(image, pixel_step=1).astype(np.float32)  # every measured pixel
        stamp = k * 3 / 30.0

        def header(stamp=stamp):
            sec = 1_700_000_000 + int(stamp)
            time_ = types["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((stamp % 1) * 1e9)))
            return types["std_msgs/msg/Header"](stamp=time_, frame_id="camera_depth_optical_frame")

        cloud = types[ros.POINTCLOUD2](
            header=header(),
            height=1,
            width=len(points),
            fields=[
                field(name=n, offset=4 * i, datatype=field.FLOAT32, count=1) for i, n in enumerate("xyz")
            ],
            is_bigendian=False,
            point_step=12,
            row_step=12 * len(points),
            data=np.frombuffer(points.tobytes(), dtype=np.uint8),
            is_dense=True,
        )
        up = -ros.STANDARD_GRAVITY * sequence.gravity(index)  # the specific force at rest points up
        vector = types["geometry_msgs/msg/Vector3"]
        quaternion = types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
        imu = types[ros.IMU](
            header=header(),
            orientation=quaternion,
            orientation_covariance=np.full(9, -1.0),
            angular_velocity=vector(x=0.0, y=0.0, z=0.0),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=vector(x=up[0], y=up[1], z=up[2]),
            linear_acceleration_covariance=np.zeros(9),
        )
        frames.append((stamp, ros.serialize(cloud, ros.POINTCLOUD2), ros.serialize(imu, ros.IMU)))
        truth.append(sequence.pose(index))
    return frames, truth


def depth_messages(indices: list[int]) -> list:
    """The same frames as afford.v1.DepthFrame messages (what `afford publish` sends of a depth sequence,
    gravity included), stamped as `ros_frames` stamps them."""
    from services.clients import sequence_messages

    framed = []
    for k, (_, message) in enumerate(sequence_messages(read_sequence(KITCHEN), indices)):
        messages.stamp(message.timestamp, 1_700_000_000 + k * 3 / 30.0)
        framed.append((k, message))
    return framed


def through_services(frames, truth, rate: float, hogs: int, folder: Path, depth=None) -> dict:
    """Clouds taken by the services at `rate` Hz with `hogs` CPU hogs: poses published, clouds decoded,
    trajectory error (cm) of the poses taken. With `depth` (`depth_messages`), those are published instead,
    as depth images on the scan key: the same frames, stamps and rate."""
    from services.clients import publish_sequence

    env = {"AFFORD_ROS__POINTS": POINTS, "AFFORD_ROS__IMU": IMU}
    poses: dict[float, np.ndarray] = {}
    lock = threading.Lock()
    with cpu_hogs(hogs), Stack(folder, env=env) as stack:
        keys = Keys(stack.robot)
        session = stack.session()

        def on_pose(sample) -> None:
            if schema_of(sample) == messages.schema_name(messages.Pose):
                pose = messages.parse(messages.Pose, sample.payload.to_bytes())
                with lock:
                    stamp = round(messages.seconds(pose.timestamp) - 1_700_000_000, 3)  # to 1 ms: a float
                    poses[stamp] = messages.pose_matrix(pose)

        subscriber = session.declare_subscriber(keys.pose, on_pose)
        if depth is not None:
            publish_sequence(session, keys, depth, "camera", rate, wait=30)
        else:
            _publish_ros(session, frames, rate, stack)
        # the last frame's pose, if it is taken, within a few seconds; then the count settles
        settle = time.monotonic() + 10
        while time.monotonic() < settle and round(frames[-1][0], 3) not in _stamps(poses, lock):
            time.sleep(0.1)
        time.sleep(1.0)
        subscriber.undeclare()
        session.close()
    log = (folder / "assembler.log").read_text()
    decoded = next((line for line in log.splitlines() if "clouds decoded" in line), "")
    taken = sorted(_stamps(poses, lock))
    by_stamp = {round(stamp, 3): k for k, (stamp, _, _) in enumerate(frames)}
    order = [by_stamp[round(stamp, 3)] for stamp in taken if round(stamp, 3) in by_stamp]
    errors = trajectory_errors([poses[s] for s in taken], [truth[k] for k in order]) if order else None
    decoded = "-" if depth is not None else decoded.split("ROS 2: ")[-1].split(" clouds")[0]
    return {"taken": len(order), "decoded": decoded, "errors": errors}


def _publish_ros(session, frames, rate: float, stack: Stack) -> None:
    """The clouds and Imu readings as a ROS 2 driver on rmw_zenoh publishes them, at `rate` Hz (the
    Imu just before its cloud; BLOCK, as zenoh's default DROP loses samples under load)."""
    import zenoh

    block = zenoh.CongestionControl.BLOCK
    points = session.declare_publisher(rmw_zenoh_key(POINTS, ros.POINTCLOUD2), congestion_control=block)
    imu = session.declare_publisher(rmw_zenoh_key(IMU, ros.IMU), congestion_control=block)
    deadline = time.monotonic() + 30
    while not (points.matching_status.matching and imu.matching_status.matching):
        if time.monotonic() > deadline:
            raise SystemExit(f"the assembler never subscribed to {POINTS}:\n{stack.logs()[-3000:]}")
        time.sleep(0.05)
    began = time.monotonic()
    for k, (_, cloud, reading) in enumerate(frames):
        imu.put(reading)
        points.put(cloud)
        time.sleep(max(0.0, began + (k + 1) / rate - time.monotonic()))
    points.undeclare()
    imu.undeclare()


def _stamps(poses: dict, lock: threading.Lock) -> list[float]:
    with lock:
        return list(poses)


def in_process(frames, hogs: int) -> dict[str, list[float]]:
    """ms per frame of the decode (the whole cloud, as before, and thinned as it is read, as the service
    does now) and of Assembler.add (calm, busy), the frames in order."""
    import kiss_icp.kiss_icp  # noqa: F401  (import cost is nobody's frame time)

    keep = AssemblerSettings().max_frame_points
    times: dict[str, list[float]] = {"decode whole": [], "decode thinned": [], "calm": [], "busy": []}
    assemblers = {"calm": Assembler(AssemblerSettings()), "busy": Assembler(AssemblerSettings())}
    with cpu_hogs(hogs):
        for stamp, cloud, reading in frames:
            start = time.perf_counter()
            ros.pointcloud2(cloud)
            times["decode whole"].append(1000 * (time.perf_counter() - start))
            start = time.perf_counter()
            decoded = ros.pointcloud2(cloud, keep=keep)
            times["decode thinned"].append(1000 * (time.perf_counter() - start))
            down = ros.imu(reading).down
            for name, assembler in assemblers.items():
                frame = SensorFrame("camera", stamp, decoded.points, gravity=down)
                start = time.perf_counter()
                assembler.add(frame, stamp, busy=name == "busy")
                times[name].append(1000 * (time.perf_counter() - start))
    times["decode + calm"] = [a + b for a, b in zip(times["decode thinned"], times["calm"], strict=True)]
    return times


def _taken_cells(runs: list[dict], sent: int) -> str:
    taken = [r["taken"] for r in runs]
    errors = sorted(runs, key=lambda r: r["taken"])[len(runs) // 2]["errors"]
    error = "-" if errors is None else f"{errors['mean_m'] * 100:.1f} / {errors['worst_m'] * 100:.1f}"
    decoded = ", ".join(r["decoded"] for r in runs)
    return f"{statistics.median(taken):.0f} / {sent} ({', '.join(map(str, taken))}) | {decoded} | {error} |"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--step", type=int, default=3, help="every n-th frame of the kitchen")
    parser.add_argument("--rate", type=float, default=8.0, help="clouds a second")
    parser.add_argument(
        "--loads", default=f"0,{os.cpu_count()}", help="CPU hogs beside the services, per run"
    )
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    indices = list(range(0, args.frames * args.step, args.step))
    frames, truth = ros_frames(indices)
    sizes = [len(cloud) for _, cloud, _ in frames]
    points = [(len(cloud) - 100) // 12 for _, cloud, _ in frames]
    print(
        f"{os.cpu_count()} cores; {len(frames)} kitchen frames (every {args.step}th), PointCloud2 of "
        f"{statistics.median(points):,.0f} points ({statistics.median(sizes) / 1e6:.1f} MB) median, "
        f"at {args.rate:g} Hz; {AssemblerSettings().max_frame_points:,} points a frame kept "
        "(AFFORD_ASSEMBLER__MAX_FRAME_POINTS)\n"
    )
    loads = [int(v) for v in args.loads.split(",")]
    depth = depth_messages(indices)
    print(
        "| input | hogs | frames taken (median; runs) | clouds decoded | trajectory error cm, mean / worst |"
    )
    print("|---|---:|---:|---|---:|", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        for hogs in loads:
            runs: dict[str, list[dict]] = {"PointCloud2": [], "depth image": []}
            for r in range(args.repeats):  # the two inputs alternated, so a noisy machine slows both alike
                for kind, runs_of in runs.items():
                    folder = Path(tmp) / f"{kind[0]}-{hogs}-{r}"
                    given = depth if kind == "depth image" else None
                    runs_of.append(through_services(frames, truth, args.rate, hogs, folder, given))
            for kind, runs_of in runs.items():
                print(f"| {kind} | {hogs} | " + _taken_cells(runs_of, len(frames)), flush=True)
    print("\nIn this process, ms a frame, median / p90 (8 Hz leaves 125 ms):\n")
    print("| CPU hogs | decode whole | decode thinned | add, calm | add, busy | thinned + calm |")
    print("|---:|---:|---:|---:|---:|---:|")
    for hogs in loads:
        times = in_process(frames, hogs)
        cells = [f"{np.median(v):.0f} / {np.percentile(v, 90):.0f}" for v in times.values()]
        print(f"| {hogs} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
