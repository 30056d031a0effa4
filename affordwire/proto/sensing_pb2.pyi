import datetime

from . import geometry_pb2 as _geometry_pb2
from google.protobuf import timestamp_pb2 as _timestamp_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class Scan(_message.Message):
    __slots__ = ("timestamp", "frame_id", "fields", "point_stride", "data", "pose_guess", "gravity")
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    FIELDS_FIELD_NUMBER: _ClassVar[int]
    POINT_STRIDE_FIELD_NUMBER: _ClassVar[int]
    DATA_FIELD_NUMBER: _ClassVar[int]
    POSE_GUESS_FIELD_NUMBER: _ClassVar[int]
    GRAVITY_FIELD_NUMBER: _ClassVar[int]
    timestamp: _timestamp_pb2.Timestamp
    frame_id: str
    fields: _containers.RepeatedCompositeFieldContainer[_geometry_pb2.PackedElementField]
    point_stride: int
    data: bytes
    pose_guess: _geometry_pb2.Pose
    gravity: _geometry_pb2.Vector3
    def __init__(self, timestamp: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., frame_id: _Optional[str] = ..., fields: _Optional[_Iterable[_Union[_geometry_pb2.PackedElementField, _Mapping]]] = ..., point_stride: _Optional[int] = ..., data: _Optional[bytes] = ..., pose_guess: _Optional[_Union[_geometry_pb2.Pose, _Mapping]] = ..., gravity: _Optional[_Union[_geometry_pb2.Vector3, _Mapping]] = ...) -> None: ...

class CameraIntrinsics(_message.Message):
    __slots__ = ("fx", "fy", "cx", "cy")
    FX_FIELD_NUMBER: _ClassVar[int]
    FY_FIELD_NUMBER: _ClassVar[int]
    CX_FIELD_NUMBER: _ClassVar[int]
    CY_FIELD_NUMBER: _ClassVar[int]
    fx: float
    fy: float
    cx: float
    cy: float
    def __init__(self, fx: _Optional[float] = ..., fy: _Optional[float] = ..., cx: _Optional[float] = ..., cy: _Optional[float] = ...) -> None: ...

class DepthFrame(_message.Message):
    __slots__ = ("timestamp", "frame_id", "width", "height", "depth", "depth_scale", "invalid_value", "intrinsics", "pose_guess", "gravity")
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    DEPTH_FIELD_NUMBER: _ClassVar[int]
    DEPTH_SCALE_FIELD_NUMBER: _ClassVar[int]
    INVALID_VALUE_FIELD_NUMBER: _ClassVar[int]
    INTRINSICS_FIELD_NUMBER: _ClassVar[int]
    POSE_GUESS_FIELD_NUMBER: _ClassVar[int]
    GRAVITY_FIELD_NUMBER: _ClassVar[int]
    timestamp: _timestamp_pb2.Timestamp
    frame_id: str
    width: int
    height: int
    depth: bytes
    depth_scale: float
    invalid_value: int
    intrinsics: CameraIntrinsics
    pose_guess: _geometry_pb2.Pose
    gravity: _geometry_pb2.Vector3
    def __init__(self, timestamp: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., frame_id: _Optional[str] = ..., width: _Optional[int] = ..., height: _Optional[int] = ..., depth: _Optional[bytes] = ..., depth_scale: _Optional[float] = ..., invalid_value: _Optional[int] = ..., intrinsics: _Optional[_Union[CameraIntrinsics, _Mapping]] = ..., pose_guess: _Optional[_Union[_geometry_pb2.Pose, _Mapping]] = ..., gravity: _Optional[_Union[_geometry_pb2.Vector3, _Mapping]] = ...) -> None: ...
