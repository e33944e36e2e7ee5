"""Settings of the IFC import (bimgraph bim)."""

from __future__ import annotations

from pydantic import Field

from bimgraph.config.section import Section


class BimImportConfig(Section):
    """IFC import."""

    min_face_area_m2: float = Field(0.05, ge=0, description="side faces smaller than this are dropped (wall ends, slivers)")
    include_slabs: bool = Field(False, description="also export slab top and bottom faces as horizontal planes")
    vertical_tol_deg: float = Field(0.5, gt=0, description="a triangle is part of a vertical face when its normal is this close to horizontal")
    axis_tol_deg: float = Field(1.0, gt=0, description="a vertical face of a wall is a side face when it is this close to parallel to the wall's axis")
    coplanar_angle_deg: float = Field(0.05, gt=0, description="triangles whose normals differ by less than this may share a face")
    coplanar_distance_m: float = Field(0.002, gt=0, description="triangles whose planes are closer than this may share a face")
    curved_face_tol_m: float = Field(0.01, gt=0, description="a curved wall face is cut into planar facets, as few as stay this close to it")
    grid_m: float = Field(1e-5, gt=0, description="precision grid of the 2-D polygon operations on faces")
    opening_slice_depth_m: float = Field(0.001, gt=0, description="openings are cut out of a face where they cross the plane this far behind it")
    lining_gap_m: float = Field(0.01, gt=0, description="a face is hidden where another wall running along it (a lining, furring or cladding modelled as a wall of its own) fills the plane this far in front of it")
    boundary_on_face_m: float = Field(0.02, gt=0, description="a space boundary lies on a wall face when all its points are this close to the face's plane")
    probe_distance_m: float = Field(0.1, gt=0, description="rooms are probed this far in front of a wall face")
    min_section_width_m: float = Field(0.5, gt=0, description="in a model without rooms, a face is not cut at a junction closer than this to its end")
    threads: int = Field(0, ge=0, description="threads of the ifcopenshell geometry iterator (0: all cores)")
