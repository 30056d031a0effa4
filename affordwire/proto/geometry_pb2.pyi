import datetime

from google.protobuf import timestamp_pb2 as _timestamp_pb2
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class Vector3(_message.Message):
    __slots__ = ("x", "y", "z")
    X_FIELD_NUMBER: _ClassVar[int]
    Y_FIELD_NUMBER: _ClassVar[int]
    Z_FIELD_NUMBER: _ClassVar[int]
    x: float
    y: float
    z: float
    def __init__(self, x: _Optional[float] = ..., y: _Optional[float] = ..., z: _Optional[float] = ...) -> None: ...

class Quaternion(_message.Message):
    __slots__ = ("x", "y", "z", "w")
    X_FIELD_NUMBER: _ClassVar[int]
    Y_FIELD_NUMBER: _ClassVar[int]
    Z_FIELD_NUMBER: _ClassVar[int]
    W_FIELD_NUMBER: _ClassVar[int]
    x: float
    y: float
    z: float
    w: float
    def __init__(self, x: _Optional[float] = ..., y: _Optional[float] = ..., z: _Optional[float] = ..., w: _Optional[float] = ...) -> None: ...

class Pose(_message.Message):
    __slots__ = ("timestamp", "frame_id", "child_frame_id", "position", "orientation")
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    CHILD_FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    POSITION_FIELD_NUMBER: _ClassVar[int]
    ORIENTATION_FIELD_NUMBER: _ClassVar[int]
    timestamp: _timestamp_pb2.Timestamp
    frame_id: str
    child_frame_id: str
    position: Vector3
    orientation: Quaternion
    def __init__(self, timestamp: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., frame_id: _Optional[str] = ..., child_frame_id: _Optional[str] = ..., position: _Optional[_Union[Vector3, _Mapping]] = ..., orientation: _Optional[_Union[Quaternion, _Mapping]] = ...) -> None: ...

class PackedElementField(_message.Message):
    __slots__ = ("name", "offset", "type")
    class NumericType(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        UNKNOWN: _ClassVar[PackedElementField.NumericType]
        UINT8: _ClassVar[PackedElementField.NumericType]
        INT8: _ClassVar[PackedElementField.NumericType]
        UINT16: _ClassVar[PackedElementField.NumericType]
        INT16: _ClassVar[PackedElementField.NumericType]
        UINT32: _ClassVar[PackedElementField.NumericType]
        INT32: _ClassVar[PackedElementField.NumericType]
        FLOAT32: _ClassVar[PackedElementField.NumericType]
        FLOAT64: _ClassVar[PackedElementField.NumericType]
    UNKNOWN: PackedElementField.NumericType
    UINT8: PackedElementField.NumericType
    INT8: PackedElementField.NumericType
    UINT16: PackedElementField.NumericType
    INT16: PackedElementField.NumericType
    UINT32: PackedElementField.NumericType
    INT32: PackedElementField.NumericType
    FLOAT32: PackedElementField.NumericType
    FLOAT64: PackedElementField.NumericType
    NAME_FIELD_NUMBER: _ClassVar[int]
    OFFSET_FIELD_NUMBER: _ClassVar[int]
    TYPE_FIELD_NUMBER: _ClassVar[int]
    name: str
    offset: int
    type: PackedElementField.NumericType
    def __init__(self, name: _Optional[str] = ..., offset: _Optional[int] = ..., type: _Optional[_Union[PackedElementField.NumericType, str]] = ...) -> None: ...
