import datetime

from . import geometry_pb2 as _geometry_pb2
from google.protobuf import timestamp_pb2 as _timestamp_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class Cloud(_message.Message):
    __slots__ = ("timestamp", "frame_id", "fields", "point_stride", "data", "world_from_input", "frames", "source", "scans_received", "sensor_origins")
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    FIELDS_FIELD_NUMBER: _ClassVar[int]
    POINT_STRIDE_FIELD_NUMBER: _ClassVar[int]
    DATA_FIELD_NUMBER: _ClassVar[int]
    WORLD_FROM_INPUT_FIELD_NUMBER: _ClassVar[int]
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    SOURCE_FIELD_NUMBER: _ClassVar[int]
    SCANS_RECEIVED_FIELD_NUMBER: _ClassVar[int]
    SENSOR_ORIGINS_FIELD_NUMBER: _ClassVar[int]
    timestamp: _timestamp_pb2.Timestamp
    frame_id: str
    fields: _containers.RepeatedCompositeFieldContainer[_geometry_pb2.PackedElementField]
    point_stride: int
    data: bytes
    world_from_input: _geometry_pb2.Pose
    frames: int
    source: str
    scans_received: int
    sensor_origins: _containers.RepeatedCompositeFieldContainer[_geometry_pb2.Vector3]
    def __init__(self, timestamp: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., frame_id: _Optional[str] = ..., fields: _Optional[_Iterable[_Union[_geometry_pb2.PackedElementField, _Mapping]]] = ..., point_stride: _Optional[int] = ..., data: _Optional[bytes] = ..., world_from_input: _Optional[_Union[_geometry_pb2.Pose, _Mapping]] = ..., frames: _Optional[int] = ..., source: _Optional[str] = ..., scans_received: _Optional[int] = ..., sensor_origins: _Optional[_Iterable[_Union[_geometry_pb2.Vector3, _Mapping]]] = ...) -> None: ...

class VoxelGrid(_message.Message):
    __slots__ = ("origin", "resolution", "nx", "ny", "nz")
    ORIGIN_FIELD_NUMBER: _ClassVar[int]
    RESOLUTION_FIELD_NUMBER: _ClassVar[int]
    NX_FIELD_NUMBER: _ClassVar[int]
    NY_FIELD_NUMBER: _ClassVar[int]
    NZ_FIELD_NUMBER: _ClassVar[int]
    origin: _geometry_pb2.Vector3
    resolution: float
    nx: int
    ny: int
    nz: int
    def __init__(self, origin: _Optional[_Union[_geometry_pb2.Vector3, _Mapping]] = ..., resolution: _Optional[float] = ..., nx: _Optional[int] = ..., ny: _Optional[int] = ..., nz: _Optional[int] = ...) -> None: ...

class SceneFields(_message.Message):
    __slots__ = ("timestamp", "frame_id", "grid", "occupancy", "distance", "normals", "x_min", "y_min", "x_max", "y_max", "world_from_input", "cloud_timestamp", "frames", "steep_facing", "scans_received", "visibility", "soft_occupancy", "normal_estimator", "columns")
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    GRID_FIELD_NUMBER: _ClassVar[int]
    OCCUPANCY_FIELD_NUMBER: _ClassVar[int]
    DISTANCE_FIELD_NUMBER: _ClassVar[int]
    NORMALS_FIELD_NUMBER: _ClassVar[int]
    X_MIN_FIELD_NUMBER: _ClassVar[int]
    Y_MIN_FIELD_NUMBER: _ClassVar[int]
    X_MAX_FIELD_NUMBER: _ClassVar[int]
    Y_MAX_FIELD_NUMBER: _ClassVar[int]
    WORLD_FROM_INPUT_FIELD_NUMBER: _ClassVar[int]
    CLOUD_TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    STEEP_FACING_FIELD_NUMBER: _ClassVar[int]
    SCANS_RECEIVED_FIELD_NUMBER: _ClassVar[int]
    VISIBILITY_FIELD_NUMBER: _ClassVar[int]
    SOFT_OCCUPANCY_FIELD_NUMBER: _ClassVar[int]
    NORMAL_ESTIMATOR_FIELD_NUMBER: _ClassVar[int]
    COLUMNS_FIELD_NUMBER: _ClassVar[int]
    timestamp: _timestamp_pb2.Timestamp
    frame_id: str
    grid: VoxelGrid
    occupancy: bytes
    distance: bytes
    normals: bytes
    x_min: float
    y_min: float
    x_max: float
    y_max: float
    world_from_input: _geometry_pb2.Pose
    cloud_timestamp: _timestamp_pb2.Timestamp
    frames: int
    steep_facing: str
    scans_received: int
    visibility: bytes
    soft_occupancy: bytes
    normal_estimator: str
    columns: FineColumns
    def __init__(self, timestamp: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., frame_id: _Optional[str] = ..., grid: _Optional[_Union[VoxelGrid, _Mapping]] = ..., occupancy: _Optional[bytes] = ..., distance: _Optional[bytes] = ..., normals: _Optional[bytes] = ..., x_min: _Optional[float] = ..., y_min: _Optional[float] = ..., x_max: _Optional[float] = ..., y_max: _Optional[float] = ..., world_from_input: _Optional[_Union[_geometry_pb2.Pose, _Mapping]] = ..., cloud_timestamp: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., frames: _Optional[int] = ..., steep_facing: _Optional[str] = ..., scans_received: _Optional[int] = ..., visibility: _Optional[bytes] = ..., soft_occupancy: _Optional[bytes] = ..., normal_estimator: _Optional[str] = ..., columns: _Optional[_Union[FineColumns, _Mapping]] = ...) -> None: ...

