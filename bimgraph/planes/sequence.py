"""Run the plane extractor over a sequence's depth images and store the planes in its keyframes."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from bimgraph.config import Config, DepthNoiseConfig, ExtractionConfig
from bimgraph.errors import BimgraphError, ConfigError, InputError
from bimgraph.planes.extractor import DetectedPlane, Extraction, PlaneExtractor
from bimgraph.sequence.format import META_FILE, Camera, Keyframe, PlaneObservation, Sequence, load_meta, load_sequence, save_sequence
from bimgraph.sequence.tum_rgbd import DEPTH_LIST, load_camera, load_tum_rgbd, read_depth_png, read_image_list
from bimgraph.validation import parse_model


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
    """Replace the planes of every keyframe that has a depth image by those extracted from it;
    a keyframe without one keeps its planes. A frame that cannot be read gets no planes (and
    `on_frame` no extraction) and one line in the report; the others go on."""
    extractor = PlaneExtractor(camera, cfg, noise)
    report = DetectionReport()
    for i, kf in enumerate(seq.keyframes):
        if kf.depth is None:
            continue
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
    """Extract the planes of every keyframe that has a depth image and save the sequence; a
    simulated depth sequence also gets the ground truth of its new planes, so that it can be
    evaluated. A sequence without depth images is refused before anything is written (its
    planes are all it has), as is one in whose depth images no plane is found. The keyframes
    file is replaced once, atomically, after the last frame: a failure or Ctrl-C half-way
    leaves it as it was."""
    from bimgraph.sim.labels import simulated_labeller

    if not any(kf.depth for kf in seq.keyframes):
        raise InputError(f"{seq.root}: no keyframe has a depth image (a sequence of plane detections?); nothing written")
    labeller = simulated_labeller(seq.root)
    position = {kf.index: i for i, kf in enumerate(seq.keyframes)}

    def frame(kf: Keyframe, extraction: Extraction | None) -> None:
        if labeller is not None:
            labeller.label(position[kf.index], kf, extraction)
        if on_frame is not None:
            on_frame(kf, extraction)

    seq.meta.camera = camera
    report = detect_planes(seq, camera, cfg.planes, cfg.depth_noise, frame)
    if report.planes == 0:
        # (saved, the planes the keyframes had would be gone, and a run could use none of them)
        why = (f"every one was skipped; the first: {report.problems[0]}" if len(report.problems) == report.frames
               else "check the intrinsics, their depth_scale and the configuration's `planes`")
        raise InputError(f"{seq.root}: no plane found in any of the {report.frames} depth images ({why}); nothing written")
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
        return parse_model(Camera, dict(width=width, height=height, fx=fx, fy=fy, cx=cx, cy=cy),
                           "--fx --fy --cx --cy", error=ConfigError)
    if seq is not None and seq.meta.camera is not None:
        return seq.meta.camera
    raise InputError("no intrinsics: give --intrinsics FILE or --fx --fy --cx --cy")


def open_input(folder: Path, trajectory: Path | None = None, intrinsics: Path | None = None,
               pinhole: tuple = (None, None, None, None), max_dt: float = 0.02) -> tuple[Sequence, Camera]:
    """What `bimgraph planes` extracts into, and the camera: a sequence folder, or a plain TUM
    RGB-D folder with a `trajectory` of any SLAM (keyframes within `max_dt` s of a pose). The
    camera comes from `intrinsics` (a file), `pinhole` (fx, fy, cx, cy; all or none) or the
    sequence. Which options go together, and `max_dt`, are checked before any file is read;
    the pinhole values once the first depth image gives the image size."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: {'a file, not a folder' if folder.exists() else 'no such folder'} (give the sequence "
                         "folder, or a TUM RGB-D folder with --trajectory)")
    given = [v is not None for v in pinhole]
    if any(given) and not all(given):
        raise ConfigError("give all four of --fx --fy --cx --cy")
    if not max_dt >= 0:  # (NaN too)
        raise ConfigError(f"--max-dt must be at least 0 s, not {max_dt}")
    pinhole = tuple(pinhole) if all(given) else None
    camera_file = load_camera(intrinsics) if intrinsics is not None else None
    if trajectory is not None:
        _, names = read_image_list(folder / DEPTH_LIST)
        camera = resolve_camera(None, camera_file, pinhole, folder / names[0] if names else None)
        seq = load_tum_rgbd(folder, trajectory, camera, max_dt=max_dt)
        if (folder / META_FILE).is_file():
            # run again (a new trajectory, other settings): what the user added by hand, the
            # model and the initial alignment, stays; the camera is the one given now (the old
            # one is not even read: one the checks refuse must not block its replacement)
            earlier = load_meta(folder, ignore=("camera",))
            seq.meta = earlier.model_copy(update={"camera": camera, "sensor": seq.meta.sensor})
        return seq, camera
    if not (folder / META_FILE).is_file():
        raise InputError(f"{folder}: no {META_FILE}; for a TUM RGB-D folder give --trajectory")
    seq = load_sequence(folder)
    first = next((folder / kf.depth for kf in seq.keyframes if kf.depth), None)
    return seq, resolve_camera(seq, camera_file, pinhole, first)
