#version 450
#extension GL_GOOGLE_include_directive : require
// Temporal anti-aliasing (Karis 2014): the radiance of this frame's jittered raster (frame.jitter) blended with the
// resolved radiance of the previous frames. The history is read where the pixel's surface was (the motion vector;
// bilinear, so a still pixel reads exactly its own history) and clamped into the YCoCg min/max box of this frame's
// 3x3 neighbourhood, so a surface that moved away or a disocclusion cannot leave a trail. The blend is
//     value = mix(history, current, alpha),   alpha = max(1 / (n + 1), frame.taa_alpha)
// with n the frames the history holds (its alpha channel): the first frames are a plain average of the jittered
// samples (a box filter over the pixel), later ones an exponential one. On frame.history_reset, or where the history
// lies outside the image, the history starts over with this frame (which on a reset is not written to out_color: the
// lighting pass's colour stays, bit for bit).
#include "common.glsl"
FRAME_BLOCK

layout(local_size_x = 8, local_size_y = 8) in;
layout(set = 0, binding = 1, rgba16f) uniform readonly image2D g_hdr;      // this frame's radiance
layout(set = 0, binding = 2, rg32f) uniform readonly image2D g_motion;     // now - then, pixels
layout(set = 0, binding = 3, rgba16f) uniform readonly image2D h_color;    // the last resolve; a: frames it holds
layout(set = 0, binding = 4, rgba16f) uniform writeonly image2D out_hdr;
layout(set = 0, binding = 5, rgba8) uniform writeonly image2D out_color;

const float MAX_FRAMES = 255.0;

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

    // The history where this pixel's surface was: bilinear over the 2x2 pixels around it, those inside the image.
    vec2 then = vec2(px) - imageLoad(g_motion, px).xy;   // (pixel centres at +0.5 on both sides: they cancel)
    ivec2 base = ivec2(floor(then));
    vec2 f = then - vec2(base);
    vec4 hist = vec4(0.0);
    float wsum = 0.0;
    if (frame.history_reset < 0.5) {
        for (int t = 0; t < 4; ++t) {
            ivec2 q = base + ivec2(t & 1, t >> 1);
            float bw = ((t & 1) != 0 ? f.x : 1.0 - f.x) * ((t >> 1) != 0 ? f.y : 1.0 - f.y);
            if (bw <= 0.0 || any(lessThan(q, ivec2(0))) || any(greaterThanEqual(q, size))) continue;
            hist += bw * imageLoad(h_color, q);
            wsum += bw;
        }
    }
    if (wsum < 0.5) {   // no history: this frame alone
        imageStore(out_hdr, px, vec4(current, 1.0));
        if (frame.history_reset < 0.5)
            imageStore(out_color, px, vec4(srgb_encode(tonemap(current * frame.exposure, frame.tonemap)), 1.0));
        return;
    }
    hist /= wsum;

    // The neighbourhood's box in YCoCg (luma and two chroma axes: a tighter box than RGB's around grey edges).
    vec3 lo = to_ycocg(current), hi = lo;
    for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
            ivec2 q = clamp(px + ivec2(dx, dy), ivec2(0), size - 1);
            vec3 c = to_ycocg(imageLoad(g_hdr, q).rgb);
            lo = min(lo, c);
            hi = max(hi, c);
        }
    vec3 clamped = from_ycocg(clamp(to_ycocg(hist.rgb), lo, hi));

    float n = floor(hist.a + 0.5);
    float alpha = max(1.0 / (n + 1.0), frame.taa_alpha);
    vec3 value = max(mix(clamped, current, alpha), vec3(0.0));
    imageStore(out_hdr, px, vec4(value, min(n + 1.0, MAX_FRAMES)));
    imageStore(out_color, px, vec4(srgb_encode(tonemap(value * frame.exposure, frame.tonemap)), 1.0));
}
