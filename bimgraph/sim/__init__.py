"""The simulator: generated buildings, as-built deviations, a camera walk, a drifting front-end,
plane detections or depth images, and their ground truth (`bimgraph simulate`)."""
