#version 450
#extension GL_GOOGLE_include_directive : require
// Batch closest-point query (engine/rt/closest.py): one point per invocation, read where rays.glsl keeps ray
// origins; writes a HitRecord (distance, primitive id, barycentrics of the nearest point).
#include "rays.glsl"
#define BVH_SET 1
#define BVH_BINDING 0
#include "bvh.glsl"
#include "bvh_point.glsl"

layout(local_size_x = 64) in;
layout(std430, set = 0, binding = 1) buffer Result { HitRecord hits[]; };

void main() {
    uint i = ray_block() * 64u + gl_LocalInvocationID.x;
    if (i >= params.count) return;
    uint k = 3u * i;
    vec3 p = vec3(ray_data[k], ray_data[k + 1u], ray_data[k + 2u]);
    BvhClosest c = bvh_closest(p);
    hits[i] = HitRecord(sqrt(c.d2), c.prim, c.u, c.v);
}
