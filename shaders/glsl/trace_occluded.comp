#version 450
#extension GL_GOOGLE_include_directive : require
// Batch any-hit query: one ray per invocation, writes 1 if anything lies in [tmin, tmax].
#include "rays.glsl"
#define BVH_SET 1
#define BVH_BINDING 0
#include "bvh.glsl"

layout(local_size_x = 64) in;
layout(std430, set = 0, binding = 0) readonly buffer Rays { Ray rays[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Result { uint occluded[]; };
// Written by the host per batch; also the vkCmdDispatchIndirect arguments, so the command buffer is recorded once.
layout(std430, set = 0, binding = 2) readonly buffer Params { uvec3 groups; uint count; } params;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= params.count) return;
    Ray r = rays[i];
    occluded[i] = bvh_occluded(r.origin.xyz, r.direction.xyz, r.origin.w, r.direction.w) ? 1u : 0u;
}
