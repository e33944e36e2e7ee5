"""Factors that bimgraph adds to the gtsam graph, each with its residual written out.

The graph uses gtsam's C++ factors wherever they compute the same residual (Python
`CustomFactor`s copy the whole `Values` into every callback and are slow inside the
optimisers); the Python versions here are the readable reference the tests hold them to.
"""

from factors.depth_tilt import anchor_step, inverse_depth_sensitivity, tilt_link_factor, tilt_sensitivity
from factors.plane import (
    deviation_cov_in_residual,
    error_jacobian_wrt_plane,
    face_tolerance_coordinates,
    face_tolerance_cov,
    local_plane_error,
    predict_local_plane,
    local_plane_custom_factor,
    local_plane_factor,
    plane_prior_at,
    plane_prior_error,
    plane_prior_factor,
    plane_to_bim_factor,
    plane_to_bim_custom_factor,
)

__all__ = [
    "anchor_step",
    "inverse_depth_sensitivity",
    "tilt_link_factor",
    "tilt_sensitivity",
    "deviation_cov_in_residual",
    "error_jacobian_wrt_plane",
    "face_tolerance_coordinates",
    "face_tolerance_cov",
    "local_plane_error",
    "predict_local_plane",
    "local_plane_custom_factor",
    "local_plane_factor",
    "plane_prior_at",
    "plane_prior_error",
    "plane_prior_factor",
    "plane_to_bim_factor",
    "plane_to_bim_custom_factor",
]
