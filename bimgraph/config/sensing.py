"""Settings of the depth sensor's noise (simulated and weighted by) and of the plane extraction (bimgraph planes)."""

from __future__ import annotations

import numpy as np
from pydantic import Field, model_validator

from bimgraph.config.section import Section


class PlaneNoiseConfig(Section):
    """Error of a plane fitted to a depth sensor's image, dominated by the sensor's systematic
    depth error (calibrated against planes extracted from simulated depth: scripts/bench_sim.py
    calibrate). Used to draw the simulator's plane detections and as the floor of the plane
    extractor's covariance."""

    normal_sigma_deg: float = Field(0.24, ge=0, description="normal noise of a plane seen frontally at 1 m ")
    normal_range_exponent: float = Field(0.95, description="normal noise grows as range^this (range in metres)")
    normal_cos_exponent: float = Field(1.4, description="normal noise scales as cos(viewing angle)^this (the cosine floored at 0.25)")
    offset_sigma_m: float = Field(0.0028, ge=0, description="offset noise of a plane seen frontally at 1 m")
    offset_range_exponent: float = Field(1.6, description="offset noise grows as range^this")
    offset_cos_exponent: float = Field(0.9, description="offset noise scales as cos(viewing angle)^this")

    def sigmas(self, range_m: float, cos_view: float) -> tuple[float, float]:
        """(normal sigma in radians, offset sigma in metres) of a plane seen at `range_m` with
        `cos_view` between its normal and the line of sight. Both shrink at oblique views:
        depth errors lie along the line of sight, which there runs nearly within the plane."""
        cos_view = max(cos_view, 0.25)
        sigma_n = np.radians(self.normal_sigma_deg) * range_m**self.normal_range_exponent * cos_view**self.normal_cos_exponent
        sigma_d = self.offset_sigma_m * range_m**self.offset_range_exponent * cos_view**self.offset_cos_exponent
        return float(sigma_n), float(sigma_d)

    def off(self) -> "PlaneNoiseConfig":
        return self.model_copy(update={"normal_sigma_deg": 0.0, "offset_sigma_m": 0.0})


class DepthNoiseConfig(Section):
    """Depth sensor noise: what the simulator adds to rendered depth, and what the plane extractor weights by."""

    sigma_a_m: float = Field(0.0012, ge=0, description="depth noise sigma = a + b * z^2 (Kinect-like, after Nguyen et al. 2012): a, metres")
    sigma_b_per_m: float = Field(0.0019, ge=0, description="depth noise sigma = a + b * z^2: b, 1/metres")
    quantum_m: float = Field(0.0002, ge=0, description="depth is rounded to this step (the 16-bit PNG unit, 1/5000 m); 0 keeps floats")
    min_range_m: float = Field(0.3, ge=0, description="no return closer than this")
    max_range_m: float = Field(7.0, gt=0, description="no return farther than this")
    dropout_probability: float = Field(0.01, ge=0, le=1, description="chance of a random hole at any pixel")
    grazing_start_deg: float = Field(70.0, ge=0, le=90, description="incidence angle (from the surface normal) where grazing dropouts begin")
    grazing_end_deg: float = Field(85.0, ge=0, le=90, description="incidence angle beyond which no return comes back (dropout chance rises linearly from start)")
    scale_sigma: float = Field(0.003, ge=0, description="systematic part, drawn once per frame: relative depth scale error (0.003 = 3 mm per metre); 0 turns it off")
    tilt_sigma_per_m: float = Field(0.002, ge=0, description="systematic part, drawn once per frame: sigma of each of two depth error terms linear across and down the image (1 at the image border), per squared metre of depth (0.002 = 2 mm at 1 m, 8 mm at 2 m); tilts fitted planes; 0 turns it off")
    curvature_sigma_per_m: float = Field(0.0002, ge=0, description="systematic part, drawn once per frame: the same for three quadratic terms (saddle, astigmatism, bowl); bends planes, so plane extraction splits walls when it is large; 0 turns it off")

    @model_validator(mode="after")
    def _ranges(self):
        return self.ordered(("min_range_m", "max_range_m"), ("grazing_start_deg", "grazing_end_deg"))

    def sigma(self, z):
        """Standard deviation of the per-pixel depth noise at depth z (metres, scalar or array)."""
        return self.sigma_a_m + self.sigma_b_per_m * z * z

    def systematic_sigma(self, z):
        """Standard deviation of the systematic depth error at depth z at the image corners,
        where it is largest (there both tilt terms, the saddle and the bowl are 1)."""
        return ((self.scale_sigma * z) ** 2 + 2 * z**4 * (self.tilt_sigma_per_m**2 + self.curvature_sigma_per_m**2)) ** 0.5

    def without_systematic(self) -> "DepthNoiseConfig":
        """The same sensor with only per-pixel noise (what the plane extractor's covariance models)."""
        return self.model_copy(update={"scale_sigma": 0.0, "tilt_sigma_per_m": 0.0, "curvature_sigma_per_m": 0.0})


class ExtractionConfig(Section):
    """Plane extraction from depth images (bimgraph planes)."""

    cell_size_px: int = Field(20, ge=4, description="side of the square image cells fitted one by one before region growing")
    min_depth_m: float = Field(0.3, ge=0, description="depth below this is ignored")
    max_depth_m: float = Field(7.0, gt=0, description="depth beyond this is ignored")
    cell_min_valid_fraction: float = Field(0.6, gt=0, le=1, description="a cell needs this fraction of valid depth pixels to be fitted")
    max_mse_ratio: float = Field(3.0, gt=0, description="a cell, and a whole plane, is planar if its mean squared residual is at most this multiple of the one the depth noise predicts")
    grow_max_chi2: float = Field(16.0, gt=0, description="a cell joins a plane if fitting it to that plane costs at most this much chi-square over its own best fit")
    grow_max_angle_deg: float = Field(4.0, gt=0, description="a cell joins a plane only if their normals differ by at most this")
    grow_max_offset_m: float = Field(0.03, gt=0, description="a cell joins a plane only if its centroid lies at most this far from it")
    grow_iterations: int = Field(3, ge=1, description="grow, refit, grow again: this many rounds per plane")
    seed_min_support: int = Field(2, ge=0, le=4, description="a region may start only from a planar cell with this many compatible 4-neighbours")
    min_cells: int = Field(3, ge=1, description="smallest number of cells of a plane")
    min_area_m2: float = Field(0.2, ge=0, description="smallest area of a reported plane")
    polygon_tolerance_px: float = Field(2.0, ge=0, description="the extent polygon may deviate from the region outline by this many pixels")
    systematic: PlaneNoiseConfig = Field(default_factory=PlaneNoiseConfig, description="the sensor's systematic plane error, added to the covariance from the pixels (which averages per-pixel noise away and so alone is far too confident)")

    @model_validator(mode="after")
    def _ranges(self):
        return self.ordered(("min_depth_m", "max_depth_m"))
