"""Input bounds shared by the scene loaders, the BVH builder and the Tracer (no Vulkan, no numpy)."""

#: Largest vertex (and ray origin) coordinate magnitude accepted. The watertight triangle test (bvh.glsl
#: bvh_triangle_) forms t * det in float32, which grows as the cube of the coordinates: within this bound it stays
#: finite for directions of length >= ~1e-3 (docs/limits.md "Coordinate limits" has the measurements).
MAX_COORD = 1e11

#: Smallest largest-component magnitude of a ray direction (2^-63, about 1.1e-19). The traversal (bvh.glsl
#: bvh_make_ray_) puts components below 1e-30 at +-1e-30 in 1 / d; a direction whose largest component is not far
#: above that is bent enough to miss boxes its ray crosses (silent misses below about 1e-27). 2^-63 is an exponent
#: test on the float32 bits (exponent field >= 64: its bit 6 or 7 set).
MIN_DIRECTION = 2.0**-63
