"""Planes from depth images: the real-time extractor."""
