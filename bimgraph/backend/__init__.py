"""The backend: keyframe poses, plane landmarks and the BIM<-SLAM extrinsic in one gtsam graph,
with plane-to-BIM factors added after association (see ../shared/DESIGN.md).

    Backend(plane_map, cfg, initial).process(keyframe) -> KeyframeResult   # online
    run_online(keyframes, plane_map, cfg, initial) -> Results
    run_offline(keyframes, plane_map, cfg, initial) -> Results
    BimAssociator(FaceIndex(plane_map, cfg.bim_association), cfg.bim_association).match(candidates)  # association alone
"""

from bimgraph.backend.alignment import Alignment, align_from_seeds, unobservable_directions
from bimgraph.backend.associate_bim import BimAssociator, FaceIndex, FaceMatch, PlaneInB, planes_in_B_independent
from bimgraph.backend.offline import run_offline
from bimgraph.backend.online import Backend, run_online
from bimgraph.backend.records import Association, KeyframeResult, Listener, Results

__all__ = ["Alignment", "Association", "Backend", "BimAssociator", "FaceIndex", "FaceMatch", "KeyframeResult",
           "Listener", "PlaneInB", "Results", "align_from_seeds", "planes_in_B_independent", "run_offline", "run_online",
           "unobservable_directions"]
