"""A PNG screenshot of the Rerun viewer showing a recording, without a display.

Spawns a headless Rerun viewer, opens the recording, moves the time cursor to its last
keyframe, waits until the viewer has loaded it, and saves the screenshot.

    python scripts/screenshot_viewer.py out/run.rrd docs/viewer.png [--size 1600x900]

Needs a graphics stack: a GPU, or Mesa's software Vulkan (Debian/Ubuntu:
`apt-get install mesa-vulkan-drivers`; llvmpipe's OpenGL alone is not enough for rerun 0.41).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("RERUN_ANALYTICS", "0")
os.environ.setdefault("RUST_LOG", "error")  # no notification toasts over the views
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _last_keyframe(rrd: Path) -> int:
    from rerun.chunk import RrdReader

    last = 0
    for chunk in RrdReader(str(rrd)).store().stream():
        batch = chunk.to_record_batch()
        if "keyframe" in batch.schema.names and chunk.num_rows:
            last = max(last, max(v for v in batch.column("keyframe").to_pylist() if v is not None))
    return last


def screenshot(rrd: Path, png: Path, width: int = 1600, height: int = 900, settle_s: float = 3.0,
               renderer: str = "vulkan") -> None:
    from rerun.experimental import ViewerClient

    from bimgraph.viewer.rrd import rerun_binary

    last = _last_keyframe(rrd)
    port = _free_port()
    process = subprocess.Popen([str(rerun_binary()), "--headless", "--hide-welcome-screen", "--port", str(port),
                                "--renderer", renderer, "--window-size", f"{width}x{height}"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        viewer = _connect(ViewerClient, port, process)
        viewer.open(str(Path(rrd).resolve()))
        viewer.set_time("keyframe", sequence=last, play_state="paused")
        time.sleep(settle_s)  # let the chunks stream in and the views lay out
        png.parent.mkdir(parents=True, exist_ok=True)
        png.write_bytes(viewer.take_screenshot())
    finally:
        # the `rerun` entry point runs the viewer binary as a child: end the whole group (gone
        # already where the viewer could not start)
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGTERM)
        process.wait(timeout=10)


def _connect(client, port: int, process, timeout_s: float = 30.0):
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return client.connect(f"rerun+http://127.0.0.1:{port}/proxy")
        except Exception:
            if process.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError("the headless rerun viewer did not start (no graphics adapter?)") from None
            time.sleep(0.5)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("rrd", type=Path)
    parser.add_argument("png", type=Path)
    parser.add_argument("--size", default="1600x900", help="window size in logical points, WxH")
    parser.add_argument("--settle", type=float, default=3.0, help="seconds to wait after loading")
    parser.add_argument("--renderer", default="vulkan", help="graphics backend of the viewer (vulkan or gl)")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    try:
        screenshot(args.rrd, args.png, width, height, args.settle, args.renderer)
    except RuntimeError as err:
        sys.exit(f"error: {err}")
    print(f"{args.png}: screenshot of {args.rrd}")


if __name__ == "__main__":
    main()
