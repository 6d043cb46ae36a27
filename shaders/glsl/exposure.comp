#version 450
#extension GL_GOOGLE_include_directive : require
// Automatic exposure (setting `auto_exposure`): one workgroup reduces the frame's radiance to its log-average
// luminance (Reinhard et al. 2002, "Photographic tone reproduction": the key 0.18 over exp(mean(log(delta + L)))),
// then tone-maps every pixel again with that factor times 2^EV. One dispatch, so the frame stays one recorded
// command buffer; the image's reads are 2 per pixel (the radiance is half floats).
#include "common.glsl"
FRAME_BLOCK

#define THREADS 256
layout(local_size_x = THREADS) in;
layout(set = 0, binding = 1, rgba16f) uniform readonly image2D g_hdr;
layout(set = 0, binding = 2, rgba8) uniform writeonly image2D out_color;

shared float partial[THREADS];

void main() {
    uint t = gl_LocalInvocationIndex;
    uint w = frame.width, n = frame.width * frame.height;
    float sum = 0.0;
    for (uint i = t; i < n; i += THREADS) {
        vec3 c = imageLoad(g_hdr, ivec2(i % w, i / w)).rgb;
        sum += log(1e-4 + luminance(max(c, vec3(0.0))));
    }
    partial[t] = sum;
    barrier();
    for (uint s = THREADS / 2u; s > 0u; s >>= 1) {
        if (t < s) partial[t] += partial[t + s];
        barrier();
    }
    float scale = frame.exposure * 0.18 / exp(partial[0] / float(max(n, 1u)));
    for (uint i = t; i < n; i += THREADS) {
        ivec2 px = ivec2(i % w, i / w);
        vec3 c = imageLoad(g_hdr, px).rgb * scale;
        imageStore(out_color, px, vec4(srgb_encode(tonemap(c, frame.tonemap)), 1.0));
    }
}
