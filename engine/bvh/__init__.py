"""Host BVH: `build_bvh(vertices, faces)` -> `BVH` with GPU-ready `nodes` and `tris` (layout in layout.py)."""

from .builder import BVH, DEFAULT_MAX_DEPTH, build_bvh
from .layout import LEAF_BIT, NODE_BYTES, NODE_DTYPE, TRI_BYTES, TRI_DTYPE

__all__ = [
    "BVH",
    "build_bvh",
    "DEFAULT_MAX_DEPTH",
    "LEAF_BIT",
    "NODE_BYTES",
    "NODE_DTYPE",
    "TRI_BYTES",
    "TRI_DTYPE",
]
