#version 450
#extension GL_GOOGLE_include_directive : require
// The second dispatch of the batch any-hit query (CPU devices): the rays trace_occluded.comp left unresolved
// (rays.glsl `retry`), walked with the array stack; a few workgroups stride over the list.
#include "rays.glsl"
#define ALPHA_BINDING 9     // alpha-tested triangles (Tracer.from_scene); dummies otherwise
#define TEXTURES_BINDING 10
#include "alpha.glsl"
#define BVH_SET 1
#define BVH_BINDING 0
#include "bvh.glsl"

layout(local_size_x = 64) in;
layout(std430, set = 0, binding = 1) buffer Result { uint occluded[]; };
// RESULT_BYTES (trace_occluded.comp): one byte per ray; the first pass wrote 0 for the rays walked here
layout(constant_id = 31) const bool RESULT_BYTES = false;

void main() {
    for (uint k = gl_GlobalInvocationID.x; k < retry.count; k += gl_NumWorkGroups.x * 64u) {
        uint i = retry.ids[k];
        vec3 o, d;
        float tmax;
        load_ray(i, o, d, tmax);
        bool hit = bvh_occluded_full(o, d, 0.0, tmax);
        if (!RESULT_BYTES) {
            occluded[i] = hit ? 1u : 0u;
        } else if (hit) {
            atomicOr(occluded[params.out_base + (i >> 2u)], 1u << (8u * (i & 3u)));
        }
    }
}
