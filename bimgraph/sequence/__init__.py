"""Sequences: keyframes with front-end poses and detected planes, and their loaders."""
