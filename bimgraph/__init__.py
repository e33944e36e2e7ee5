"""bimgraph: a BIM-aware SLAM backend.

Data path: IFC -> BIM plane map (`bimgraph.bim`) -> sequence (`bimgraph.sequence`) ->
association -> graph (`bimgraph.backend`, `factors`) -> results -> viewer.
"""

__version__ = "0.1.0"
