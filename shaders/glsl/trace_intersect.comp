#version 450
#extension GL_GOOGLE_include_directive : require
// Batch closest-hit query: one ray per invocation, writes t, primitive id and barycentrics (the rare ray left
// unresolved goes to trace_intersect_retry.comp).
#include "rays.glsl"
#define ALPHA_BINDING 9     // alpha-tested triangles (Tracer.from_scene); dummies otherwise
#define TEXTURES_BINDING 10
#include "alpha.glsl"
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
    uint i = ray_block() * 64u + gl_LocalInvocationID.x;
    if (i >= params.count) return;
    load_ray(i, o, d, tmax);
    if (CHECK_RAYS && !ray_fine(i, o, d, tmax)) {
        hits[i] = HitRecord(uintBitsToFloat(0x7f800000u), -1, 0.0, 0.0);   // (the query raises: never read)
        return;
    }
    bool unresolved;
    hits[i] = record_(bvh_intersect_first(o, d, 0.0, tmax, unresolved));
    if (unresolved) {
        retry_later(i);   // trace_intersect_retry.comp finishes it from this closest hit so far
    }
}
