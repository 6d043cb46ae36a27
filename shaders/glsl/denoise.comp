#version 450
#extension GL_GOOGLE_include_directive : require
// One iteration of the edge-aware a-trous wavelet filter (Dammertz et al. 2010; the variance guidance of
// SVGF, Schied et al. 2017) over the light masks and AO. The renderer runs it with steps 1, 2, 4, 8 (ping-pong).
//
// A 5x5 B3-spline kernel with holes of `step` pixels; each tap q is weighted, for the centre p, by
//     w = h(dx) h(dy) * w_normal * w_plane * w_value
//     w_normal = max(dot(n_p, n_q), 0)^128
//     w_plane  = exp(-|dot(x_q - x_p, n_p)| / (0.1 * pixel footprint at p * |offset in pixels|))
//     w_value  = exp(-|v_q - v_p| / (4 * sqrt(var_p) + 1e-4))
// so the filter follows surfaces (normal + distance to p's tangent plane) and stops at real shadow edges
// (a value step much larger than the noise). The variance of the value is estimated in the first
// iteration from the accumulated value itself, as a binomial: the visible fraction of k rays per frame
// accumulated over n frames has variance p (1 - p) / (k n_eff), with p the 3x3 (same-surface) mean and
// n_eff = min(n, 2 / alpha_min - 1); each iteration then carries it on as sum(w^2 var_q) / sum(w)^2.
// Zero-size lights (binary masks), the background and pixels without noise (variance 0) pass through untouched.
#include "common.glsl"
FRAME_BLOCK
#include "filter.glsl"
#include "shares.glsl"

layout(local_size_x = 8, local_size_y = 8) in;
layout(constant_id = 15) const uint WORK_SHARES = 1u;   // shares.glsl: the device's worker threads
layout(set = 0, binding = 1, rgba32f) uniform readonly image2D g_position;
layout(set = 0, binding = 2, rgba32f) uniform readonly image2D g_normal;
layout(set = 0, binding = 12, rgba8_snorm) uniform readonly image2D g_normal8;   // the taps' normals, 8-bit
layout(std430, set = 0, binding = 3) readonly buffer MasksIn { float masks_in[]; };
layout(std430, set = 0, binding = 4) readonly buffer MasksInVar { float masks_in_var[]; };
layout(std430, set = 0, binding = 5) writeonly buffer MasksOut { float masks_out[]; };
layout(std430, set = 0, binding = 6) writeonly buffer MasksOutVar { float masks_out_var[]; };
layout(std430, set = 0, binding = 7) readonly buffer AOIn { float ao_in[]; };
layout(std430, set = 0, binding = 8) readonly buffer AOInVar { float ao_in_var[]; };
layout(std430, set = 0, binding = 9) writeonly buffer AOOut { float ao_out[]; };
layout(std430, set = 0, binding = 10) writeonly buffer AOOutVar { float ao_out_var[]; };
layout(std430, set = 0, binding = 11) readonly buffer HistLen { float hist_len[]; };
// The four inputs again as R32F storage texel buffers (the same buffers), read where DENOISE_TEXEL says (set by
// engine/passes/denoise.py): llvmpipe 22.3 loads a storage buffer lane by lane (a scalar loop over the 8 lanes per
// load, 25 taps per pixel) but an image load as vector code. Storage buffers on GPUs, where the views are slower.
layout(constant_id = 0) const bool DENOISE_TEXEL = false;
layout(set = 0, binding = 13, r32f) uniform readonly restrict imageBuffer masks_in_texels;
layout(set = 0, binding = 14, r32f) uniform readonly restrict imageBuffer masks_in_var_texels;
layout(set = 0, binding = 15, r32f) uniform readonly restrict imageBuffer ao_in_texels;
layout(set = 0, binding = 16, r32f) uniform readonly restrict imageBuffer ao_in_var_texels;
layout(push_constant) uniform Push { uint flags; uint step; } pc;

const float SIGMA_NORMAL = 128.0;
const float SIGMA_PLANE = 0.1;
const float SIGMA_VALUE = 4.0;
const float KERNEL[3] = float[3](3.0 / 8.0, 1.0 / 4.0, 1.0 / 16.0);

// The surface similarity of tap q to the centre (p, n): w_normal in .x, the exponent of w_plane in .y
// (w = x * exp(-y)), so that one exp serves both w_plane and w_value.
vec2 geometry_weight(vec3 p, vec3 n, float footprint, ivec2 q, float dist_px) {
    vec4 qn = imageLoad(g_normal8, q);
    if (qn.w <= 0.0) return vec2(0.0);
    vec3 qp = imageLoad(g_position, q).xyz;
    float c = max(dot(n, normalize(qn.xyz)), 0.0);   // renormalized: 8-bit rounding moves c^128 by < 0.5%
    c *= c; c *= c; c *= c; c *= c; c *= c; c *= c; c *= c;   // c^128
    return vec2(c, abs(dot(qp - p, n)) / (SIGMA_PLANE * footprint * max(dist_px, 1.0)));
}

