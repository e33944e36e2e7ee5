"""Run the plane extractor over a sequence's depth images and store the planes in its keyframes."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from bimgraph.config import Config, DepthNoiseConfig, ExtractionConfig
from bimgraph.errors import BimgraphError, InputError
from bimgraph.planes.extractor import DetectedPlane, Extraction, PlaneExtractor
from bimgraph.sequence.format import Camera, Keyframe, PlaneObservation, Sequence, save_sequence
from bimgraph.sequence.tum_rgbd import read_depth_png


@dataclass
class DetectionReport:
    frames: int = 0
    planes: int = 0
    problems: list[str] = field(default_factory=list)  # one line per frame that gave no planes


def observation(plane: DetectedPlane) -> PlaneObservation:
    return PlaneObservation(
        n=tuple(plane.n), d=plane.d, cov=tuple(map(tuple, plane.cov)),
        polygon=[tuple(p) for p in plane.polygon] if len(plane.polygon) >= 3 else None,
        area=plane.area, centre=tuple(plane.centre), inliers=plane.inliers,
    )


def load_depth(seq: Sequence, kf: Keyframe, camera: Camera) -> np.ndarray:
    """The keyframe's depth image in metres; InputError for anything the extractor cannot use."""
    if kf.depth is None:
        raise InputError(f"keyframe {kf.index}: has no depth image")
    path = seq.root / kf.depth
    depth = read_depth_png(path, camera.depth_scale)
    if depth.shape != (camera.height, camera.width):
        raise InputError(f"{path}: depth image is {depth.shape[1]}x{depth.shape[0]}, the camera is {camera.width}x{camera.height}")
    if not depth.any():
        raise InputError(f"{path}: no valid depth (all pixels are 0)")
    return depth


def detect_planes(seq: Sequence, camera: Camera, cfg: ExtractionConfig, noise: DepthNoiseConfig,
                  on_frame: Callable[[Keyframe, Extraction | None], None] | None = None) -> DetectionReport:
    """Replace every keyframe's planes by those extracted from its depth image. A frame that
    cannot be read gets no planes (and `on_frame` no extraction) and one line in the report;
    the others go on."""
    extractor = PlaneExtractor(camera, cfg, noise)
    report = DetectionReport()
    for i, kf in enumerate(seq.keyframes):
        try:
            extraction = extractor.extract(load_depth(seq, kf, camera))
            planes = extraction.planes
        except BimgraphError as err:
            report.problems.append(str(err))
            extraction, planes = None, []
        seq.keyframes[i] = kf.model_copy(update={"planes": [observation(p) for p in planes]})
        report.frames += 1
        report.planes += len(planes)
        if on_frame is not None:
            on_frame(kf, extraction)
    return report


def extract_into(seq: Sequence, camera: Camera, cfg: Config,
                 on_frame: Callable[[Keyframe, Extraction | None], None] | None = None) -> DetectionReport:
    """Extract the planes of every keyframe and save the sequence; a simulated depth sequence
    also gets the ground truth of its new planes, so that it can be evaluated."""
    from bimgraph.sim.labels import simulated_labeller

    labeller = simulated_labeller(seq.root)
    position = {kf.index: i for i, kf in enumerate(seq.keyframes)}

    def frame(kf: Keyframe, extraction: Extraction | None) -> None:
        if labeller is not None:
            labeller.label(position[kf.index], kf, extraction)
        if on_frame is not None:
            on_frame(kf, extraction)

    seq.meta.camera = camera
    report = detect_planes(seq, camera, cfg.planes, cfg.depth_noise, frame)
    save_sequence(seq)
    if labeller is not None:
        labeller.save(seq.root)
    return report


def resolve_camera(seq: Sequence | None, intrinsics: Camera | None, pinhole: tuple | None, first_depth=None) -> Camera:
    """The camera from (in this order) an intrinsics file, fx/fy/cx/cy options (image size from
    the first depth image), or the sequence's metadata."""
    if intrinsics is not None:
        return intrinsics
    if pinhole is not None:
        if first_depth is None:
            raise InputError("no depth image to take the image size from")
        height, width = read_depth_png(first_depth).shape
        fx, fy, cx, cy = pinhole
        return Camera(width=width, height=height, fx=fx, fy=fy, cx=cx, cy=cy)
    if seq is not None and seq.meta.camera is not None:
        return seq.meta.camera
    raise InputError("no intrinsics: give --intrinsics FILE or --fx --fy --cx --cy")
