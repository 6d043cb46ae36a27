#version 450
#extension GL_GOOGLE_include_directive : require
// Batch closest-hit query: one ray per invocation, writes t, primitive id and barycentrics.
#include "rays.glsl"
#define BVH_SET 1
#define BVH_BINDING 0
#include "bvh.glsl"

layout(local_size_x = 64) in;
layout(std430, set = 0, binding = 1) writeonly buffer Result { HitRecord hits[]; };

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= params.count) return;
    vec3 o, d;
    float tmax;
    load_ray(i, o, d, tmax);
    BvhHit h = bvh_intersect(o, d, 0.0, tmax);
    hits[i] = HitRecord(h.prim >= 0 ? h.t : uintBitsToFloat(0x7f800000u), h.prim, h.u, h.v);
}
