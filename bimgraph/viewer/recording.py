"""Where a Rerun recording goes: a file, a newly spawned viewer, or both."""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

from bimgraph.errors import ConfigError, InputError
from bimgraph.files import ensure_folder
from bimgraph.sequence.format import Camera
from bimgraph.viewer import blueprint as bp

# the first bytes of an .rrd file (RRF2 since rerun 0.17, RRF0 and RRF1 before)
_RRD_MAGIC = b"RRF"


def check_viewer_can_open() -> None:
    """Refuse to spawn the Rerun viewer where it cannot open: it is a window, and without a
    display (Linux: no DISPLAY, WAYLAND_DISPLAY or WAYLAND_SOCKET) it exits while the caller
    waits for it forever; without its executable on PATH rerun raises a RuntimeError."""
    if sys.platform.startswith("linux") and not any(os.environ.get(v) for v in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET")):
        raise ConfigError("no display to open the Rerun viewer on (DISPLAY and WAYLAND_DISPLAY are unset): "
                          "save the recording with --rrd FILE instead, and open it where there is one: rerun FILE")
    if shutil.which("rerun") is None:
        raise ConfigError("no Rerun viewer (`rerun`) on PATH: activate the environment bimgraph is installed in, "
                          "or save the recording with --rrd FILE")


def prepare_target(path: Path) -> None:
    """Make the folder of `path`; an InputError if `path` cannot take the recording, found
    before it is made (rerun's own error would come with its buffer's warnings): a folder, a
    file that cannot be written, or an existing file that is not a Rerun recording (a run's
    own inputs or outputs, given by a slip of the shell, would be lost). An existing file is
    left as it is."""
    ensure_folder(path.parent, path)
    if path.is_dir():
        raise InputError(f"{path}: is a folder, not a recording file")
    existed = path.exists()
    try:
        with open(path, "ab+") as f:
            f.seek(0)
            head = f.read(len(_RRD_MAGIC))
    except OSError as err:
        raise InputError(f"{path}: cannot write the recording ({err.strerror})") from None
    if not existed:
        path.unlink(missing_ok=True)
    elif head and head != _RRD_MAGIC:
        raise InputError(f"{path}: exists and is not a Rerun recording; the recording would replace it")


def open_recording(rrd: Path | None = None, spawn: bool = False, camera: Camera | None = None,
                   application_id: str = "bimgraph"):
    """A recording stream saving to `rrd`, streaming to a newly spawned viewer, or both;
    `camera` frames the camera view of the layout."""
    import rerun as rr

    if spawn:
        check_viewer_can_open()
    recording = rr.RecordingStream(application_id)
    blueprint = bp.default_blueprint(None if camera is None else (camera.width, camera.height))
    if rrd is not None:
        prepare_target(Path(rrd))
    if rrd is not None and spawn:
        recording.spawn(connect=False)
        recording.set_sinks(rr.GrpcSink(), rr.FileSink(str(rrd)), default_blueprint=blueprint)
    elif rrd is not None:
        recording.save(rrd, default_blueprint=blueprint)
    elif spawn:
        recording.spawn(default_blueprint=blueprint)
    return recording
