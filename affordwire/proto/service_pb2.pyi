import datetime

from google.protobuf import timestamp_pb2 as _timestamp_pb2
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class Status(_message.Message):
    __slots__ = ("timestamp", "service", "robot", "state", "detail", "accepted", "rejected", "published", "last_seconds", "version", "skipped", "dropped", "newest_input", "no_output", "last_reset", "refused_on_arrival")
    class State(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        UNKNOWN: _ClassVar[Status.State]
        STARTING: _ClassVar[Status.State]
        READY: _ClassVar[Status.State]
        BUSY: _ClassVar[Status.State]
        STOPPING: _ClassVar[Status.State]
    UNKNOWN: Status.State
    STARTING: Status.State
    READY: Status.State
    BUSY: Status.State
    STOPPING: Status.State
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    SERVICE_FIELD_NUMBER: _ClassVar[int]
    ROBOT_FIELD_NUMBER: _ClassVar[int]
    STATE_FIELD_NUMBER: _ClassVar[int]
    DETAIL_FIELD_NUMBER: _ClassVar[int]
    ACCEPTED_FIELD_NUMBER: _ClassVar[int]
    REJECTED_FIELD_NUMBER: _ClassVar[int]
    PUBLISHED_FIELD_NUMBER: _ClassVar[int]
    LAST_SECONDS_FIELD_NUMBER: _ClassVar[int]
    VERSION_FIELD_NUMBER: _ClassVar[int]
    SKIPPED_FIELD_NUMBER: _ClassVar[int]
    DROPPED_FIELD_NUMBER: _ClassVar[int]
    NEWEST_INPUT_FIELD_NUMBER: _ClassVar[int]
    NO_OUTPUT_FIELD_NUMBER: _ClassVar[int]
    LAST_RESET_FIELD_NUMBER: _ClassVar[int]
    REFUSED_ON_ARRIVAL_FIELD_NUMBER: _ClassVar[int]
    timestamp: _timestamp_pb2.Timestamp
    service: str
    robot: str
    state: Status.State
    detail: str
    accepted: int
    rejected: int
    published: int
    last_seconds: float
    version: str
    skipped: int
    dropped: int
    newest_input: _timestamp_pb2.Timestamp
    no_output: str
    last_reset: _timestamp_pb2.Timestamp
    refused_on_arrival: int
    def __init__(self, timestamp: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., service: _Optional[str] = ..., robot: _Optional[str] = ..., state: _Optional[_Union[Status.State, str]] = ..., detail: _Optional[str] = ..., accepted: _Optional[int] = ..., rejected: _Optional[int] = ..., published: _Optional[int] = ..., last_seconds: _Optional[float] = ..., version: _Optional[str] = ..., skipped: _Optional[int] = ..., dropped: _Optional[int] = ..., newest_input: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., no_output: _Optional[str] = ..., last_reset: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., refused_on_arrival: _Optional[int] = ...) -> None: ...

class Error(_message.Message):
    __slots__ = ("timestamp", "service", "key", "encoding", "payload_bytes", "reason", "input_timestamp", "input_source", "input_scans")
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    SERVICE_FIELD_NUMBER: _ClassVar[int]
    KEY_FIELD_NUMBER: _ClassVar[int]
    ENCODING_FIELD_NUMBER: _ClassVar[int]
    PAYLOAD_BYTES_FIELD_NUMBER: _ClassVar[int]
    REASON_FIELD_NUMBER: _ClassVar[int]
    INPUT_TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    INPUT_SOURCE_FIELD_NUMBER: _ClassVar[int]
    INPUT_SCANS_FIELD_NUMBER: _ClassVar[int]
    timestamp: _timestamp_pb2.Timestamp
    service: str
    key: str
    encoding: str
    payload_bytes: int
    reason: str
    input_timestamp: _timestamp_pb2.Timestamp
    input_source: str
    input_scans: int
    def __init__(self, timestamp: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., service: _Optional[str] = ..., key: _Optional[str] = ..., encoding: _Optional[str] = ..., payload_bytes: _Optional[int] = ..., reason: _Optional[str] = ..., input_timestamp: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., input_source: _Optional[str] = ..., input_scans: _Optional[int] = ...) -> None: ...

class Reset(_message.Message):
    __slots__ = ("timestamp", "operator", "reason")
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    OPERATOR_FIELD_NUMBER: _ClassVar[int]
    REASON_FIELD_NUMBER: _ClassVar[int]
    timestamp: _timestamp_pb2.Timestamp
    operator: str
    reason: str
    def __init__(self, timestamp: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., operator: _Optional[str] = ..., reason: _Optional[str] = ...) -> None: ...
