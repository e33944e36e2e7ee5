"""TUM RGB-D folders: 16-bit depth PNGs (metres * 5000), `depth.txt` / `rgb.txt` image lists,
and their conversion into a bimgraph sequence with poses from any SLAM's TUM trajectory.

Layout (https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats):
`depth.txt` and `rgb.txt` hold `stamp path` lines (`#` starts a comment), the paths being
relative to the folder. A depth pixel of 0 means no return.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from bimgraph.errors import FormatError, InputError
from bimgraph.files import read_json, read_yaml, write_atomic
from bimgraph.geometry import pose_to_tum
from bimgraph.sequence.format import Camera, Keyframe, Sequence, SequenceMeta
from bimgraph.sequence.tum import data_lines, not_seconds, read_tum
from bimgraph.validation import parse_model

DEPTH_LIST = "depth.txt"
RGB_LIST = "rgb.txt"
DEPTH_SCALE = 5000.0
_UINT16_MAX = np.iinfo(np.uint16).max


def write_depth_png(path: Path, depth_m: np.ndarray, scale: float = DEPTH_SCALE) -> None:
    """A z-depth image in metres as a 16-bit PNG; depths the format cannot hold become 0."""
    import cv2

    units = np.round(np.asarray(depth_m, dtype=float) * scale)
    units[~np.isfinite(units) | (units < 0) | (units > _UINT16_MAX)] = 0
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), units.astype(np.uint16)):
        raise InputError(f"{path}: cannot write a PNG here")


def read_depth_png(path: Path, scale: float = DEPTH_SCALE) -> np.ndarray:
    """A 16-bit single-channel depth PNG as float metres (0 = no return)."""
    import cv2

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such depth image")
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputError(f"{path}: not a readable image")
    if image.ndim != 2:
        raise InputError(f"{path}: depth image has {image.shape[2]} channels, must have 1")
    if image.dtype != np.uint16:
        bits = image.dtype.itemsize * 8
        raise InputError(f"{path}: depth image is {bits}-bit {image.dtype}, must be 16-bit unsigned (metres * {scale:g})")
    return image.astype(float) / scale


def read_image_list(path: Path, in_order: bool = False) -> tuple[np.ndarray, list[str]]:
    """Stamps and relative paths of a TUM `depth.txt` / `rgb.txt`; `in_order`: FormatError
    naming the line where a stamp does not follow the one before (each depth image becomes a
    keyframe, and keyframes must follow one another)."""
    stamps, names = [], []
    for lineno, fields in data_lines(path):
        if len(fields) != 2:
            raise FormatError(f"{path}: line {lineno}: expected `stamp path`, got {len(fields)} fields")
        try:
            stamp = float(fields[0])
        except ValueError:
            stamp = math.nan
        if not math.isfinite(stamp):  # (float() takes "nan" and "inf")
            raise FormatError(f"{path}: line {lineno}: stamp {fields[0]!r} is not a finite number")
        if (why := not_seconds(stamp)) is not None:
            raise FormatError(f"{path}: line {lineno}: stamp {why}")
        if in_order and stamps and stamp <= stamps[-1]:
            raise FormatError(f"{path}: line {lineno}: stamp {fields[0]} does not follow {stamps[-1]:.6f} (list each image "
                              "once, in time order)")
        stamps.append(stamp)
        names.append(fields[1])
    return np.array(stamps), names


def write_image_list(path: Path, stamps, names, kind: str) -> None:
    """A TUM `depth.txt` / `rgb.txt`; `kind` names the images in its header."""
    lines = [f"# {kind} images", "# timestamp filename"]
    lines += [f"{float(s):.6f} {n}" for s, n in zip(stamps, names)]
    write_atomic(path, "\n".join(lines) + "\n")


def load_camera(path: Path) -> Camera:
    """Intrinsics from a YAML or JSON file with width, height, fx, fy, cx, cy (depth_scale optional)."""
    path = Path(path)
    data = read_json(path) if path.suffix.lower() == ".json" else read_yaml(path)
    return parse_model(Camera, data, str(path))


def nearest(query: np.ndarray, stamps: np.ndarray, max_dt: float) -> np.ndarray:
    """Index into sorted `stamps` of the one nearest each query stamp, -1 if none within max_dt."""
    if len(stamps) == 0:
        return np.full(len(query), -1)
    order = np.argsort(stamps)
    s = stamps[order]
    hi = np.clip(np.searchsorted(s, query), 1, len(s) - 1) if len(s) > 1 else np.zeros(len(query), int)
    lo = np.maximum(hi - 1, 0)
    pick = np.where(np.abs(s[lo] - query) <= np.abs(s[hi] - query), lo, hi)
    found = np.abs(s[pick] - query) <= max_dt
    return np.where(found, order[pick], -1)


def load_tum_rgbd(folder: Path, trajectory: Path, camera: Camera, root: Path | None = None,
                  max_dt: float = 0.02, name: str = "") -> Sequence:
    """A sequence from a TUM RGB-D folder and a TUM trajectory (T_S_C of any SLAM): one
    keyframe per depth image with a pose within `max_dt` seconds. Image paths are written
    relative to `root` (default: the folder itself), where the sequence is to be saved."""
    folder = Path(folder)
    root = Path(root) if root is not None else folder
    depth_stamps, depth_names = read_image_list(folder / DEPTH_LIST, in_order=True)
    rgb_stamps, rgb_names = read_image_list(folder / RGB_LIST) if (folder / RGB_LIST).is_file() else (np.zeros(0), [])
    pose_stamps, poses = read_tum(trajectory)
    if not len(poses):
        raise FormatError(f"{trajectory}: no poses (an empty trajectory)")
    pose_of = nearest(depth_stamps, pose_stamps, max_dt)
    rgb_of = nearest(depth_stamps, rgb_stamps, max_dt)
    keyframes = []
    for k in np.flatnonzero(pose_of >= 0):
        rgb = os.path.relpath(folder / rgb_names[rgb_of[k]], root) if rgb_of[k] >= 0 else None
        keyframes.append(Keyframe(
            index=len(keyframes),
            stamp=float(depth_stamps[k]),
            T_S_C=tuple(pose_to_tum(poses[pose_of[k]])),
            depth=os.path.relpath(folder / depth_names[k], root),
            rgb=rgb,
        ))
    if not keyframes:
        raise InputError(f"{trajectory}: no pose within {max_dt} s of any of the {len(depth_stamps)} depth images in {folder}")
    meta = SequenceMeta(name=name or folder.name, camera=camera, sensor="depth")
    return Sequence(root=root, meta=meta, keyframes=keyframes)
