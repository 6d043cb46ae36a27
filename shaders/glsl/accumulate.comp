#version 450
#extension GL_GOOGLE_include_directive : require
// Temporal accumulation of the light masks and AO.
//
// Each pixel is reprojected by its motion vector (the resolve's: camera and object motion); the 2x2 bilinear
// footprint there is read from the previous frame's G-buffer (history copies of position, normal and instance) and a
// tap is kept only if it saw the same surface: covered, the same instance, normal within ~25 degrees of where this
// point's normal was, and on the tangent plane of where this point was (plane distance below 1% of the depth plus
// two pixel footprints). So a moving object keeps its history where its surface stays in view, and a pixel it
// leaves (or newly covers) starts over: no trails. Kept taps give the history value and the
// history length n (bilinear weights renormalized over the kept taps); with none kept the pixel is disoccluded
// and starts over (n = 0). The new value is an exponential blend:
//     value = mix(history, raw, alpha),   alpha = max(1 / (n + 1), alpha_min)
// so the first frames are a plain average. Zero-size lights (binary masks) pass through.
// On a frame where an instance moved (frame.objects_moved), the shadows and occlusion it casts moved too, also on
// surfaces that did not: there the history is clamped into the range of this frame's raw values in the 3x3
// neighbourhood, so a shadow that left a static surface does not linger as a trail.
// Without FILTER_TEMPORAL (denoise only) or when frame.history_reset says the history is invalid, value = raw.
#include "common.glsl"
FRAME_BLOCK
#include "filter.glsl"

layout(local_size_x = 8, local_size_y = 8) in;
layout(set = 0, binding = 1, rgba32f) uniform readonly image2D g_position;   // xyz world, w: view depth
layout(set = 0, binding = 2, rgba32f) uniform readonly image2D g_normal;     // xyz normal, w: 1 where covered
layout(set = 0, binding = 3, rgba32f) uniform readonly image2D h_position;   // the previous frame's
layout(set = 0, binding = 4, rgba32f) uniform readonly image2D h_normal;
layout(std430, set = 0, binding = 5) readonly buffer MasksRaw { float masks_raw[]; };
layout(std430, set = 0, binding = 6) readonly buffer MasksHist { float masks_hist[]; };
layout(std430, set = 0, binding = 7) writeonly buffer MasksCur { float masks_cur[]; };
layout(std430, set = 0, binding = 8) readonly buffer AORaw { float ao_raw[]; };
layout(std430, set = 0, binding = 9) readonly buffer AOHist { float ao_hist[]; };
layout(std430, set = 0, binding = 10) writeonly buffer AOCur { float ao_cur[]; };
layout(std430, set = 0, binding = 11) readonly buffer LenHist { float len_hist[]; };
layout(std430, set = 0, binding = 12) writeonly buffer LenCur { float len_cur[]; };
layout(set = 0, binding = 13, rg32f) uniform readonly image2D g_motion;          // now - then, pixels
layout(set = 0, binding = 14, rgba32f) uniform readonly image2D g_prev_position; // this point, previous frame
layout(set = 0, binding = 15, rgba16f) uniform readonly image2D g_prev_normal;
layout(set = 0, binding = 16, r32ui) uniform readonly uimage2D g_instance;
layout(set = 0, binding = 17, r32ui) uniform readonly uimage2D h_instance;         // the previous frame's
layout(push_constant) uniform Push { uint flags; } pc;

const float NORMAL_COS = 0.9;
const float PLANE_REL = 0.01;
const float PLANE_PIXELS = 2.0;

// One invocation per pixel and channel (gl_GlobalInvocationID.z): the lights' masks first, then AO.
void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    uint w = frame.width, h = frame.height;
    if (px.x >= int(w) || px.y >= int(h)) return;
    uint pixel = uint(px.y) * w + uint(px.x);
    uint n_pixels = w * h;
    uint channel = gl_GlobalInvocationID.z;
    bool is_mask = (pc.flags & FILTER_MASKS) != 0u && channel < frame.light_count;
    uint at = channel * n_pixels + pixel;

    vec4 nrm = imageLoad(g_normal, px);
    vec4 pos = imageLoad(g_position, px);
    bool covered = nrm.w > 0.0;
    float raw = is_mask ? masks_raw[at] : ao_raw[pixel];
    bool random = covered && (!is_mask || light_has_extent(frame.lights[channel]));

    // Reprojection into the previous frame and the disocclusion tests.
    float wsum = 0.0, hlen = 0.0, hval = 0.0;
    bool temporal = covered && (pc.flags & FILTER_TEMPORAL) != 0u && frame.history_reset < 0.5;
    if (temporal) {
        vec3 then = imageLoad(g_prev_position, px).xyz;
        vec3 then_n = imageLoad(g_prev_normal, px).xyz;
        uint inst = imageLoad(g_instance, px).x;
        vec4 clip = frame.prev_view_proj * vec4(then, 1.0);
        if (clip.w > 0.0) {
            vec2 pp = vec2(px) - imageLoad(g_motion, px).xy;   // the previous pixel position, minus the centre's 0.5
            ivec2 base = ivec2(floor(pp));
            vec2 f = pp - vec2(base);
            float tol = PLANE_REL * clip.w + PLANE_PIXELS * pixel_footprint(clip.w);
            for (int t = 0; t < 4; ++t) {
                ivec2 q = base + ivec2(t & 1, t >> 1);
                if (q.x < 0 || q.y < 0 || q.x >= int(w) || q.y >= int(h)) continue;
                float bw = ((t & 1) != 0 ? f.x : 1.0 - f.x) * ((t >> 1) != 0 ? f.y : 1.0 - f.y);
                if (bw <= 0.0) continue;
                if (imageLoad(h_instance, q).x != inst) continue;
                vec4 qn = imageLoad(h_normal, q);
                if (qn.w <= 0.0 || dot(qn.xyz, then_n) < NORMAL_COS) continue;
                vec3 qp = imageLoad(h_position, q).xyz;
                if (abs(dot(qp - then, then_n)) > tol) continue;
                uint qi = uint(q.y) * w + uint(q.x);
                wsum += bw;
                hlen += bw * len_hist[qi];
                hval += bw * (is_mask ? masks_hist[channel * n_pixels + qi] : ao_hist[qi]);
            }
        }
    }
    float n_prev = 0.0;
    if (wsum > 1e-3) {
        n_prev = floor(hlen / wsum + 0.5);   // a whole number of frames
        hval /= wsum;
        if (frame.objects_moved > 0.5 && random) {
            float lo = raw, hi = raw;
            for (int dy = -1; dy <= 1; ++dy)
                for (int dx = -1; dx <= 1; ++dx) {
                    ivec2 q = clamp(px + ivec2(dx, dy), ivec2(0), ivec2(int(w) - 1, int(h) - 1));
                    uint qi = uint(q.y) * w + uint(q.x);
                    float r = is_mask ? masks_raw[channel * n_pixels + qi] : ao_raw[qi];
                    lo = min(lo, r);
                    hi = max(hi, r);
                }
            hval = clamp(hval, lo, hi);
        }
    }
    float alpha = n_prev > 0.0 ? max(1.0 / (n_prev + 1.0), frame.accum_alpha) : 1.0;
    if (channel == 0u) len_cur[pixel] = covered ? min(n_prev + 1.0, MAX_HISTORY) : 0.0;
    float value = random ? clamp(mix(hval, raw, alpha), 0.0, 1.0) : raw;   // (a rounding step past 1 taken back)
    if (is_mask) masks_cur[at] = value;
    else ao_cur[pixel] = value;
}