class FineColumns(_message.Message):
    __slots__ = ("x0", "y0", "resolution", "nx", "ny", "low", "high")
    X0_FIELD_NUMBER: _ClassVar[int]
    Y0_FIELD_NUMBER: _ClassVar[int]
    RESOLUTION_FIELD_NUMBER: _ClassVar[int]
    NX_FIELD_NUMBER: _ClassVar[int]
    NY_FIELD_NUMBER: _ClassVar[int]
    LOW_FIELD_NUMBER: _ClassVar[int]
    HIGH_FIELD_NUMBER: _ClassVar[int]
    x0: float
    y0: float
    resolution: float
    nx: int
    ny: int
    low: bytes
    high: bytes
    def __init__(self, x0: _Optional[float] = ..., y0: _Optional[float] = ..., resolution: _Optional[float] = ..., nx: _Optional[int] = ..., ny: _Optional[int] = ..., low: _Optional[bytes] = ..., high: _Optional[bytes] = ...) -> None: ...

class PoseGridSpec(_message.Message):
    __slots__ = ("x0", "y0", "step", "nx", "ny", "z", "theta_step", "n_theta")
    X0_FIELD_NUMBER: _ClassVar[int]
    Y0_FIELD_NUMBER: _ClassVar[int]
    STEP_FIELD_NUMBER: _ClassVar[int]
    NX_FIELD_NUMBER: _ClassVar[int]
    NY_FIELD_NUMBER: _ClassVar[int]
    Z_FIELD_NUMBER: _ClassVar[int]
    THETA_STEP_FIELD_NUMBER: _ClassVar[int]
    N_THETA_FIELD_NUMBER: _ClassVar[int]
    x0: float
    y0: float
    step: float
    nx: int
    ny: int
    z: _containers.RepeatedScalarFieldContainer[float]
    theta_step: float
    n_theta: int
    def __init__(self, x0: _Optional[float] = ..., y0: _Optional[float] = ..., step: _Optional[float] = ..., nx: _Optional[int] = ..., ny: _Optional[int] = ..., z: _Optional[_Iterable[float]] = ..., theta_step: _Optional[float] = ..., n_theta: _Optional[int] = ...) -> None: ...

class PlacedSkeleton(_message.Message):
    __slots__ = ("x", "y", "z", "theta", "score", "joints", "probability")
    X_FIELD_NUMBER: _ClassVar[int]
    Y_FIELD_NUMBER: _ClassVar[int]
    Z_FIELD_NUMBER: _ClassVar[int]
    THETA_FIELD_NUMBER: _ClassVar[int]
    SCORE_FIELD_NUMBER: _ClassVar[int]
    JOINTS_FIELD_NUMBER: _ClassVar[int]
    PROBABILITY_FIELD_NUMBER: _ClassVar[int]
    x: float
    y: float
    z: float
    theta: float
    score: float
    joints: _containers.RepeatedScalarFieldContainer[float]
    probability: float
    def __init__(self, x: _Optional[float] = ..., y: _Optional[float] = ..., z: _Optional[float] = ..., theta: _Optional[float] = ..., score: _Optional[float] = ..., joints: _Optional[_Iterable[float]] = ..., probability: _Optional[float] = ...) -> None: ...

