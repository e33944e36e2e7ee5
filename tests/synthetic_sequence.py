"""A sequence folder written from the backend's synthetic scene, as the simulator would write
it but in a second: plane detections, a plane map JSON as the model, ground truth."""

import numpy as np

from bimgraph.backend.synthetic import make_scene
from bimgraph.bim.planemap import save_plane_map
from bimgraph.sequence.format import Camera, InitialAlignment, Sequence, SequenceMeta, save_sequence
from bimgraph.sequence.groundtruth import GroundTruth, pose7, write_groundtruth

CAMERA = Camera(width=640, height=480, fx=525.0, fy=525.0, cx=319.5, cy=239.5)


def write_sequence(root, n_keyframes: int, rooms=(1, 2), seed: int = 5, sensor: str = "planes"):
    """Write the folder `root` (made if needed); returns the scene. `sensor` as the metadata's
    (`depth`: as if `bimgraph planes` had detected the planes in depth images)."""
    scene = make_scene(n_keyframes=n_keyframes, rooms=rooms, seed=seed)
    root.mkdir(parents=True, exist_ok=True)
    save_plane_map(scene.plane_map, root / "planes.json")
    meta = SequenceMeta(name="synthetic", model="planes.json", sensor=sensor, camera=CAMERA,
                        initial_alignment=InitialAlignment(T_B_S=tuple(pose7(scene.initial.T_B_S))))
    save_sequence(Sequence(root=root, meta=meta, keyframes=scene.keyframes))
    observations = [[{"face_id": scene.truth.get((kf.index, i))} for i in range(len(kf.planes))] for kf in scene.keyframes]
    write_groundtruth(root, GroundTruth(np.array([kf.stamp for kf in scene.keyframes]), np.array(scene.T_B_C),
                                        scene.T_B_S, {}, observations, {},
                                        [{"index": k, "faces": {}} for k in range(len(scene.keyframes))]))
    return scene
