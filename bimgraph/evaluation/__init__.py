"""Evaluation: the seed paper's baselines, ground-truth metrics and the reproduction table."""
