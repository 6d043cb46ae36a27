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
// RESULT_BYTES (queries on CUDA arrays; on GPUs numpy ones too): one byte per ray (0 / 1, a bool array's layout) instead of one uint, the
// workgroup's 64 packed in shared memory into 16 words at params.out_base + 16 * block.
layout(constant_id = 31) const bool RESULT_BYTES = false;
shared uint packed_[16];

void main() {
    uint lane = gl_LocalInvocationID.x;
    uint block = ray_block();
    uint i = block * 64u + lane;
    uint hit = 0u;
    if (i < params.count) {
        vec3 o, d;
        float tmax;
        load_ray(i, o, d, tmax);
        bool unresolved = false;
        if (!CHECK_RAYS || ray_fine(i, o, d, tmax)) {
            hit = bvh_occluded_first(o, d, 0.0, tmax, unresolved) ? 1u : 0u;
        }
        if (RAYS_TEXEL && !RESULT_BYTES) {
            imageStore(occluded_texels, int(i), uvec4(hit));
        } else if (!RESULT_BYTES) {
            occluded[i] = hit;
        }
        if (unresolved) {
            retry_later(i);   // trace_occluded_retry.comp answers it
        }
    }
    if (RESULT_BYTES) {   // (a constant: every invocation reaches the barriers)
        if (lane < 16u) packed_[lane] = 0u;
        barrier();
        if (hit != 0u) atomicOr(packed_[lane >> 2u], 1u << (8u * (lane & 3u)));
        barrier();
        if (lane < 16u && block * 64u + 4u * lane < params.count) {
            occluded[params.out_base + block * 16u + lane] = packed_[lane];
        }
    }
}
