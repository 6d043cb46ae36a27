"""The scene on the GPU: uploads and the BVH's buffers and traversal constants, shared by passes and the Tracer."""
from .bvh import (LAYOUTS, InstancedBVH, SceneBVH, bvh_descriptor_set, bvh_layout, bvh_spec, compresses, is_instanced,
                  scene_bvh)

__all__ = ["LAYOUTS", "SceneBVH", "InstancedBVH", "bvh_descriptor_set", "bvh_layout", "bvh_spec", "compresses",
           "is_instanced", "scene_bvh"]
