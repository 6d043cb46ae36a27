#version 450
#extension GL_GOOGLE_include_directive : require
// Batch closest-hit query: one ray per invocation, writes t, primitive id and barycentrics (passes: rays.glsl).
#include "rays.glsl"
#define BVH_SET 1
#define BVH_BINDING 0
#include "bvh.glsl"

layout(local_size_x = 64) in;
layout(std430, set = 0, binding = 1) buffer Result { HitRecord hits[]; };

HitRecord record_(BvhHit h) {
    return HitRecord(h.prim >= 0 ? h.t : uintBitsToFloat(0x7f800000u), h.prim, h.u, h.v);
}

void main() {
    vec3 o, d;
    float tmax;
    if (TRACE_PASS == 2) {
        for (uint k = gl_GlobalInvocationID.x; k < retry.count; k += gl_NumWorkGroups.x * 64u) {
            uint i = retry.ids[k];
            load_ray(i, o, d, tmax);
            HitRecord r = hits[i];   // the first pass's closest hit so far
            BvhHit so_far = BvhHit(r.t, r.prim, r.u, r.v);
            hits[i] = record_(bvh_intersect_full(o, d, 0.0, tmax, so_far));
        }
        return;
    }
    uint i = gl_GlobalInvocationID.x;
    if (i >= params.count) return;
    load_ray(i, o, d, tmax);
    BvhHit h;
    if (TRACE_PASS == 1) {
        bool unresolved;
        h = bvh_intersect_first(o, d, 0.0, tmax, unresolved);
        if (unresolved) {
            retry_later(i);
        }
    } else {
        h = bvh_intersect(o, d, 0.0, tmax);
    }
    hits[i] = record_(h);
}
