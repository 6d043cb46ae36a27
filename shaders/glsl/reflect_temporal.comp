#version 450
#extension GL_GOOGLE_include_directive : require
// Roughness-aware temporal accumulation of the traced reflections (reflect.comp).
//
// The pixel is reprojected by its motion vector and the 2x2 bilinear footprint there is kept where it saw the same
// surface (the same instance, normal and tangent plane: accumulate.comp's tests). The history is clipped to this
// frame's raw neighbourhood (3x3 mean +- CLIP_SIGMA standard deviations per channel), so a reflected object that
// moved, or a reflection that slid with the view over a still surface, leaves no trail (and a clipped history counts
// as at most CLIPPED_HISTORY frames); then blended:
//     value = mix(history, raw, alpha),   alpha = max(1 / (n + 1), alpha_min(roughness))
// alpha_min is 1 for a mirror (its one ray is exact: no history, no lag) and falls to ALPHA_MIN_ROUGH for rough
// lobes, whose single rays are noisy. Writes rgb and w = the history length n + 1 (0: not traced).
// DIFFUSE (the diffuse GI's irradiance, gi.comp): a lobe of roughness 1, and no clipping: one cosine ray's 3x3
// neighbourhood says little about a mean that a few of its directions bring (a history clipped to it goes dark:
// measured on tests/test_gi.py's room, clipping to a 5x5 mean +- 2 sigma doubled the error to the path tracer).
#include "common.glsl"
FRAME_BLOCK
#include "filter.glsl"

layout(local_size_x = 8, local_size_y = 8) in;
layout(constant_id = 0) const uint DIFFUSE = 0u;   // 1: the diffuse GI (gi.comp)
layout(set = 0, binding = 1, rgba32f) uniform readonly image2D g_position;
layout(set = 0, binding = 2, rgba32f) uniform readonly image2D g_normal;
layout(set = 0, binding = 3, rgba8) uniform readonly image2D g_pbr;
layout(set = 0, binding = 4, rgba32f) uniform readonly image2D h_position;   // the previous frame's
layout(set = 0, binding = 5, rgba32f) uniform readonly image2D h_normal;
layout(set = 0, binding = 6, rg32f) uniform readonly image2D g_motion;         // now - then, pixels
layout(set = 0, binding = 7, rgba32f) uniform readonly image2D g_prev_position;
layout(set = 0, binding = 8, rgba16f) uniform readonly image2D g_prev_normal;
layout(set = 0, binding = 9, r32ui) uniform readonly uimage2D g_instance;
layout(set = 0, binding = 10, r32ui) uniform readonly uimage2D h_instance;
layout(std430, set = 0, binding = 11) readonly buffer Raw { vec4 raw[]; };
layout(std430, set = 0, binding = 12) readonly buffer Hist { vec4 hist[]; };
layout(std430, set = 0, binding = 13) writeonly buffer Cur { vec4 cur[]; };

const float NORMAL_COS = 0.9;
const float PLANE_REL = 0.01;
const float PLANE_PIXELS = 2.0;
const float CLIP_SIGMA = 1.0;
const float ALPHA_MIN_ROUGH = 0.05;
const float MAX_REFLECTION_HISTORY = 64.0;
const float CLIPPED_HISTORY = 2.0;

void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    uint w = frame.width, h = frame.height;
    if (px.x >= int(w) || px.y >= int(h)) return;
    uint pixel = uint(px.y) * w + uint(px.x);
    vec4 now = raw[pixel];
    if (now.w <= 0.0) {
        cur[pixel] = vec4(0.0);
        return;
    }
    float wsum = 0.0, hlen = 0.0;
    vec3 hval = vec3(0.0);
    if (frame.history_reset < 0.5) {
        vec3 then = imageLoad(g_prev_position, px).xyz;
        vec3 then_n = imageLoad(g_prev_normal, px).xyz;
        uint inst = imageLoad(g_instance, px).x;
        vec4 clip = frame.prev_view_proj * vec4(then, 1.0);
        if (clip.w > 0.0) {
            vec2 pp = vec2(px) - imageLoad(g_motion, px).xy;
            ivec2 base = ivec2(floor(pp));
            vec2 f = pp - vec2(base);
            float tol = PLANE_REL * clip.w + PLANE_PIXELS * pixel_footprint(clip.w);
            for (int t = 0; t < 4; ++t) {
                ivec2 q = base + ivec2(t & 1, t >> 1);
                if (q.x < 0 || q.y < 0 || q.x >= int(w) || q.y >= int(h)) continue;
                float bw = ((t & 1) != 0 ? f.x : 1.0 - f.x) * ((t >> 1) != 0 ? f.y : 1.0 - f.y);
                if (bw <= 0.0 || imageLoad(h_instance, q).x != inst) continue;
                vec4 qn = imageLoad(h_normal, q);
                if (qn.w <= 0.0 || dot(qn.xyz, then_n) < NORMAL_COS) continue;
                if (abs(dot(imageLoad(h_position, q).xyz - then, then_n)) > tol) continue;
                vec4 hq = hist[uint(q.y) * w + uint(q.x)];
                if (hq.w <= 0.0) continue;   // not traced there
                wsum += bw;
                hlen += bw * hq.w;
                hval += bw * hq.rgb;
            }
        }
    }
    float n_prev = 0.0;
    if (wsum > 1e-3) {
        n_prev = floor(hlen / wsum + 0.5);
        hval /= wsum;
    }
    if (wsum > 1e-3 && DIFFUSE == 0u) {
        vec3 m1 = vec3(0.0), m2 = vec3(0.0);
        float k = 0.0;
        for (int dy = -1; dy <= 1; ++dy)
            for (int dx = -1; dx <= 1; ++dx) {
                ivec2 q = clamp(px + ivec2(dx, dy), ivec2(0), ivec2(int(w) - 1, int(h) - 1));
                vec4 rq = raw[uint(q.y) * w + uint(q.x)];
                if (rq.w <= 0.0) continue;
                m1 += rq.rgb;
                m2 += rq.rgb * rq.rgb;
                k += 1.0;
            }
        m1 /= k;
        vec3 sigma = sqrt(max(m2 / k - m1 * m1, vec3(0.0)));
        vec3 clipped = clamp(hval, m1 - CLIP_SIGMA * sigma, m1 + CLIP_SIGMA * sigma);
        // a history outside the neighbourhood's spread saw something else (it rarely is where the signal is still):
        // it is kept only as a short one, so the new reflection takes over within a few frames
        if (any(greaterThan(abs(clipped - hval), 0.25 * sigma + 1e-4))) n_prev = min(n_prev, CLIPPED_HISTORY);
        hval = clipped;
    }
    float roughness = DIFFUSE != 0u ? 1.0 : imageLoad(g_pbr, px).x;
    float alpha_min = mix(1.0, ALPHA_MIN_ROUGH, smoothstep(0.02, 0.3, roughness));
    float alpha = n_prev > 0.0 ? max(1.0 / (n_prev + 1.0), alpha_min) : 1.0;
    cur[pixel] = vec4(mix(hval, now.rgb, alpha), min(n_prev + 1.0, MAX_REFLECTION_HISTORY));
}
