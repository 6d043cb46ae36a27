"""Input bounds shared by the scene loaders, the BVH builder and the Tracer (no Vulkan, no numpy)."""

#: Largest vertex (and ray origin) coordinate magnitude accepted. The watertight triangle test (bvh.glsl
#: bvh_triangle_) forms t * det in float32, which grows as the cube of the coordinates: within this bound it stays
#: finite for directions of length >= ~1e-3 (docs/benchmarks.md "Limits" has the measurements).
MAX_COORD = 1e11
