"""Settings of the simulator (bimgraph simulate): buildings as built, the walk, the front-end, the detections."""

from __future__ import annotations

from pydantic import Field, model_validator

from bimgraph.config.section import Range, Section
from bimgraph.config.sensing import PlaneNoiseConfig


class AsBuiltConfig(Section):
    """As-built deviations and clutter of one kind of building."""

    offset_fraction: float = Field(0.15, ge=0, le=1, description="fraction of wall faces moved along their normal")
    offset_min_m: float = Field(0.01, ge=0, description="smallest offset of a moved face")
    offset_max_m: float = Field(0.10, ge=0, description="largest offset of a moved face")
    tilt_fraction: float = Field(0.10, ge=0, le=1, description="fraction of wall faces tilted about their bottom edge")
    tilt_max_deg: float = Field(2.0, ge=0, le=10, description="largest tilt of a tilted face")
    missing_wall_fraction: float = Field(0.0, ge=0, le=1, description="fraction of walls not yet built (never all of them)")
    clutter_per_m2: float = Field(0.04, ge=0, description="boxes and cabinets per square metre of floor")
    boards_per_m2: float = Field(0.0, ge=0, description="boards leaning against walls per square metre of floor")
    partitions: int = Field(0, ge=0, description="temporary partitions (walls absent from the model)")

    @model_validator(mode="after")
    def _ranges(self):
        return self.ordered(("offset_min_m", "offset_max_m"))


class TrajectoryConfig(Section):
    """Simulated camera path."""

    grid_m: float = Field(0.05, gt=0, description="cell size of the occupancy grid sliced from the as-built walls")
    clearance_m: float = Field(0.3, gt=0, description="closest approach of the camera to any wall or clutter")
    height_min_m: float = Field(1.2, gt=0, description="lowest camera height above the floor")
    height_max_m: float = Field(1.7, gt=0, description="highest camera height above the floor")
    keyframe_distance_m: float = Field(0.3, gt=0, description="a keyframe is taken after this much travel...")
    keyframe_angle_deg: float = Field(10.0, gt=0, description="...or this much rotation since the last one")
    step_m: float = Field(0.02, gt=0, description="spacing of the dense path the keyframes are picked from")
    waypoint_spacing_m: float = Field(2.5, gt=0, description="least distance between the waypoints the path visits")
    smoothing_m: float = Field(0.4, ge=0, description="width of the moving average that rounds the path's corners")
    sweep_deg: float = Field(30.0, ge=0, description="amplitude of the side-to-side look-around about the walking direction")
    sweep_period_m: float = Field(8.0, gt=0, description="distance walked per look-around cycle")
    pitch_deg: float = Field(12.0, ge=0, description="amplitude of the up-and-down look")
    pitch_mean_deg: float = Field(-5.0, description="mean pitch (negative looks down)")
    roll_deg: float = Field(2.0, ge=0, description="amplitude of the hand-held roll")
    spin_probability: float = Field(0.1, ge=0, le=1, description="chance of turning on the spot once around at a waypoint")
    speed_m_s: float = Field(0.7, gt=0, description="walking speed, for the time stamps")
    turn_rate_deg_s: float = Field(45.0, gt=0, description="turning speed on the spot, for the time stamps")

    @model_validator(mode="after")
    def _ranges(self):
        return self.ordered(("height_min_m", "height_max_m"))


class FrontEndConfig(Section):
    """Simulated SLAM front-end: drifting odometry in the frame S of the first camera."""

    gravity_aligned: bool = Field(True, description="S has z up (as AR trackers do); else S is the first camera frame")
    translation_drift: float = Field(0.01, ge=0, description="position drift per metre travelled (0.01 = 1 %)")
    yaw_drift_deg_per_m: float = Field(0.2, ge=0, description="heading drift per metre travelled")
    scale_error: float = Field(0.0, gt=-0.5, lt=0.5, description="each step's length is off by this share "
                               "(0.01 = 1 % too long, as a wheel odometry's or a tracker's scale error); the planes stay metric")
    random_walk_m: float = Field(0.003, ge=0, description="position random walk, metres per square-root metre travelled")
    random_walk_deg: float = Field(0.05, ge=0, description="rotation random walk, degrees per square-root metre travelled")
    noise_m: float = Field(0.002, ge=0, description="white noise on each keyframe position")
    noise_deg: float = Field(0.05, ge=0, description="white noise on each keyframe orientation")


class ObserveConfig(Section):
    """Simulated plane detections (--sensor planes)."""

    stride_px: int = Field(4, ge=1, description="ray-cast every this many pixels of the 640x480 image to find visible face parts")
    min_range_m: float = Field(0.3, ge=0, description="the sensor sees nothing closer")
    max_range_m: float = Field(5.5, gt=0, description="the sensor sees nothing farther")
    max_obliquity_deg: float = Field(75.0, gt=0, le=90, description="planes seen more obliquely than this are not detected")
    min_area_m2: float = Field(0.25, ge=0, description="smallest visible area of a detected plane")
    min_pixels: int = Field(1500, ge=1, description="smallest number of full-resolution pixels of a detected plane")
    noise: PlaneNoiseConfig = PlaneNoiseConfig()
    floors_and_ceilings: bool = Field(True, description="also detect floor and ceiling planes")
    oversegment_probability: float = Field(0.05, ge=0, le=1, description="chance that a detector splits a plane (twice the minimum area or more) into two detections")

    @model_validator(mode="after")
    def _ranges(self):
        return self.ordered(("min_range_m", "max_range_m"))


class SimConfig(Section):
    """Simulator (bimgraph simulate)."""

    storey: str = Field("", description="storey of the model to walk (name); empty picks the one with the most wall area")
    width: int = Field(640, gt=0, description="image width in pixels")
    height: int = Field(480, gt=0, description="image height in pixels")
    fx: float = Field(525.0, gt=0, description="focal length in pixels (x)")
    fy: float = Field(525.0, gt=0, description="focal length in pixels (y)")
    initial_rot_error_deg: Range = Field((1.0, 2.0), description="range of the yaw error of the simulated manual alignment")
    initial_trans_error_m: Range = Field((0.1, 0.2), description="range of the horizontal position error of the manual alignment")
    as_built_office: AsBuiltConfig = AsBuiltConfig()
    as_built_site: AsBuiltConfig = AsBuiltConfig(
        offset_fraction=0.25, tilt_fraction=0.15, missing_wall_fraction=0.1, clutter_per_m2=0.08, boards_per_m2=0.03, partitions=3
    )
    as_built_ifc: AsBuiltConfig = AsBuiltConfig(clutter_per_m2=0.03)
    trajectory: TrajectoryConfig = TrajectoryConfig()
    frontend: FrontEndConfig = FrontEndConfig()
    observe: ObserveConfig = ObserveConfig()

    @model_validator(mode="after")
    def _ranges(self):
        for name in ("initial_rot_error_deg", "initial_trans_error_m"):
            lo, hi = getattr(self, name)
            if not 0 <= lo <= hi:
                raise ValueError(f"{name} must be a range [low, high] with 0 <= low <= high")
        # the planes sensor ray-casts an image `observe.stride_px` times smaller: it needs a pixel
        stride = self.observe.stride_px
        if min(self.width, self.height) < stride:
            raise ValueError(f"width and height ({self.width}x{self.height}) must be at least observe.stride_px ({stride})")
        return self
