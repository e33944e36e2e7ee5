"""Entity paths of a bimgraph recording and its default Rerun layout: the BIM frame in 3-D,
the camera's view, and the time series."""

from __future__ import annotations

WORLD = "world"
FACES = "world/bim/faces"
LABELS = "world/bim/labels"
WIDTHS = "world/bim/widths"
THICKNESSES = "world/bim/thicknesses"
RAW = "world/trajectory/raw"
CORRECTED = "world/trajectory/corrected"
TRUTH = "world/trajectory/groundtruth"
FINAL = "world/trajectory/final"
SLAM = "world/slam"
CAMERA = "world/camera"
IMAGE = "world/camera/image"
PLANES = "world/camera/planes"
PLANES_2D = "world/camera/image/planes"
ASSOCIATIONS = "world/associations"
METRICS = "metrics"

KEYFRAME = "keyframe"
STAMP = "stamp"

# Time series, one view each: (entity under METRICS, tab name). Grouped by unit.
SERIES = (
    ("position_error_cm", "position error (cm)"),
    ("extrinsic_deg", "extrinsic (deg)"),
    ("extrinsic_cm", "extrinsic (cm)"),
    ("latency_ms", "latency (ms)"),
    ("associations", "associations"),
)

# Logged one segment per keyframe; the 3-D view accumulates them from the start of the
# timeline up to the cursor, so the whole line shows without being logged again and again.
TRAILS = (RAW, CORRECTED, TRUTH)


def default_blueprint(image_size: tuple[int, int] | None = None):
    """The layout; `image_size` (width, height in pixels) frames the camera view on the
    whole image rather than on what happens to be drawn in it."""
    import rerun.blueprint as rrb

    trail = rrb.VisibleTimeRanges(
        timeline=KEYFRAME, start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.cursor_relative()
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin=WORLD, name="BIM frame", overrides={path: trail for path in TRAILS}),
            rrb.Vertical(
                rrb.Spatial2DView(origin=IMAGE, name="camera", visual_bounds=None if image_size is None else
                                  rrb.VisualBounds2D(x_range=[0, image_size[0]], y_range=[0, image_size[1]])),
                rrb.Tabs(
                    *(rrb.TimeSeriesView(origin=f"{METRICS}/{group}", name=name) for group, name in SERIES),
                ),
            ),
            column_shares=[3, 2],
        ),
        # "following" keeps the cursor on the newest keyframe: live runs scroll, and a
        # finished recording opens at its end, every trail drawn.
        rrb.TimePanel(timeline=KEYFRAME, play_state="following", expanded=False),
        collapse_panels=True,
    )
