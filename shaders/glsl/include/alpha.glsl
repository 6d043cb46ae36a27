// Alpha-tested triangles in ray passes: bvh.glsl's leaf test calls bvh_alpha_passes for a candidate hit on a
// triangle whose BVH record has v1.w = 1 + its alpha record (engine/passes/gbuffer.py `alpha_records`); the hit
// counts only where the texture's alpha at the hit's UV, at mip level 0, reaches the record's threshold (the
// material's cutoff / base alpha). BLEND's records hold -(1 + base alpha): where the includer defines ALPHA_RANDOM
// (a function returning a uniform number in [0, 1): the path tracer) the hit counts with probability alpha =
// texture alpha x base alpha, a stochastic blend that rays of every kind see alike (pass-through 1 - alpha, and
// shadow rays' transmittance 1 - alpha in expectation); elsewhere it is cut out at 0.5 as in the raster. Opaque
// triangles (v1.w = 0) skip the test.
//
// Include before bvh.glsl, after defining ALPHA_BINDING (the records) and TEXTURES_BINDING (the texture arrays),
// both in set 0. ALPHA_TEST (specialization constant 24) is false for scenes without alpha-tested materials: the
// test is then compiled out.
#ifndef ALPHA_GLSL
#define ALPHA_GLSL

#define TEXTURES_SET 0
#define TEXTURE_ARRAYS_ID 23   // (20-22: bvh.glsl's instancing constants)
#include "textures.glsl"

layout(constant_id = 24) const bool ALPHA_TEST = false;
// 2 texels per alpha-tested triangle: (uv0, uv1), (uv2, texture handle bits, alpha threshold)
layout(set = 0, binding = ALPHA_BINDING) uniform samplerBuffer alpha_tris;

bool bvh_alpha_passes(uint record, float u, float v) {
    vec4 a = texelFetch(alpha_tris, 2 * int(record)), b = texelFetch(alpha_tris, 2 * int(record) + 1);
    vec2 uv = (1.0 - u - v) * a.xy + u * a.zw + v * b.xy;
    uint handle = floatBitsToUint(b.z);
    float alpha = sample_texture_lod(handle, uv, 0.0, texture_bit(handle)).a;
    if (b.w >= 0.0) return alpha >= b.w;
    float base = -b.w - 1.0;   // BLEND
#ifdef ALPHA_RANDOM
    return ALPHA_RANDOM() < alpha * base;
#else
    return alpha * base >= 0.5;
#endif
}

#define BVH_ALPHA_TEST ALPHA_TEST

#endif
