// Ray and hit records of the batch query API (engine/rt/tracer.py packs and unpacks these).
//
// Rays (binding 0) are three tightly packed arrays in one buffer of `capacity` rays (params.capacity): origins as
// 3 floats per ray at [0, 3 capacity), directions at [3 capacity, 6 capacity), tmax at [6 capacity, 7 capacity).
// The host fills them with three contiguous copies (an interleaved record per ray was 16x slower to pack).
// Params (binding 2) is written by the host per batch; its first three words are also the vkCmdDispatchIndirect
// arguments, so the command buffer is recorded once.
#ifndef RAYS_GLSL
#define RAYS_GLSL
struct HitRecord {
    float t;          // +inf on a miss
    int prim;         // original triangle index, -1 on a miss
    float u, v;       // barycentrics of vertices 1 and 2
};

layout(std430, set = 0, binding = 0) readonly buffer Rays { float ray_data[]; };
layout(std430, set = 0, binding = 2) readonly buffer Params { uvec3 groups; uint count; uint capacity; } params;

// Ray i: origin, direction (not normalized: hit = origin + t * direction) and tmax; tmin is 0.
void load_ray(uint i, out vec3 o, out vec3 d, out float tmax) {
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
#endif
