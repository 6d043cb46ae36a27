"""The scene on the GPU, shared by the renderer's passes and the Tracer: the BVH's buffers and traversal constants
(bvh.py, refit.py, tlas.py; re-exported here), the raster geometry and instances (scene.py), the draw tables
(draws.py), the materials and the rays' alpha test (materials.py) and the texture arrays (textures.py)."""

from .bvh import (
    LAYOUTS,
    InstancedBVH,
    SceneBVH,
    bvh_descriptor_set,
    bvh_layout,
    bvh_spec,
    compresses,
    is_instanced,
    scene_bvh,
)

__all__ = [
    "LAYOUTS",
    "SceneBVH",
    "InstancedBVH",
    "bvh_descriptor_set",
    "bvh_layout",
    "bvh_spec",
    "compresses",
    "is_instanced",
    "scene_bvh",
]
