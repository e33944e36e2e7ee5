"""Settings of what is made of a run: the deviation report, the seed paper's baselines, the Rerun viewer."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field, model_validator

from bimgraph.config.section import Section


class DeviationConfig(Section):
    """As-built deviations of observed walls from plan (deviations.json, .csv, .bcf)."""

    tolerance_m: float = Field(0.02, gt=0, le=1.0, description="allowed offset of a built face along its normal (common wall tolerance +/-2 cm; in metres: 20 for 20 mm is refused)")
    tilt_tolerance_deg: float = Field(0.5, gt=0, description="allowed tilt of a built face (about 2 cm over a 2.5 m storey)")
    k_sigma: float = Field(3.0, ge=0, description="a face deviates if |offset| - k*sigma > tolerance, or its tilt likewise (a significance test, so that noise does not make a wall deviate: each flag sends someone to the wall; on 8 simulated sites, k = 2 flagged 3 sound faces, 3 none)")
    min_keyframes: int = Field(3, ge=1, description="faces seen in fewer keyframes have not enough evidence, and unmatched planes seen in fewer are not reported as unplanned (a glimpse sends nobody to the site)")
    conformance_k: float = Field(2.0, ge=0, description="a face is within tolerance only where its offset and tilt lie inside the tolerance by k sigma: ISO 14253-1's conformance zone, the tolerance less the expanded uncertainty at its coverage factor k = 2 (about 98 % sure one-sided); between that zone and k_sigma beyond the tolerance, neither is proven and the face has not enough evidence. 0: the estimate inside the tolerance suffices, however uncertain")
    match_max_offset_m: float = Field(0.2, gt=0, description="a face no landmark is associated with is measured, for the report, by a landmark passing this close to its centre...")
    match_max_tilt_deg: float = Field(5.0, gt=0, description="...is tilted less than this from it...")
    match_min_overlap_m2: float = Field(0.25, ge=0, description="...and its extent overlaps the face by at least this much...")
    match_margin_m: float = Field(0.3, ge=0, description="...or, for a landmark without an extent polygon, its centre lies within this of the face")
    plan_coplanar_m: float = Field(0.02, gt=0, description="...and a landmark measures, of the faces it passes, only those the plan puts on one plane with its own (the face the graph matched it to, else the nearest it passes; every corner within this of that plane): not a face hidden behind it, as a party wall behind its furring")
    unplanned_min_area_m2: float = Field(1.0, ge=0, description="unmatched landmarks at least this large are reported as unplanned")
    unplanned_vertical_only: bool = Field(True, description="only near-vertical unmatched planes count as unplanned (floors and ceilings are not walls)")
    vertical_tolerance_deg: float = Field(10.0, gt=0, description="a plane is vertical if its normal is within this of horizontal")
    visibility_grid_m: float = Field(0.25, ge=0.01, description="spacing of the sample points on each face for the expected-in-view test (at least 1 cm: finer costs memory by its inverse square and sees nothing more)")
    visibility_min_range_m: float = Field(0.3, ge=0, description="a face point is in view from this distance...")
    visibility_max_range_m: float = Field(5.0, gt=0, description="...up to this one...")
    visibility_max_obliquity_deg: float = Field(70.0, gt=0, le=90, description="...seen at most this obliquely...")
    visibility_min_area_m2: float = Field(0.5, ge=0, description="...and a face is in view if at least this much of it is in view and not occluded by other faces")
    min_expected_keyframes: int = Field(5, ge=1, description="a never-observed face in view in at least this many keyframes is possibly not built")
    online_refine: bool = Field(True, description="after an online run, measure the walls where the offline rounds take its graph (the drift and odometry noise estimated, the robust alignment, re-association), not at its own batch solution: the online graph keeps the given odometry noise, looser than the front-end's (offline estimates it at 0.2-0.4 of it on the simulated walks), so walls built off plan bend its trajectory and sound faces read centimetres off at several sigma (office 2: 8 of 31 faces beyond 3 sigma, none refined). Costs about the offline rounds: 6-12 s on a 600-keyframe walk")
    contest_min_probability: float = Field(0.01, ge=0, le=1, description="where the robust alignment's runner-up consensus is at least this likely and judges some face otherwise (deviating under one alignment, not under the other), the report lists both explanations, e.g. one of two parallel walls 5 cm off, which one the data cannot tell, with a BCF topic naming the walls")
    width_max_angle_deg: float = Field(1.0, gt=0, description="a room's width (a wall's thickness) is measured between two wall faces of that room (of that wall) whose normals are opposite within this...")
    width_min_overlap_m: float = Field(0.5, ge=0, description="...and whose extents along the walls overlap by this much (they face each other; are back to back), each measured by a landmark of its own")
    bcf_author: str = Field("bimgraph", description="author of the BCF topics")
    bcf_view_distance_m: float = Field(3.0, gt=0, description="the BCF viewpoint looks at the face (its material nearest its centre) from this far along its normal, or nearer where the room is shallower")

    @model_validator(mode="after")
    def _ranges(self):
        return self.ordered(("visibility_min_range_m", "visibility_max_range_m"))


class BaselineConfig(Section):
    """The seed paper's baselines (bimgraph eval, scripts/reproduce_paper.py)."""

    offset_sigma_m: float = Field(0.02, gt=0, description="global/local: one sigma of a matched plane's offset...")
    prior_trans_m: float = Field(2.0, gt=0, description="...against that of the weak prior toward the manual alignment, so that translations the planes leave free stay there")
    local_max_planes: int = Field(12, ge=3, description="local: at most this many matched planes per solve")
    local_radius_m: float = Field(6.0, gt=0, description="local: planes farther from the camera than this are never added")


