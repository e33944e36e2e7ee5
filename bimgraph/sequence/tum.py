"""TUM trajectory files: one pose a line, `stamp tx ty tz qx qy qz qw`, as evo and the TUM
RGB-D benchmark read them. Lines starting with `#` are comments."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bimgraph.errors import FormatError
from bimgraph.files import read_text, write_atomic
from bimgraph.geometry import pose_from_tum, pose_to_tum


def format_tum(stamps, poses) -> str:
    """The file's text; fixed precision so that the same poses always give the same bytes."""
    lines = ["# stamp tx ty tz qx qy qz qw"]
    for stamp, T in zip(stamps, poses):
        values = " ".join(f"{v:.9f}" for v in pose_to_tum(np.asarray(T)))
        lines.append(f"{float(stamp):.6f} {values}")
    return "\n".join(lines) + "\n"


def write_tum(path: Path, stamps, poses) -> None:
    if len(stamps) != len(poses):
        raise ValueError(f"{len(stamps)} stamps for {len(poses)} poses")
    write_atomic(path, format_tum(stamps, poses))


# the year 5138 in Unix seconds: a stamp past it is in smaller units (rerun's own bound)
_MAX_STAMP_S = 1e11


def not_seconds(stamp: float) -> str | None:
    """Why `stamp` cannot be in seconds, or None. Milli- or nanoseconds would pass through a
    run rounded by float64 (the outputs' stamps then no longer those of the input), and the
    viewer's time axis refuses them: rerun takes seconds since the Unix epoch."""
    if abs(stamp) < _MAX_STAMP_S:
        return None
    unit = "nanoseconds" if abs(stamp) >= 1e17 else "microseconds" if abs(stamp) >= 1e14 else "milliseconds"
    return (f"{stamp:.17g} is not in seconds (it looks like {unit}, if Unix time): stamps are seconds, such as "
            "1700000000.123456 (divide milliseconds by 1e3, microseconds by 1e6, nanoseconds by 1e9)")


def data_lines(path: Path):
    """(line number, fields) of every line of a TUM text file that is neither blank nor a
    `#` comment; fields split at white space (and commas, as some tools write)."""
    for lineno, line in enumerate(read_text(path).splitlines(), start=1):
        line = line.strip()
        if line and not line.startswith("#"):
            yield lineno, line.replace(",", " ").split()


def read_tum(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Stamps (N,) and poses (N, 4, 4); a FormatError names the bad line."""
    stamps, poses = [], []
    for lineno, fields in data_lines(path):
        if len(fields) != 8:
            raise FormatError(f"{path}: line {lineno}: expected 8 values (stamp tx ty tz qx qy qz qw), got {len(fields)}")
        try:
            values = [float(f) for f in fields]
        except ValueError:
            raise FormatError(f"{path}: line {lineno}: not a number") from None
        if not np.all(np.isfinite(values)):
            name = ("stamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw")[int(np.flatnonzero(~np.isfinite(values))[0])]
            raise FormatError(f"{path}: line {lineno}: {name} is not a finite number")
        if (why := not_seconds(values[0])) is not None:
            raise FormatError(f"{path}: line {lineno}: stamp {why}")
        q_norm = np.linalg.norm(values[4:8])
        if abs(q_norm - 1.0) > 1e-3:
            raise FormatError(f"{path}: line {lineno}: quaternion has norm {q_norm:.4f}, must be unit")
        stamps.append(values[0])
        poses.append(pose_from_tum(values[1:]))
    return np.array(stamps), np.array(poses).reshape(-1, 4, 4)
