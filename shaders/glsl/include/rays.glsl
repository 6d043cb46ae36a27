// Ray and hit records of the batch query API (engine/rt/tracer.py packs and unpacks these).
//
// Rays (binding 0) are three tightly packed arrays in one buffer of `capacity` rays (params.capacity): origins as
// 3 floats per ray at [0, 3 capacity), directions at [3 capacity, 6 capacity), tmax at [6 capacity, 7 capacity).
// The host fills them with three contiguous copies (an interleaved record per ray is far slower to pack).
// Params (binding 2) is written by the host per batch; its first three words are also the vkCmdDispatchIndirect
// arguments, so the command buffer is recorded once.
#ifndef RAYS_GLSL
#define RAYS_GLSL
#include "shares.glsl"
struct HitRecord {
    float t;          // +inf on a miss
    int prim;         // original triangle index, -1 on a miss
    float u, v;       // barycentrics of vertices 1 and 2
};

layout(std430, set = 0, binding = 0) readonly buffer Rays { float ray_data[]; };
layout(std430, set = 0, binding = 2) readonly buffer Params {
    uvec3 groups;
    uint count;
    uint capacity;
    uint shares;  // how many contiguous shares of the workgroups the device runs in parallel (see ray_block)
    uint out_base;  // where this batch's results start in the result buffer, in words (RESULT_BYTES only)
} params;
// The same three arrays as uniform texel buffers: origins and directions as RGB32F texels, tmax as R32F.
layout(set = 0, binding = 4) uniform samplerBuffer ray_origins;
layout(set = 0, binding = 5) uniform samplerBuffer ray_directions;
layout(set = 0, binding = 6) uniform samplerBuffer ray_tmax;
// The result buffer (binding 1) as storage texel buffers: one uint per ray (occlusion) and one HitRecord as an
// RGBA32UI texel per ray (closest hit).
layout(set = 0, binding = 7, r32ui) uniform writeonly restrict uimageBuffer occluded_texels;
layout(set = 0, binding = 8, rgba32ui) uniform writeonly restrict uimageBuffer hit_texels;
// RAYS_TEXEL (set by engine/rt/tracer.py): read the rays and write the results through the texel buffers. llvmpipe
// 22.3 loads and stores a storage buffer lane by lane (a scalar loop over the 8 lanes with a bounds check per
// element, 7 of them per ray to load it); its texel fetches and image stores are vector code. On for the occlusion
// kernels on CPU devices, where it is faster; off for closest hits, where it is not.
layout(constant_id = 13) const bool RAYS_TEXEL = false;

// The block of 64 rays this workgroup traces (shares.glsl; params.shares: the device's worker threads).
uint ray_block() {
    return share_block(gl_WorkGroupID.x, gl_NumWorkGroups.x, params.shares);
}

// Ray i: origin, direction (not normalized: hit = origin + t * direction) and tmax; tmin is 0.
void load_ray(uint i, out vec3 o, out vec3 d, out float tmax) {
    if (RAYS_TEXEL) {
        o = texelFetch(ray_origins, int(i)).xyz;
        d = texelFetch(ray_directions, int(i)).xyz;
        tmax = texelFetch(ray_tmax, int(i)).x;
        return;
    }
    uint c3 = 3u * params.capacity;
    uint k = 3u * i;
    o = vec3(ray_data[k], ray_data[k + 1u], ray_data[k + 2u]);
    d = vec3(ray_data[c3 + k], ray_data[c3 + k + 1u], ray_data[c3 + k + 2u]);
    tmax = ray_data[2u * c3 + i];
}
// The rays a kernel's register stack left unresolved (bvh.glsl bvh_*_first; CPU devices only, where the stack can
// overflow): the batch kernels append them here, and trace_*_retry.comp, a second small dispatch, walks them again
// with the array stack. The host zeroes retry.count before each batch (a fill recorded in the same command buffer).
layout(std430, set = 0, binding = 3) buffer Retry { uint count; uint ids[]; } retry;

void retry_later(uint i) {
    retry.ids[atomicAdd(retry.count, 1u)] = i;
}

// CHECK_RAYS (queries on CUDA arrays, engine/rt/cuda_arrays.py, whose rays the host never sees, and numpy ones on
// GPUs, whose packing then only copies): each kernel checks its ray as engine/rt/checks.py does on the host and
// traces only fine ones; the first bad ray of each kind goes to ray_errors (origins, directions, tmax; 0xffffffff:
// none), which the host sets before and reads after the batch.
layout(constant_id = 30) const bool CHECK_RAYS = false;
#define RAY_MAX_COORD 1e11   // engine.limits.MAX_COORD
layout(std430, set = 0, binding = 12) buffer RayErrors { uint first_bad[4]; } ray_errors;

// Whether ray i is fine: origins finite and within +-MAX_COORD, directions finite and with a component of magnitude
// >= 2^-63 (engine.limits.MIN_DIRECTION: bvh_make_ray_ bends shorter ones), tmax not NaN. Records the ray when not.
bool ray_fine(uint i, vec3 o, vec3 d, float tmax) {
    vec3 ad = abs(d);
    bool o_ok = all(lessThanEqual(abs(o), vec3(RAY_MAX_COORD)));   // (false for NaN)
    bool d_ok = all(lessThanEqual(ad, vec3(uintBitsToFloat(0x7f7fffffu))))
                && any(greaterThanEqual(ad, vec3(uintBitsToFloat(0x20000000u))));
    bool t_ok = !isnan(tmax);
    if (o_ok && d_ok && t_ok) return true;
    if (!o_ok) atomicMin(ray_errors.first_bad[0], i);
    if (!d_ok) atomicMin(ray_errors.first_bad[1], i);
    if (!t_ok) atomicMin(ray_errors.first_bad[2], i);
    return false;
}
#endif
