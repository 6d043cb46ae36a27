#version 450
#extension GL_GOOGLE_include_directive : require
// The second dispatch of the batch closest-hit query (CPU devices): the rays trace_intersect.comp left unresolved
// (rays.glsl `retry`), walked with the array stack from the first pass's closest hit so far; a few workgroups
// stride over the list.
#include "rays.glsl"
#define ALPHA_BINDING 9     // alpha-tested triangles (Tracer.from_scene); dummies otherwise
#define TEXTURES_BINDING 10
#include "alpha.glsl"
#define BVH_SET 1
#define BVH_BINDING 0
#include "bvh.glsl"

layout(local_size_x = 64) in;
layout(std430, set = 0, binding = 1) buffer Result { HitRecord hits[]; };

void main() {
    for (uint k = gl_GlobalInvocationID.x; k < retry.count; k += gl_NumWorkGroups.x * 64u) {
        uint i = retry.ids[k];
        vec3 o, d;
        float tmax;
        load_ray(i, o, d, tmax);
        HitRecord r = hits[i];   // the first pass's closest hit so far
        BvhHit h = bvh_intersect_full(o, d, 0.0, tmax, BvhHit(r.t, r.prim, r.u, r.v));
        hits[i] = HitRecord(h.prim >= 0 ? h.t : uintBitsToFloat(0x7f800000u), h.prim, h.u, h.v);
    }
}
