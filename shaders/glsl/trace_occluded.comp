#version 450
#extension GL_GOOGLE_include_directive : require
// Batch any-hit query: one ray per invocation, writes 1 if anything lies in [0, tmax] (passes: rays.glsl).
#include "rays.glsl"
#define BVH_SET 1
#define BVH_BINDING 0
#include "bvh.glsl"

layout(local_size_x = 64) in;
layout(std430, set = 0, binding = 1) writeonly buffer Result { uint occluded[]; };

void main() {
    vec3 o, d;
    float tmax;
    if (TRACE_PASS == 2) {
        for (uint k = gl_GlobalInvocationID.x; k < retry.count; k += gl_NumWorkGroups.x * 64u) {
            uint i = retry.ids[k];
            load_ray(i, o, d, tmax);
            occluded[i] = bvh_occluded_full(o, d, 0.0, tmax) ? 1u : 0u;
        }
        return;
    }
    uint i = gl_GlobalInvocationID.x;
    if (i >= params.count) return;
    load_ray(i, o, d, tmax);
    bool hit;
    if (TRACE_PASS == 1) {
        bool unresolved;
        hit = bvh_occluded_first(o, d, 0.0, tmax, unresolved);
        if (unresolved) {
            retry_later(i);
        }
    } else {
        hit = bvh_occluded(o, d, 0.0, tmax);
    }
    occluded[i] = hit ? 1u : 0u;
}
