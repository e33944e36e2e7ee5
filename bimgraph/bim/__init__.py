"""The BIM side: IFC models to per-room wall-face planes in frame B."""