uint n_pixels;
bool is_mask;
uint channel;

float value_at(uint pixel) {
    if (DENOISE_TEXEL) {
        return is_mask ? imageLoad(masks_in_texels, int(channel * n_pixels + pixel)).x
                       : imageLoad(ao_in_texels, int(pixel)).x;
    }
    return is_mask ? masks_in[channel * n_pixels + pixel] : ao_in[pixel];
}
float variance_at(uint pixel) {
    if (DENOISE_TEXEL) {
        return is_mask ? imageLoad(masks_in_var_texels, int(channel * n_pixels + pixel)).x
                       : imageLoad(ao_in_var_texels, int(pixel)).x;
    }
    return is_mask ? masks_in_var[channel * n_pixels + pixel] : ao_in_var[pixel];
}
void store(uint pixel, float value, float variance) {
    if (is_mask) {
        masks_out[channel * n_pixels + pixel] = value;
        masks_out_var[channel * n_pixels + pixel] = variance;
    } else {
        ao_out[pixel] = value;
        ao_out_var[pixel] = variance;
    }
}

// One invocation per pixel and channel (gl_GlobalInvocationID.z): the lights' masks first, then AO.
void main() {
    uvec3 gid = share_invocation(WORK_SHARES, gl_WorkGroupSize);   // gl_GlobalInvocationID in the order of shares.glsl
    ivec2 px = ivec2(gid.xy);
    uint w = frame.width, h = frame.height;
    if (px.x >= int(w) || px.y >= int(h)) return;
    uint pixel = uint(px.y) * w + uint(px.x);
    n_pixels = w * h;
    channel = gid.z;
    is_mask = (pc.flags & FILTER_MASKS) != 0u && channel < frame.light_count;
    bool first = (pc.flags & FILTER_FIRST) != 0u;

    vec4 nrm = imageLoad(g_normal, px);
    float centre = value_at(pixel);
    if (nrm.w <= 0.0 || (is_mask && !light_has_extent(frame.lights[channel]))) {
        store(pixel, centre, 0.0);   // background, binary masks: untouched
        return;
    }
    vec4 pos = imageLoad(g_position, px);
    float footprint = pixel_footprint(pos.w);

    float var_c;
    if (first) {
        // Binomial variance from the 3x3 same-surface mean of the accumulated value.
        float mean = 0.0, wsum = 0.0;
        for (int dy = -1; dy <= 1; ++dy) {
            for (int dx = -1; dx <= 1; ++dx) {
                ivec2 q = px + ivec2(dx, dy);
                if (q.x < 0 || q.y < 0 || q.x >= int(w) || q.y >= int(h)) continue;
                vec2 g = (dx == 0 && dy == 0) ? vec2(1.0, 0.0) : geometry_weight(pos.xyz, nrm.xyz, footprint, q, 1.0);
                float gw = g.x * exp(-g.y);
                if (gw < 1e-3) continue;
                mean += gw * value_at(uint(q.y) * w + uint(q.x));
                wsum += gw;
            }
        }
        mean /= wsum;
        float n_eff = clamp(hist_len[pixel], 1.0, 2.0 / max(frame.accum_alpha, 1e-3) - 1.0);
        float k = max(is_mask ? frame.shadow_samples : frame.ao_samples, 1.0);
        var_c = mean * (1.0 - mean) / (k * n_eff);
    } else {
        var_c = variance_at(pixel);
    }

    if (var_c <= 0.0) {
        store(pixel, centre, 0.0);   // no noise (fully lit or in umbra): nothing to filter, and it is the common case
        return;
    }
    float sigma = SIGMA_VALUE * sqrt(var_c) + 1e-4;
    float sum = 0.0, wsum = 0.0, vsum = 0.0;
    int step = int(pc.step);
    for (int dy = -2; dy <= 2; ++dy) {
        for (int dx = -2; dx <= 2; ++dx) {
            ivec2 q = px + ivec2(dx, dy) * step;
            if (q.x < 0 || q.y < 0 || q.x >= int(w) || q.y >= int(h)) continue;
            float k = KERNEL[abs(dx)] * KERNEL[abs(dy)];
            bool is_centre = dx == 0 && dy == 0;
            vec2 g = is_centre ? vec2(1.0, 0.0)
                               : geometry_weight(pos.xyz, nrm.xyz, footprint, q, float(step) * length(vec2(dx, dy)));
            if (g.x * k < 1e-6 || g.y > 14.0) continue;
            uint qi = uint(q.y) * w + uint(q.x);
            float v = is_centre ? centre : value_at(qi);
            float vq = (first || is_centre) ? var_c : variance_at(qi);
            float wt = k * g.x * exp(-g.y - abs(v - centre) / sigma);
            sum += wt * v;
            wsum += wt;
            vsum += wt * wt * vq;
        }
    }
    // (a weighted mean of values in [0, 1]; the clamp takes back a rounding step past 1, as GPUs' fused ops give)
    store(pixel, clamp(sum / wsum, 0.0, 1.0), vsum / (wsum * wsum));
}
