#version 450
#extension GL_GOOGLE_include_directive : require
// Temporal anti-aliasing (Karis 2014): the radiance of this frame's jittered raster (frame.jitter) blended with the
// resolved radiance of the previous frames. The history is read where the pixel's surface was (the motion vector;
// the background's view direction under the previous camera; Catmull-Rom, so a still pixel reads exactly its own
// history) and clamped into this frame's 3x3 neighbourhood's YCoCg box (min/max narrowed by the variance), so a
// surface that moved away or a disocclusion cannot leave a trail. The blend is
//     value = mix(history, current, alpha),   alpha = max(1 / (n + 1), frame.taa_alpha)
// with n the frames the history holds (its alpha channel): the first frames are a plain average of the jittered
// samples (a box filter over the pixel), later ones an exponential one. On frame.history_reset or a camera cut
// (frame.camera_cut), or where the history lies outside the image, the history starts over with this frame (which on
// a reset or cut is not written to out_color: the lighting pass's colour stays, bit for bit).
#include "common.glsl"
FRAME_BLOCK

layout(local_size_x = 8, local_size_y = 8) in;
layout(set = 0, binding = 1, rgba16f) uniform readonly image2D g_hdr;      // this frame's radiance
layout(set = 0, binding = 2, rg32f) uniform readonly image2D g_motion;     // now - then, pixels
layout(set = 0, binding = 3, rgba16f) uniform readonly image2D h_color;    // the last resolve; a: frames it holds
layout(set = 0, binding = 4, rgba16f) uniform writeonly image2D out_hdr;
layout(set = 0, binding = 5, rgba8) uniform writeonly image2D out_color;
layout(set = 0, binding = 6, rgba32f) uniform readonly image2D g_normal;   // w: 1 where a surface is drawn

const float MAX_FRAMES = 255.0;
const float VARIANCE_GAMMA = 1.0;

vec3 to_ycocg(vec3 c) {
    return vec3(0.25 * c.r + 0.5 * c.g + 0.25 * c.b, 0.5 * c.r - 0.5 * c.b, -0.25 * c.r + 0.5 * c.g - 0.25 * c.b);
}

vec3 from_ycocg(vec3 c) {
    return vec3(c.x + c.y - c.z, c.x + c.z, c.x - c.y - c.z);
}

void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = ivec2(frame.width, frame.height);
    if (px.x >= size.x || px.y >= size.y) return;
    vec3 current = imageLoad(g_hdr, px).rgb;
    bool restart = frame.history_reset > 0.5 || frame.camera_cut > 0.5;

    // The history where this pixel's surface was (in pixel index coordinates).
    // The background (motion 0: it is at infinity) is where its view direction was under the previous camera.
    vec2 then = vec2(px) - imageLoad(g_motion, px).xy;   // (pixel centres at +0.5 on both sides: they cancel)
    if (imageLoad(g_normal, px).w <= 0.0) {
        vec2 ndc = (vec2(px) + 0.5) / vec2(size) * 2.0 - 1.0;
        vec4 far = frame.inv_view_proj * vec4(ndc, 1.0, 1.0);
        vec4 prev = frame.prev_view_proj * vec4(far.xyz / far.w - frame.eye, 0.0);
        then = prev.w > 0.0 ? (prev.xy / prev.w * 0.5 + 0.5) * vec2(size) - 0.5 : vec2(-2.0);
    }
    // Catmull-Rom over the 4x4 pixels around it (a bilinear read blurs the history a little more every frame the
    // view moves; its overshoot is clamped below), weights renormalized over those inside the image; the frames the
    // history holds (alpha) from the nearest pixel.
    ivec2 base = ivec2(floor(then));
    vec2 f = then - vec2(base);
    vec2 w[4] = vec2[4](f * (-0.5 + f * (1.0 - 0.5 * f)), 1.0 + f * f * (-2.5 + 1.5 * f),
                        f * (0.5 + f * (2.0 - 1.5 * f)), f * f * (-0.5 + 0.5 * f));
    vec4 hist = vec4(0.0);
    float wsum = 0.0;
    ivec2 nearest = ivec2(floor(then + 0.5));
    bool inside = all(greaterThanEqual(nearest, ivec2(0))) && all(lessThan(nearest, size));
    if (!restart && inside) {
        for (int j = 0; j < 4; ++j)
            for (int i = 0; i < 4; ++i) {
                ivec2 q = base + ivec2(i - 1, j - 1);
                if (any(lessThan(q, ivec2(0))) || any(greaterThanEqual(q, size))) continue;
                float bw = w[i].x * w[j].y;
                hist.rgb += bw * imageLoad(h_color, q).rgb;
                wsum += bw;
            }
        hist.a = imageLoad(h_color, nearest).a;
    }
    if (!(wsum > 0.5)) {   // no history: this frame alone
        imageStore(out_hdr, px, vec4(current, 1.0));
        if (!restart)
            imageStore(out_color, px, vec4(srgb_encode(tonemap(current * frame.exposure, frame.tonemap)), 1.0));
        return;
    }
    hist.rgb /= wsum;

    // The neighbourhood's box in YCoCg (luma and two chroma axes: a tighter box than RGB's around grey edges): its
    // min/max, narrowed to mean +- VARIANCE_GAMMA standard deviations (Salvi 2016), which at an edge between two
    // surfaces holds the mixes of them a jittered pixel sees but not much of a surface that is no longer there.
    vec3 lo = to_ycocg(current), hi = lo, m1 = vec3(0.0), m2 = vec3(0.0);
    for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
            ivec2 q = clamp(px + ivec2(dx, dy), ivec2(0), size - 1);
            vec3 c = to_ycocg(imageLoad(g_hdr, q).rgb);
            lo = min(lo, c);
            hi = max(hi, c);
            m1 += c;
            m2 += c * c;
        }
    vec3 mean = m1 / 9.0, sigma = sqrt(max(m2 / 9.0 - mean * mean, vec3(0.0)));
    lo = max(lo, mean - VARIANCE_GAMMA * sigma);
    hi = min(hi, mean + VARIANCE_GAMMA * sigma);
    vec3 clamped = from_ycocg(clamp(to_ycocg(hist.rgb), lo, hi));

    float n = floor(hist.a + 0.5);
    float alpha = max(1.0 / (n + 1.0), frame.taa_alpha);
    vec3 value = max(mix(clamped, current, alpha), vec3(0.0));
    imageStore(out_hdr, px, vec4(value, min(n + 1.0, MAX_FRAMES)));
    imageStore(out_color, px, vec4(srgb_encode(tonemap(value * frame.exposure, frame.tonemap)), 1.0));
}
