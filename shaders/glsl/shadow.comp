#version 450
#extension GL_GOOGLE_include_directive : require
// Shadow rays from the G-buffer: per pixel, per light, the visible fraction of the light (1 = lit).
//   hard:       one ray to the light's centre.
//   soft:       `frame.shadow_samples` rays to points of the light's area / solid angle, from an R2 sequence rotated
//               per pixel and advanced per frame (accumulated and denoised by later passes).
//   seed-delta: the paper's occlusion delta (section 4.2.3): one closest-hit ray to the light's centre; where
//               it is blocked the mask is t_occluder / t_light (clamped to [0, 1]), the fraction of the way to the
//               light at which the occluder sits (the paper's "occlusion delta" is its reciprocal). For the sun
//               t_light is the scene's bounding-box diagonal.
//   reference:  `pc.count` of `pc.total` rays per dispatch, added up over several dispatches (ground truth).
// Dispatches may cover a band of rows (`pc.row0`): the reference mode splits its work so that no dispatch runs long.
#include "common.glsl"
FRAME_BLOCK
#include "sampling.glsl"
#include "lights.glsl"
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
layout(std430, set = 0, binding = 3) buffer Masks { float masks[]; };   // [light][y][x]
layout(set = 0, binding = 8, rgba16f) uniform readonly image2D g_terminator;   // terminator.glsl's shift

layout(push_constant) uniform Push {
    uint mode;
    uint first;    // reference: first sample index of this dispatch
    uint count;    // reference: samples in this dispatch
    uint total;    // reference: samples in all (the mask is their mean)
    uint row0;     // first image row of this dispatch
} pc;

void main() {
    // the 8x8 tiles in the order of shares.glsl (WORK_SHARES: the device's worker threads)
    ivec2 px = ivec2(share_invocation(WORK_SHARES, gl_WorkGroupSize).xy) + ivec2(0, pc.row0);
    uint w = frame.width, h = frame.height;
    if (px.x >= int(w) || px.y >= int(h)) return;
    uint pixel = uint(px.y) * w + uint(px.x);
    uint n_pixels = w * h;
    bool reference = pc.mode == SHADOW_REFERENCE;
    bool add = reference && pc.first > 0u;
    vec4 nrm = imageLoad(g_normal, px);
    if (nrm.w <= 0.0) {                       // background: nothing to shadow
        if (!add)
            for (uint i = 0u; i < frame.light_count; ++i) masks[i * n_pixels + pixel] = 1.0;
        return;
    }
    vec3 p = imageLoad(g_position, px).xyz;
    vec3 n = nrm.xyz;
    // (the terminator shift moves the start off flat triangles of smooth meshes: gbuffer_resolve.comp)
    vec3 shift = frame.shadow_terminator > 0.5 ? imageLoad(g_terminator, px).xyz : vec3(0.0);
    vec3 o = offset_ray(p + shift, n);
    bool sampled = pc.mode == SHADOW_SOFT || reference;
    uint k = reference ? pc.count : (pc.mode == SHADOW_SOFT ? max(uint(frame.shadow_samples), 1u) : 1u);
    uint first = reference ? pc.first : frame.frame_index * k;
    float norm = reference ? 1.0 / float(max(pc.total, 1u)) : 1.0 / float(k);
    for (uint i = 0u; i < frame.light_count; ++i) {
        Light l = frame.lights[i];
        vec2 rot = pixel_rotation(uvec2(px), i);
        float visible = 0.0;
        if (pc.mode == SHADOW_SEED_DELTA) {
            float tmax;
            vec3 d = light_ray(l, o, vec2(-1.0), frame.scene_scale, tmax);
            if (dot(d, n) > 0.0) {
                BvhHit hit = bvh_intersect(o, d, 0.0, tmax);
                float t_hit = hit.t;
                if (hit.prim < 0) {
                    visible = 1.0;
                } else {
                    // Distances along the ray: t is in units of |d| (d reaches the light's centre at t = 1);
                    // for the sun |d| = 1 and the light is taken to be one scene diagonal away.
                    float t_light = int(l.pos_type.w) == LIGHT_DIRECTIONAL ? frame.scene_scale : 1.0;
                    visible = clamp(t_hit / t_light, 0.0, 1.0);
                }
            }
        } else {
            for (uint s = 0u; s < k; ++s) {
                vec2 xi = sampled ? r2(first + s, rot) : vec2(-1.0);
                float tmax;
                vec3 d = light_ray(l, o, xi, frame.scene_scale, tmax);
                if (dot(d, n) <= 0.0) continue;   // the light point is below the surface's horizon
                visible += bvh_occluded(o, d, 0.0, tmax) ? 0.0 : 1.0;
            }
        }
        uint at = i * n_pixels + pixel;
        float value = pc.mode == SHADOW_SEED_DELTA ? visible : visible * norm;
        masks[at] = add ? masks[at] + value : value;
    }
}
