"""How far the assembler's trajectory strays from the truth, with and without the robot's odometry.

For the real 7-Scenes kitchen (no odometry: hand-held) and generated rooms of `afford synth --sequences`
(whose frames carry wheel odometry that drifts with the distance gone), every --step-th frame goes through
the assembler in this process, every frame taken, and the trajectory is compared with the true poses (mean
and worst position error, anchored at the first frame; final rotation error): the odometry alone, the
assembler started from the odometry's motion (as `afford publish` sends it), and the assembler without it
(KISS-ICP's constant-velocity guess), with its median time a frame. `--against KEY=VALUE,...` runs the
assembler a second time with those AFFORD_ASSEMBLER__ settings, side by side.

    .venv/bin/python benchmarks/bench_odometry.py                # kitchen + 3 generated rooms, ~3 min
    .venv/bin/python benchmarks/bench_odometry.py --against INITIAL_THRESHOLD=2.0,MIN_MOTION=0.1
    .venv/bin/python benchmarks/bench_odometry.py --generated 2 --slip turn --against ODOMETRY_PRIOR=0

`--slip translate|turn`: from the 30th frame taken on, the odometry is off by a wheel slip, 10 cm along the
sensor's x or 5 degrees about its y (the camera's down axis: mostly a turn of heading), as a robot's
odometry is after its wheels slip.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_live import add_source_arguments, sources  # noqa: E402

from affordcore.assembly.assembler import Assembler, SensorFrame, trajectory_errors  # noqa: E402
from affordcore.assembly.depth import DepthImage  # noqa: E402
from affordcore.assembly.sequence import read_sequence  # noqa: E402
from affordcore.settings import AssemblerSettings  # noqa: E402

SLIP_FROM = 30  # frames taken before the slip


def slip(kind: str) -> np.ndarray:
    """The odometry's error after a slip: 10 cm along the sensor's x, or 5 degrees about its y (down)."""
    from scipy.spatial.transform import Rotation

    error = np.eye(4)
    if kind == "translate":
        error[0, 3] = 0.1
    elif kind == "turn":
        error[:3, :3] = Rotation.from_euler("y", 5, degrees=True).as_matrix()
    return error


def assembled(
    sequence,
    indices: list[int],
    settings: AssemblerSettings,
    odometry: bool,
    slipped: np.ndarray | None = None,
):
    """The assembler's poses (odom_from_sensor) of the frames, every one taken, and its median ms a frame
    (back-projection, registration and map, as `Assembler.add` does them; the image read from disk before).
    `slipped`: the odometry's error from the `SLIP_FROM`-th frame on."""
    assembler, seconds = Assembler(settings), []
    for taken, index in enumerate(indices):
        stamp = 1.0 + index / 30
        guess = sequence.odometry(index) if odometry else None
        if guess is not None and slipped is not None and taken >= SLIP_FROM:
            guess = guess @ slipped
        depth = DepthImage(sequence.depth(index), sequence.intrinsics, 0.001, 65535)
        frame = SensorFrame("camera", stamp, depth=depth, gravity=sequence.gravity(index), pose_guess=guess)
        start = time.perf_counter()
        assembler.add(frame, stamp)
        seconds.append(time.perf_counter() - start)
    return list(assembler.trajectory.poses), 1000 * float(np.median(seconds))


def row(
    name: str, how: str, poses: list[np.ndarray], truth: list[np.ndarray], ms: float | None = None
) -> str:
    errors, cost = trajectory_errors(poses, truth), "-" if ms is None else f"{ms:.0f}"
    return (
        f"| {name} | {how} | {100 * errors['mean_m']:.1f} / {100 * errors['worst_m']:.1f} "
        f"| {errors['final_rotation_deg']:.1f} | {errors['path_m']:.2f} | {cost} |"
    )


def against_settings(against: str) -> dict:
    """`KEY=VALUE,...` of AFFORD_ASSEMBLER__ settings (the prefix optional) as AssemblerSettings fields."""
    return {
        k.lower().removeprefix("afford_assembler__"): float(v)
        for k, v in (p.split("=", 1) for p in against.split(",") if p)
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    add_source_arguments(parser)
    parser.add_argument("--against", default="", help="AFFORD_ASSEMBLER__ settings: KEY=VALUE,...")
    parser.add_argument(
        "--slip", choices=["translate", "turn"], help="the odometry slips after the 30th frame taken"
    )
    args = parser.parse_args()
    slipped = slip(args.slip) if args.slip else None
    against = against_settings(args.against)
    variants = [("defaults", AssemblerSettings())]
    if against:
        variants.append((args.against, AssemblerSettings(**against)))
    slipping = f"; the odometry slips ({args.slip}) after the {SLIP_FROM}th frame" if args.slip else ""
    print(f"Every {args.step}th frame, every frame taken, {os.cpu_count()} cores{slipping}\n")
    print(
        "| source | trajectory | position error mean / worst (cm) | final rotation (deg) | path (m) "
        "| ms a frame (median) |"
    )
    print("|---|---|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as tmp:
        for source in sources(args, Path(tmp) / "generated"):
            sequence = read_sequence(source.sequence)
            indices = list(range(0, len(sequence.frames), args.step))
            truth = [sequence.pose(i) for i in indices]
            if sequence.has_odometry():
                first = np.linalg.inv(sequence.odometry(indices[0]))
                alone = [first @ sequence.odometry(i) for i in indices]
                if slipped is not None:
                    alone = alone[:SLIP_FROM] + [pose @ slipped for pose in alone[SLIP_FROM:]]
                print(row(source.name, "odometry alone", alone, truth), flush=True)
            for label, settings in variants:
                runs = [True, False] if sequence.has_odometry() else [False]
                for odometry in runs:
                    how = f"assembler ({label}), {'from the odometry' if odometry else 'no odometry'}"
                    poses, ms = assembled(sequence, indices, settings, odometry, slipped)
                    print(row(source.name, how, poses, truth, ms), flush=True)


if __name__ == "__main__":
    main()