class AffordanceMap(_message.Message):
    __slots__ = ("timestamp", "frame_id", "affordance", "model", "threshold", "grid", "skeletons", "positives", "confidence", "world_from_input", "cloud_timestamp", "frames", "place_threshold", "place_probability", "scans_received")
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    AFFORDANCE_FIELD_NUMBER: _ClassVar[int]
    MODEL_FIELD_NUMBER: _ClassVar[int]
    THRESHOLD_FIELD_NUMBER: _ClassVar[int]
    GRID_FIELD_NUMBER: _ClassVar[int]
    SKELETONS_FIELD_NUMBER: _ClassVar[int]
    POSITIVES_FIELD_NUMBER: _ClassVar[int]
    CONFIDENCE_FIELD_NUMBER: _ClassVar[int]
    WORLD_FROM_INPUT_FIELD_NUMBER: _ClassVar[int]
    CLOUD_TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    PLACE_THRESHOLD_FIELD_NUMBER: _ClassVar[int]
    PLACE_PROBABILITY_FIELD_NUMBER: _ClassVar[int]
    SCANS_RECEIVED_FIELD_NUMBER: _ClassVar[int]
    timestamp: _timestamp_pb2.Timestamp
    frame_id: str
    affordance: str
    model: str
    threshold: float
    grid: PoseGridSpec
    skeletons: _containers.RepeatedCompositeFieldContainer[PlacedSkeleton]
    positives: bytes
    confidence: bytes
    world_from_input: _geometry_pb2.Pose
    cloud_timestamp: _timestamp_pb2.Timestamp
    frames: int
    place_threshold: float
    place_probability: float
    scans_received: int
    def __init__(self, timestamp: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., frame_id: _Optional[str] = ..., affordance: _Optional[str] = ..., model: _Optional[str] = ..., threshold: _Optional[float] = ..., grid: _Optional[_Union[PoseGridSpec, _Mapping]] = ..., skeletons: _Optional[_Iterable[_Union[PlacedSkeleton, _Mapping]]] = ..., positives: _Optional[bytes] = ..., confidence: _Optional[bytes] = ..., world_from_input: _Optional[_Union[_geometry_pb2.Pose, _Mapping]] = ..., cloud_timestamp: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., frames: _Optional[int] = ..., place_threshold: _Optional[float] = ..., place_probability: _Optional[float] = ..., scans_received: _Optional[int] = ...) -> None: ...

class NextViews(_message.Message):
    __slots__ = ("timestamp", "frame_id", "views", "world_from_input", "cloud_timestamp", "frames", "scans_received", "camera")
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    VIEWS_FIELD_NUMBER: _ClassVar[int]
    WORLD_FROM_INPUT_FIELD_NUMBER: _ClassVar[int]
    CLOUD_TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    SCANS_RECEIVED_FIELD_NUMBER: _ClassVar[int]
    CAMERA_FIELD_NUMBER: _ClassVar[int]
    timestamp: _timestamp_pb2.Timestamp
    frame_id: str
    views: _containers.RepeatedCompositeFieldContainer[NextView]
    world_from_input: _geometry_pb2.Pose
    cloud_timestamp: _timestamp_pb2.Timestamp
    frames: int
    scans_received: int
    camera: NextViewCamera
    def __init__(self, timestamp: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., frame_id: _Optional[str] = ..., views: _Optional[_Iterable[_Union[NextView, _Mapping]]] = ..., world_from_input: _Optional[_Union[_geometry_pb2.Pose, _Mapping]] = ..., cloud_timestamp: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., frames: _Optional[int] = ..., scans_received: _Optional[int] = ..., camera: _Optional[_Union[NextViewCamera, _Mapping]] = ...) -> None: ...

class NextView(_message.Message):
    __slots__ = ("pose", "heading", "gain", "places")
    POSE_FIELD_NUMBER: _ClassVar[int]
    HEADING_FIELD_NUMBER: _ClassVar[int]
    GAIN_FIELD_NUMBER: _ClassVar[int]
    PLACES_FIELD_NUMBER: _ClassVar[int]
    pose: _geometry_pb2.Pose
    heading: float
    gain: float
    places: _containers.RepeatedCompositeFieldContainer[LookedAtPlace]
    def __init__(self, pose: _Optional[_Union[_geometry_pb2.Pose, _Mapping]] = ..., heading: _Optional[float] = ..., gain: _Optional[float] = ..., places: _Optional[_Iterable[_Union[LookedAtPlace, _Mapping]]] = ...) -> None: ...

class LookedAtPlace(_message.Message):
    __slots__ = ("affordance", "x", "y", "probability")
    AFFORDANCE_FIELD_NUMBER: _ClassVar[int]
    X_FIELD_NUMBER: _ClassVar[int]
    Y_FIELD_NUMBER: _ClassVar[int]
    PROBABILITY_FIELD_NUMBER: _ClassVar[int]
    affordance: str
    x: float
    y: float
    probability: float
    def __init__(self, affordance: _Optional[str] = ..., x: _Optional[float] = ..., y: _Optional[float] = ..., probability: _Optional[float] = ...) -> None: ...

class NextViewCamera(_message.Message):
    __slots__ = ("fov_horizontal", "fov_vertical", "pitch", "min_range", "max_range")
    FOV_HORIZONTAL_FIELD_NUMBER: _ClassVar[int]
    FOV_VERTICAL_FIELD_NUMBER: _ClassVar[int]
    PITCH_FIELD_NUMBER: _ClassVar[int]
    MIN_RANGE_FIELD_NUMBER: _ClassVar[int]
    MAX_RANGE_FIELD_NUMBER: _ClassVar[int]
    fov_horizontal: float
    fov_vertical: float
    pitch: float
    min_range: float
    max_range: float
    def __init__(self, fov_horizontal: _Optional[float] = ..., fov_vertical: _Optional[float] = ..., pitch: _Optional[float] = ..., min_range: _Optional[float] = ..., max_range: _Optional[float] = ...) -> None: ...
