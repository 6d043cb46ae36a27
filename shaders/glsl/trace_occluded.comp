#version 450
#extension GL_GOOGLE_include_directive : require
// Batch any-hit query: one ray per invocation, writes 1 if anything lies in [0, tmax] (the rare ray left
// unresolved goes to trace_occluded_retry.comp).
#include "rays.glsl"
#define ALPHA_BINDING 9     // alpha-tested triangles (Tracer.from_scene); dummies otherwise
#define TEXTURES_BINDING 10
#include "alpha.glsl"
#define BVH_SET 1
#define BVH_BINDING 0
#include "bvh.glsl"

layout(local_size_x = 64) in;
layout(std430, set = 0, binding = 1) writeonly buffer Result { uint occluded[]; };

void main() {
    vec3 o, d;
    float tmax;
    uint i = ray_block() * 64u + gl_LocalInvocationID.x;
    if (i >= params.count) return;
    load_ray(i, o, d, tmax);
    bool unresolved;
    uint hit = bvh_occluded_first(o, d, 0.0, tmax, unresolved) ? 1u : 0u;
    if (RAYS_TEXEL) {
        imageStore(occluded_texels, int(i), uvec4(hit));
    } else {
        occluded[i] = hit;
    }
    if (unresolved) {
        retry_later(i);   // trace_occluded_retry.comp answers it
    }
}