Rgba = Annotated[list[Annotated[int, Field(ge=0, le=255)]], Field(min_length=3, max_length=4)]


class ViewerConfig(Section):
    """Rerun viewer (bimgraph run --rrd / --spawn, bimgraph view). Colours are [r, g, b, a], 0-255."""

    flush_seconds: float = Field(0.5, ge=0, description="send the buffered rows to Rerun at most this often (the live view lags by about this much)...")
    flush_budget: float = Field(0.05, gt=0, le=1, description="...and so rarely that sending takes at most this fraction of the run's wall time")
    depth_images: bool = Field(True, description="log each keyframe's depth image in the camera view (when the sequence has them)")
    frustum_m: float = Field(0.3, gt=0, description="depth of the camera frustum drawn in 3-D")
    axes_length_m: float = Field(0.3, gt=0, description="length of the axes drawn at the camera and at the origin of S")
    trajectory_radius_m: float = Field(0.015, gt=0, description="half-width of the trajectory lines")
    label_radius_m: float = Field(0.03, gt=0, description="radius of the point carrying each face's id label")
    observed_angle_deg: float = Field(15.0, gt=0, description="display only: a face counts as observed when a detected plane, mapped by the current estimate, is this parallel to it...")
    observed_distance_m: float = Field(0.3, gt=0, description="...its centre this close to the face's plane...")
    observed_margin_m: float = Field(0.5, ge=0, description="...and inside the face's bounding box grown by this margin")
    colour_unobserved: Rgba = Field([170, 170, 170, 90], description="BIM face never observed")
    colour_observed: Rgba = Field([90, 150, 230, 140], description="BIM face observed but not associated")
    colour_associated: Rgba = Field([60, 190, 90, 170], description="BIM face associated with a landmark")
    colour_contested: Rgba = Field([250, 160, 0, 200], description="BIM face of a contest: one of its walls deviates, which one the data cannot tell (deviations.json's contested)")
    colour_deviating: Rgba = Field([230, 60, 50, 200], description="BIM face whose as-built position deviates beyond tolerance")
    colour_raw: Rgba = Field([240, 140, 30, 255], description="raw front-end trajectory mapped by the initial alignment")
    colour_corrected: Rgba = Field([30, 110, 240, 255], description="corrected trajectory, as estimated at each keyframe")
    colour_final: Rgba = Field([150, 60, 220, 255], description="final trajectory (logged once at the end)")
    colour_truth: Rgba = Field([40, 40, 40, 255], description="ground-truth trajectory")
    colour_plane: Rgba = Field([250, 210, 40, 255], description="outline of a detected plane not associated with a BIM face")
    colour_plane_associated: Rgba = Field([60, 190, 90, 255], description="outline of a detected plane associated with a BIM face")
    colour_association: Rgba = Field([60, 190, 90, 255], description="line from an associated plane to its BIM face's centre")

    def colour(self, state: str) -> Rgba:
        """The colour of a face state: unobserved, observed, associated, contested or deviating."""
        return getattr(self, f"colour_{state}")
