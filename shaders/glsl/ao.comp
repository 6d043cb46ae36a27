#version 450
#extension GL_GOOGLE_include_directive : require
// Ambient occlusion from the G-buffer: `frame.ao_samples` cosine-weighted hemisphere rays of length
// `frame.ao_radius` per pixel; writes the unoccluded fraction (1 = open). The reference mode runs `pc.count` of
// `pc.total` samples per dispatch and adds them up over several dispatches, optionally a band of rows each.
#include "common.glsl"
FRAME_BLOCK
#include "sampling.glsl"
#include "rayutil.glsl"
#define ALPHA_BINDING 6
#define TEXTURES_BINDING 7
#include "alpha.glsl"
#define BVH_SET 1
#define BVH_BINDING 0
#include "bvh.glsl"
#include "shares.glsl"

layout(local_size_x = 8, local_size_y = 8) in;
layout(constant_id = 15) const uint WORK_SHARES = 1u;
layout(set = 0, binding = 1, rgba32f) uniform readonly image2D g_position;
layout(set = 0, binding = 2, rgba32f) uniform readonly image2D g_normal;
layout(std430, set = 0, binding = 3) buffer AO { float ao[]; };
layout(push_constant) uniform Push {
    uint mode;     // 0: this frame's samples (frame.ao_samples of them), 1: reference
    uint first;    // reference: first sample index of this dispatch
    uint count;    // reference: samples in this dispatch
    uint total;    // reference: samples in all
    uint row0;     // first image row of this dispatch
} pc;

void main() {
    // the 8x8 tiles in the order of shares.glsl (WORK_SHARES: the device's worker threads)
    ivec2 px = ivec2(share_invocation(WORK_SHARES, gl_WorkGroupSize).xy) + ivec2(0, pc.row0);
    uint w = frame.width, h = frame.height;
    if (px.x >= int(w) || px.y >= int(h)) return;
    uint pixel = uint(px.y) * w + uint(px.x);
    bool reference = pc.mode == 1u;
    bool add = reference && pc.first > 0u;
    vec4 nrm = imageLoad(g_normal, px);
    if (nrm.w <= 0.0) {
        if (!add) ao[pixel] = 1.0;
        return;
    }
    vec3 n = nrm.xyz;
    vec3 o = offset_ray(imageLoad(g_position, px).xyz, n);
    uint k = reference ? pc.count : max(uint(frame.ao_samples), 1u);
    uint first = reference ? pc.first : frame.frame_index * k;
    float norm = 1.0 / float(reference ? max(pc.total, 1u) : k);
    float radius = frame.ao_radius;
    vec2 rot = pixel_rotation(uvec2(px), 0x9e3779b9u);
    float open = 0.0;
    for (uint s = 0u; s < k; ++s) {
        vec3 d = cosine_hemisphere(n, r2(first + s, rot));
        open += bvh_occluded(o, d, 0.0, radius) ? 0.0 : 1.0;
    }
    ao[pixel] = add ? ao[pixel] + open * norm : open * norm;
}
