// Scene textures: every texture is a layer of one of MAX_TEXTURE_ARRAYS 2D array textures (engine/passes/textures.py),
// named by a handle = array << 16 | layer (TEXTURE_NONE: none, samples as white).
//
// Before including, define TEXTURES_SET, TEXTURES_BINDING (where the sampler2DArray[MAX_TEXTURE_ARRAYS] goes) and
// TEXTURE_ARRAYS_ID (the constant_id of TEXTURE_ARRAYS, the number of arrays the scene has: sampling code past it
// is dropped when the pipeline is specialized).
//
// Each array is sampled with a constant index, in a block taken where the array's bit is in `mask`: with a mask
// that is uniform over the workgroup (the OR of texture_bit() of its pixels) the branch is uniform, every lane
// samples the array and keeps the texel if its handle names it. Not textures[handle >> 16]: without descriptor
// indexing a dynamically indexed array must be uniform, and lavapipe 22.3 was seen to sample the wrong texture.
#ifndef TEXTURES_GLSL
#define TEXTURES_GLSL

#include "interface.glsl"

layout(constant_id = TEXTURE_ARRAYS_ID) const int TEXTURE_ARRAYS = MAX_TEXTURE_ARRAYS;
layout(set = TEXTURES_SET, binding = TEXTURES_BINDING) uniform sampler2DArray textures[MAX_TEXTURE_ARRAYS];

// The bit of the array a handle names (0 for TEXTURE_NONE).
uint texture_bit(uint handle) {
    return handle == TEXTURE_NONE ? 0u : 1u << (handle >> 16);
}

#define TEXTURE_BLOCK_(k, CALL)                                                                                  \
    if (k < TEXTURE_ARRAYS && (mask & (1u << k)) != 0u) {                                                      \
        vec4 t_ = CALL(k);                                                                                      \
        if (a == k) r = t_;                                                                                     \
    }
#define TEXTURE_BLOCKS_(CALL)                                                                                    \
    TEXTURE_BLOCK_(0, CALL) TEXTURE_BLOCK_(1, CALL) TEXTURE_BLOCK_(2, CALL) TEXTURE_BLOCK_(3, CALL)               \
    TEXTURE_BLOCK_(4, CALL) TEXTURE_BLOCK_(5, CALL) TEXTURE_BLOCK_(6, CALL) TEXTURE_BLOCK_(7, CALL)               \
    TEXTURE_BLOCK_(8, CALL) TEXTURE_BLOCK_(9, CALL) TEXTURE_BLOCK_(10, CALL) TEXTURE_BLOCK_(11, CALL)             \
    TEXTURE_BLOCK_(12, CALL) TEXTURE_BLOCK_(13, CALL) TEXTURE_BLOCK_(14, CALL) TEXTURE_BLOCK_(15, CALL)

#define TEXTURE_GRAD_(k) textureGrad(textures[k], c, dx, dy)
#define TEXTURE_LOD_(k) textureLod(textures[k], c, lod)

// The texture at uv with explicit UV derivatives (one pixel right, one pixel down): trilinear, and anisotropic
// where the sampler has it. `mask` must include texture_bit(handle).
vec4 sample_texture_masked(uint handle, vec2 uv, vec2 dx, vec2 dy, uint mask) {
    uint a = handle >> 16;
    vec3 c = vec3(uv, float(handle & 0xFFFFu));
    vec4 r = vec4(1.0);
    TEXTURE_BLOCKS_(TEXTURE_GRAD_)
    return r;
}

vec4 sample_texture(uint handle, vec2 uv, vec2 dx, vec2 dy) {
    return sample_texture_masked(handle, uv, dx, dy, texture_bit(handle));
}

// At a fixed mip level (ray passes, which have no pixel footprint).
vec4 sample_texture_lod(uint handle, vec2 uv, float lod, uint mask) {
    uint a = handle >> 16;
    vec3 c = vec3(uv, float(handle & 0xFFFFu));
    vec4 r = vec4(1.0);
    TEXTURE_BLOCKS_(TEXTURE_LOD_)
    return r;
}

#endif
