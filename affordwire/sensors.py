"""Sensor messages to the assembler's frames: one decoder per message type, registered under the schema name
its zenoh encoding carries. The assembler takes whatever this registry decodes; a new sensor type is one
decoder here (and its tests)."""

from __future__ import annotations

from collections.abc import Callable

from affordcore.assembly.assembler import SensorFrame
from affordcore.settings import LimitSettings

from . import messages


def _common(message, limits: LimitSettings) -> dict:
    """What every sensor message may carry besides its data: frame, time, IMU gravity and a pose guess."""
    return {
        "frame_id": message.frame_id or "sensor",
        "stamp": messages.checked_seconds(message.timestamp, limits),
        "gravity": messages.gravity_of(message),
        "pose_guess": messages.pose_matrix(message.pose_guess) if message.HasField("pose_guess") else None,
    }


def scan_frame(payload: bytes, limits: LimitSettings) -> SensorFrame:
    """An afford.v1.Scan: packed points in the sensor frame."""
    message = messages.parse(messages.Scan, payload)
    points, _ = messages.unpack_points(message, limits.max_points)
    return SensorFrame(points=points, **_common(message, limits))


def depth_frame(payload: bytes, limits: LimitSettings) -> SensorFrame:
    """An afford.v1.DepthFrame: a 16-bit depth image and its pinhole intrinsics."""
    message = messages.parse(messages.DepthFrame, payload)
    return SensorFrame(depth=messages.depth_image(message, limits), **_common(message, limits))


SENSOR_DECODERS: dict[str, Callable[[bytes, LimitSettings], SensorFrame]] = {
    messages.schema_name(messages.Scan): scan_frame,
    messages.schema_name(messages.DepthFrame): depth_frame,
}


def decode_sensor(schema: str, payload: bytes, limits: LimitSettings | None = None) -> SensorFrame:
    """The frame a sensor message holds, by the schema its encoding names, checked against `limits`;
    `MessageError` when no decoder knows it or the message is unusable."""
    decoder = SENSOR_DECODERS.get(schema)
    if decoder is None:
        raise messages.MessageError(
            f"expected encoding application/protobuf with schema {' or '.join(SENSOR_DECODERS)}, "
            f"got schema {schema or 'none'!r}"
        )
    return decoder(payload, limits or LimitSettings())
