"""Typed settings for every stage, overridable from the environment.

Every field can be set with an ``AFFORD_`` variable; nested groups use ``__``, for example
``AFFORD_VOXEL__RESOLUTION=0.05`` or ``AFFORD_GRAVITY__MAX_TILT_DEG=20``. ``afford config`` prints the
defaults together with the variable that overrides each one.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal, get_args

from pydantic import BaseModel, Field, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict


class VoxelSettings(BaseModel):
    resolution: float = Field(
        0.10, gt=0, description="voxel edge of the occupancy, distance and normal fields (m)"
    )
    margin: float = Field(
        1.0,
        ge=0,
        description="empty space kept around the cloud so placed skeletons stay inside the fields (m)",
    )
    min_height: float = Field(
        2.2, gt=0, description="the fields reach at least this high above the floor (m), even over a low scan"
    )
    fields: Literal["binary", "soft"] = Field(
        "binary",
        description="binary: a voxel is occupied or not, distances run between voxel centres (the paper's, "
        "the shipped models'); soft: each point weighs on the voxel centres around it by how near it lies, "
        "so the features change smoothly as the room moves against the lattice (docs/geometry.md)",
    )
    max_voxels: int = Field(
        10_000_000,
        ge=1000,
        description="a cloud whose fields would need more voxels than this is refused before anything is "
        "allocated (a 50 m x 50 m floor at 0.1 m is 8 million; docs/security.md gives the memory per voxel)",
    )


# which way normals steeper than 60 deg face (affordcore.geometry.fields): the cloud's mean point in plan, or
# the side
# with more scanned floor
SteepFacing = Literal["centre", "floor"]
STEEP_FACINGS = get_args(SteepFacing)
# how a point's normal is estimated (affordcore.geometry.normals): from its nearest neighbours within the
# radius, or from the points of the radius-sided cube around the lattice vertex nearest it
NormalEstimator = Literal["nearest", "cube"]
NORMAL_ESTIMATORS = get_args(NormalEstimator)


class NormalSettings(BaseModel):
    downsample: float = Field(
        0.025,
        ge=0,
        description="voxel size the cloud is thinned to before normals are estimated (m); 0 keeps every "
        "point",
    )
    estimator: NormalEstimator = Field(
        "cube",
        description="cube: the points of the cube of side radius around the lattice vertex nearest the point "
        "(the shipped models'); nearest: the max_neighbours nearest points within radius, as open3d's "
        "estimate_normals, slower (docs/geometry.md measures both)",
    )
    radius: float = Field(
        0.10, gt=0, description="neighbourhood radius for normal estimation, or the cube's side (m)"
    )
    max_neighbours: int = Field(30, ge=3, description="at most this many neighbours per normal (nearest)")
    steep_facing: SteepFacing = Field(
        "centre",
        description="which way normals steeper than 60 deg face: the cloud's mean point in plan (centre, the "
        "shipped models') or the side with more scanned floor (floor: local, so map updates stay local; "
        "docs/geometry.md)",
    )


class GridSettings(BaseModel):
    step: float = Field(
        0.10, gt=0, description="x, y spacing of the pose grid (m); a whole multiple of the voxel resolution"
    )
    theta_step: float = Field(0.1, gt=0, description="orientation spacing (rad)")
    n_theta: int = Field(63, ge=1, description="number of orientations, theta = k * theta_step")
    z_levels_each_side: int = Field(
        1, ge=0, description="torso heights tried one voxel apart above and below the skeleton's own"
    )


class FeatureSettings(BaseModel):
    cube_size: float = Field(1.0, gt=0, description="edge of the normal cube around the torso (m)")
    cell_size: float = Field(
        0.25,
        gt=0,
        description="edge of one normal-cube cell (m); the paper's 0.10 has 14x the features "
        "(docs/geometry.md)",
    )
    distance_cap: float | None = Field(
        None,
        gt=0,
        description="the joints' distance feature is truncated here (m), so a change of the room changes "
        "scores only near it (docs/geometry.md); none: untruncated, as in the paper and the shipped models",
    )
    chunk_mb: float = Field(
        256.0, gt=0, description="feature rows are produced in chunks of at most this many MB"
    )


class GravitySettings(BaseModel):
    up_candidates: list[str] = Field(
        default_factory=lambda: ["+z", "+y", "-y"],
        description="input-frame axes that may point up, tried by the automatic alignment: "
        "z-up scans, y-up scans, camera frames (y down)",
    )
    max_tilt_deg: float = Field(
        35.0,
        gt=0,
        le=90,
        description="a floor may lean at most this far from its candidate axis (a camera pitched down)",
    )
    lowest_fraction: float = Field(
        0.25,
        gt=0,
        le=1,
        description="the floor is searched among this lowest fraction of points along a candidate axis",
    )
    ransac_threshold: float = Field(0.03, gt=0, description="plane inlier distance (m)")
    ransac_iterations: int = Field(1000, ge=10)
    min_floor_area: float = Field(1.0, gt=0, description="a floor must cover at least this much area (m^2)")
    min_patch_area: float = Field(
        0.2,
        gt=0,
        description="... or, where no plane does, the lowest plane with almost nothing under it is taken as "
        "a less sure floor when it covers this much (m^2): under a given gravity, or under the sensor where "
        "the cloud says where it stood (a single frame seldom shows a square metre of one floor plane)",
    )
    max_below_fraction: float = Field(
        0.02, ge=0, le=1, description="at most this fraction of points may lie more than 5 cm under a floor"
    )
    sample_voxel: float = Field(
        0.03, gt=0, description="the cloud is thinned to this voxel size for the search (m)"
    )
    sensor_heights: tuple[float, float] = Field(
        (0.05, 2.2),
        description="where the cloud says where its sensor stood, a floor lies this far under it (m): from a "
        "robot's lowest lidar to a hand held high; a plane the sensor stands further from is a wall",
    )
    seed: int = 0

    @model_validator(mode="after")
    def _heights_in_order(self) -> GravitySettings:
        low, high = self.sensor_heights
        if not 0 <= low < high:
            raise ValueError(
                f"sensor_heights must be (low, high) with 0 <= low < high, not {self.sensor_heights}"
            )
        return self


class VisibilitySettings(BaseModel):
    angular_step: float = Field(
        1.0, gt=0, le=10, description="bin of the range images free space is carved from (degrees)"
    )
    max_origins: int = Field(
        32, ge=1, description="at most this many sensor positions carve free space (spread out over all)"
    )
    carrier_radius: float = Field(
        0.2,
        ge=0,
        description="a sensor's carrier (robot, person) stood this far around each sensor position, from the "
        "floor up to it (m): that space is free though no sensor looked at it; 0: none",
    )
    seen_low: float = Field(0.2, description="a place's body space starts this high above the floor (m)")
    seen_high: float = Field(1.4, description="and ends this high (m)")
    seen_radius: float = Field(
        0.3, ge=0, description="a place's body space: its voxel columns within this distance (m)"
    )
    min_seen: float = Field(
        0.05,
        ge=0,
        le=1,
        description="with sensor positions, a cell is mapped only when the sensors saw (free or surface) at "
        "least this share of its body space: unknown is not empty; 0: no such rule",
    )


class NextViewSettings(BaseModel):
    """Where a robot still mapping a room should look next (affordcore.mapping.next_views): a camera of a
    Kinect-class field of view and range on a mobile base."""

    count: int = Field(
        0,
        ge=0,
        le=20,
        description="views each map suggests where the sensor positions are known (afford map --next-views); "
        "0: none",
    )
    fov_horizontal_deg: float = Field(58.0, gt=0, le=360, description="the camera's horizontal field of view")
    fov_vertical_deg: float = Field(45.0, gt=0, le=180, description="its vertical field of view")
    pitch_deg: float = Field(0.0, ge=-90, le=90, description="its tilt above the horizon (negative: down)")
    min_range: float = Field(0.5, ge=0, description="the nearest it measures (m)")
    max_range: float = Field(4.5, gt=0, description="the farthest it measures (m)")
    height: float = Field(
        1.0,
        gt=0,
        description="the camera's height above the floor (m), where the sensor positions do not say",
    )
    footprint: float = Field(
        0.3,
        ge=0,
        description="the robot's radius (m): a view stands on seen-free floor this far from anything",
    )
    step: float = Field(0.2, gt=0, description="views are tried on a grid of this spacing (m)")
    headings: int = Field(24, ge=1, le=360, description="headings tried at each position")
    unseen_prior: float = Field(
        0.1,
        ge=0,
        le=0.5,
        description="the chance that never-seen body space no candidate stands in holds a place: a view that "
        "would see such space gains that much (0: views look only at the candidates)",
    )


class MapSettings(BaseModel):
    place_probability: float | None = Field(
        None,
        ge=0,
        le=1,
        description="the skeleton map keeps the places a person can use with at least this probability "
        "(models with a place model; docs/maps.md); none: each model's own cut, chosen on its validation "
        "rooms (learn.place_false_budget)",
    )
    nms_radius: float = Field(
        0.45,
        gt=0,
        description="one skeleton per place: cells within this distance of a better one are suppressed (m)",
    )
    floor_margin: float = Field(
        0.3,
        description="only cells within this distance of scanned floor are mapped (m), and cells whose column "
        "holds a scanned surface (map.hidden_floor); negative: map every cell",
    )
    hidden_floor: bool = Field(
        True,
        description="also map the cells whose floor is hidden under a scanned surface (a seat, a table top, "
        "a pushed-in chair): unknown is not empty; false: only cells near scanned floor",
    )
    rescore_max_poses: int | None = Field(
        None,
        ge=1,
        description="a cascade's trees rescore at most this many poses per affordance, its first stage's "
        "best; none: the model's own. Fewer is faster, at a cost in places docs/maps.md (Speed) measures",
    )
    max_points: int = Field(
        5_000_000, ge=1000, description="a larger cloud is thinned (with a warning) to about this many points"
    )
    thin_voxel: float = Field(
        0.01,
        gt=0,
        description="voxel size the first thinning pass of a huge cloud uses (m); doubled until it fits",
    )


class AssemblerSettings(BaseModel):
    min_range: float = Field(
        0.3, ge=0, description="scan points nearer than this to the sensor are dropped (m)"
    )
    max_range: float = Field(
        4.0,
        gt=0,
        description="scan points farther than this are dropped (m): Kinect-class depth is noisy beyond it",
    )
    voxel_size: float = Field(
        0.05,
        gt=0,
        description="KISS-ICP's local-map voxel (m), above Kinect-class depth steps and noise "
        "(docs/services.md has the measurements behind it)",
    )
    max_points_per_voxel: int = Field(
        5,
        ge=1,
        description="points KISS-ICP's local map keeps per voxel (KISS-ICP's 20 is for its 1 m voxels: in a "
        "5 cm one they cost registration twice the time for no better trajectory; docs/services.md)",
    )
    initial_threshold: float = Field(
        0.1,
        gt=0,
        description="KISS-ICP's correspondence scale (m) until it has learned one from its own prediction "
        "errors (KISS-ICP's 2 m is a car's at 10 Hz; a walking sensor moves centimetres a frame)",
    )
    min_motion: float = Field(
        0.005,
        gt=0,
        description="prediction errors (m, at max_range) smaller than this teach KISS-ICP's adaptive "
        "threshold nothing (KISS-ICP's 0.1 m is a car's: a walking sensor's errors never reach it, and "
        "the threshold stayed at its start, matching points up to 6 m apart)",
    )
    registration_voxels: float = Field(
        1.5,
        gt=0,
        description="a frame is registered on one point per cube of this many voxel_size (KISS-ICP's 1.5), "
        "the whole frame joining the local map",
    )
    busy_registration_voxels: float = Field(
        2.5,
        gt=0,
        description="... and of this many while scans wait for the assembler: half the time a frame on a "
        "busy computer, so fewer frames are skipped (docs/services.md has the measurements)",
    )
    registration_threads: int = Field(
        0,
        ge=0,
        description="threads KISS-ICP's registration may use (0: every core). With one, a frame's pose is "
        "the same to the bit in every run; with more, its sums are added in the order the threads finish",
    )
    max_frame_points: int = Field(
        100_000,
        ge=100,
        description="a frame with more points (a dense PointCloud2) is thinned to about this many, evenly, "
        "before anything else: KISS-ICP keeps one point per half voxel of it anyway",
    )
    convergence: float = Field(
        1.5e-4,
        gt=0,
        description="KISS-ICP's ICP stops once a step changes the pose less than this (KISS-ICP's own "
        "1e-4 costs more time a frame for the same accuracy: docs/services.md has the measurements)",
    )
    pixel_step: int = Field(
        2,
        ge=1,
        description="depth images become one point per n x n block of pixels, at the block's mean depth",
    )
    block_stride: int = Field(1, ge=1, description="... of every n-th block along each axis (1: every block)")
    map_voxel: float = Field(
        0.02,
        gt=0,
        description="voxel of the global map the assembler keeps (m): per voxel the mean of every point seen "
        "in it, nothing forgotten",
    )
    map_edge_spread: float = Field(
        0.05,
        ge=0,
        description="a depth image's block whose depths spread over more than this fraction of its mean "
        "depth (it straddles a depth edge: its mean is a point in mid-air) is registered but left out of the "
        "map; 0 keeps every block (docs/services.md has the measurements behind it)",
    )
    floor_level_max_deg: float = Field(
        5.0,
        ge=0,
        description="the map is levelled on its floor plane when the frames' gravity (an IMU's) finds one "
        "leaning at most this far from it (degrees), on the gravity otherwise; 0: always on the gravity",
    )
    odometry_prior: bool = Field(
        True,
        description="with the robot's odometry (a pose guess), register point to plane from its motion, "
        "weighted by it as a prior, instead of KISS-ICP's point to point from it (docs/services.md has the "
        "measurements); without odometry KISS-ICP registers either way",
    )
    odometry_error: float = Field(
        0.05,
        gt=0,
        description="the odometry's error between two frames, as a share of the step's length and of its "
        "turn (one standard deviation per axis)",
    )
    odometry_least_error: float = Field(
        0.002, gt=0, description="... at least this much (m), however short the step"
    )
    odometry_least_turn_error_deg: float = Field(
        0.1, gt=0, description="... and at least this much of a turn (degrees)"
    )
    plane_noise: float = Field(
        0.02,
        gt=0,
        description="how far (m, one standard deviation) a registration point may lie off the local map's "
        "plane through its neighbours: weighs the planes against the odometry, and the robust kernel's scale",
    )
    keyframe_distance: float = Field(
        0.05,
        ge=0,
        description="a frame joins the global map when the sensor moved this far since the last one did (m)",
    )
    keyframe_angle_deg: float = Field(5.0, ge=0, description="... or turned this far (degrees)")
    relevel_distance: float = Field(
        0.02,
        ge=0,
        description="once the map is levelled, a new levelling replaces the kept one only when it would move "
        "some map point further than this (m): every small correction moves every point, and the services "
        "then map the whole room again instead of what changed",
    )
    publish_period: float = Field(
        2.0,
        ge=0,
        description="the map cloud is published at most this often (s), counted from the first scan, and "
        "once more after the last scan",
    )
    busy_publish_period: float = Field(
        6.0,
        ge=0,
        description="... and at most this often while scans wait for the assembler: each map costs the "
        "features and inference services the cores the assembler is short of, and the one they are still "
        "working on when the scans stop delays the last map (docs/services.md has the measurements)",
    )
    checkpoint_period: float = Field(
        10.0,
        gt=0,
        description="with a state folder, the whole map is rewritten there this often (s); every frame in "
        "between is journaled as it is accepted",
    )


class LimitSettings(BaseModel):
    """What input from the network may be (AFFORD_LIMITS__*): larger or stranger input is refused, before
    anything is allocated or changed, with a message naming the limit."""

    max_points: int = Field(5_000_000, ge=100, description="points in one scan or cloud message")
    max_depth_pixels: int = Field(
        4096 * 3072, ge=1, description="pixels in one depth image (a Kinect frame is 307,200)"
    )
    max_extent: float = Field(
        100.0,
        gt=0,
        description="a map cloud spans at most this (m) along each axis, and the assembler's sensor stays "
        "within this of where it started",
    )
    max_speed: float = Field(
        5.0,
        gt=0,
        description="the sensor moves at most this fast (m/s) between frames, by its pose guess and by "
        "registration: a larger jump is refused rather than carried into the map",
    )
    max_turn_rate_deg: float = Field(720.0, gt=0, description="... and turns at most this fast (degrees/s)")
    max_sensor_origins: int = Field(
        10_000, ge=0, description="sensor positions one map cloud may carry (Cloud.sensor_origins)"
    )
    latest_timestamp: float = Field(
        4_102_444_800.0,
        gt=0,
        description="timestamps are seconds since the epoch from 0 (unset) up to this (2100-01-01)",
    )


class LearnSettings(BaseModel):
    negatives_per_room: int = Field(
        20_000,
        ge=0,
        description="training keeps every positive pose of a room and a seeded random sample of this many "
        "of its negatives (0: every negative); memory grows with rooms x this",
    )
    max_negatives: int = Field(
        500_000,
        ge=1,
        description="a training set keeps at most this many negatives in all, a seeded random share of the "
        "rooms' samples weighted up to stand for the rest: memory stops growing with the number of rooms "
        "(liblinear copies its data at 16 bytes a value)",
    )
    max_positives: int = Field(
        300_000,
        ge=1,
        description="a training set keeps at most this many positives in all, likewise: every positive pose "
        "of a room is kept, so without a cap the positives grow with the rooms (docs/learning.md)",
    )
    rescore_fraction: float = Field(
        0.03,
        gt=0,
        le=1,
        description="the second stage rescores this fraction of a room's poses, the first stage's best",
    )
    rescore_max_poses: int = Field(
        12_000,
        ge=1,
        description="and at most this many per room and affordance: a room has a bounded number of places, "
        "and the second stage's time stays bounded in large rooms (docs/maps.md measures it)",
    )
    local_detail: bool = Field(
        True,
        description="a cascade trained now gives its trees the fine columns around each pose besides its "
        "features: the lowest and highest surface of 5 cm columns in the skeleton's frame",
    )
    workers: int = Field(
        0, ge=0, description="processes that prepare rooms for training in parallel (0: one per core)"
    )
    place_false_budget: float = Field(
        0.4,
        ge=0,
        description="a model's place cut is the lowest probability from 0.5 down to 0.2 at which its "
        "validation rooms, scored by place models fitted without them, keep at most this many false places "
        "per room (docs/maps.md)",
    )
    real_share: float = Field(
        0.5,
        gt=0,
        lt=1,
        description="where real labelled rooms calibrate the place models beside the generated validation "
        "rooms (afford models rebuild --real), the share of the weight they hold together",
    )
    cache_dir: Path | None = Field(
        None,
        description="where training and evaluation keep each room's voxel fields and sampled feature rows, "
        "written once and read back one room at a time (learn/cache.py; none: $XDG_CACHE_HOME/affordmap, "
        "else ~/.cache/affordmap); safe to delete",
    )


class ClusterSettings(BaseModel):
    address: str | None = Field(
        None,
        description="a Ray cluster's address (HOST:PORT of its head, or 'auto'): rooms are generated, "
        "scanned and featurised and the k-fold trainings run there (the [cluster] extra; docs/deploy.md); "
        "none: local processes. The data set and learn.cache_dir must be on a file system every node mounts "
        "at the same path",
    )
    cpus_per_job: float = Field(1.0, gt=0, description="CPUs Ray reserves for each job")


class Settings(BaseSettings):
    """All tunables of affordmap. Defaults follow DESIGN.md (10 cm voxels and grid, 63 orientations)."""

    model_config = SettingsConfigDict(
        env_prefix="AFFORD_", env_nested_delimiter="__", env_parse_none_str="none", extra="ignore"
    )

    voxel: VoxelSettings = VoxelSettings()
    normals: NormalSettings = NormalSettings()
    grid: GridSettings = GridSettings()
    features: FeatureSettings = FeatureSettings()
    gravity: GravitySettings = GravitySettings()
    map: MapSettings = MapSettings()
    visibility: VisibilitySettings = VisibilitySettings()
    next_views: NextViewSettings = NextViewSettings()
    assembler: AssemblerSettings = AssemblerSettings()
    limits: LimitSettings = LimitSettings()
    learn: LearnSettings = LearnSettings()
    cluster: ClusterSettings = ClusterSettings()
    skeleton_dirs: list[Path] = Field(
        default_factory=list,
        description="extra folders of skeleton files (<affordance>.json); "
        "a file here overrides the built-in one of the same name",
    )

    @model_validator(mode="after")
    def _grid_on_voxel_lattice(self) -> Settings:
        ratio = self.grid.step / self.voxel.resolution
        if abs(ratio - round(ratio)) > 1e-6 or round(ratio) < 1:
            raise ValueError(
                f"grid.step ({self.grid.step}) must be a whole multiple of voxel.resolution "
                f"({self.voxel.resolution}): "
                "features are read from the voxel fields by shifting whole slabs"
            )
        return self


def describe_defaults(settings_class: type[BaseModel] = Settings) -> list[tuple[str, str, str]]:
    """(environment variable, default, description) for every setting of `settings_class`."""
    rows: list[tuple[str, str, str]] = []

    def walk(model: type[BaseModel], prefix: str) -> None:
        for name, field in model.model_fields.items():
            annotation = field.annotation
            if isinstance(annotation, type) and issubclass(annotation, BaseModel):
                walk(annotation, f"{prefix}{name.upper()}__")
                continue
            default = field.default_factory() if field.default_factory else field.default
            rows.append((f"{prefix}{name.upper()}", repr(default), field.description or ""))

    walk(settings_class, "AFFORD_")
    return rows
