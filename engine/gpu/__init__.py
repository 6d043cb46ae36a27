"""The scene on the GPU: uploads and the BVH's buffers and traversal constants, shared by passes and the Tracer."""
from .bvh import LAYOUTS, SceneBVH, bvh_descriptor_set, bvh_layout, bvh_spec, compresses

__all__ = ["LAYOUTS", "SceneBVH", "bvh_descriptor_set", "bvh_layout", "bvh_spec", "compresses"]
