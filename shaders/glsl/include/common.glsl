// Shared structs and helpers for every shader of the renderer.
// The structs, limits and flags shared with the host are generated: interface.glsl.
#ifndef COMMON_GLSL
#define COMMON_GLSL

#include "interface.glsl"
#define PI 3.14159265358979

float luminance(vec3 c) { return dot(c, vec3(0.2126, 0.7152, 0.0722)); }

vec3 srgb_encode(vec3 c) {
    c = clamp(c, 0.0, 1.0);
    return mix(12.92 * c, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(vec3(0.0031308), c));
}

// Narkowicz's ACES filmic fit: maps HDR radiance to [0, 1].
vec3 tonemap_aces(vec3 x) {
    return clamp((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0);
}

// Khronos PBR Neutral (github.com/KhronosGroup/ToneMapping): base colours up to 0.76 pass unchanged (less a small
// toe offset), brighter ones are compressed towards white and desaturated.
vec3 tonemap_neutral(vec3 color) {
    const float start = 0.8 - 0.04, desaturation = 0.15;
    float x = min(color.r, min(color.g, color.b));
    float offset = x < 0.08 ? x - 6.25 * x * x : 0.04;
    color -= offset;
    float peak = max(color.r, max(color.g, color.b));
    if (peak < start) return color;
    const float d = 1.0 - start;
    float new_peak = 1.0 - d * d / (peak + d - start);
    color *= new_peak / peak;
    float g = 1.0 - 1.0 / (desaturation * (peak - new_peak) + 1.0);
    return mix(color, vec3(new_peak), g);
}

// AgX, base look (Troy Sobotka's curve; the inset/outset matrices and the sigmoid's polynomial fit of Benjamin
// Wrensch's minimal version), returned as linear sRGB (the curve's 2.2 display encoding undone).
vec3 tonemap_agx(vec3 color) {
    const mat3 inset = mat3(0.842479062253094, 0.0423282422610123, 0.0423756549057051,
                            0.0784335999999992, 0.878468636469772, 0.0784336,
                            0.0792237451477643, 0.0791661274605434, 0.879142973793104);
    const mat3 outset = mat3(1.19687900512017, -0.0528968517574562, -0.0529716355144438,
                             -0.0980208811401368, 1.15190312990417, -0.0980434501171241,
                             -0.0990297440797205, -0.0989611768448433, 1.15107367264116);
    const float min_ev = -12.47393, max_ev = 4.026069;
    vec3 x = clamp(log2(max(inset * color, vec3(1e-10))), min_ev, max_ev);
    x = (x - min_ev) / (max_ev - min_ev);
    vec3 x2 = x * x, x4 = x2 * x2;
    x = 15.5 * x4 * x2 - 40.14 * x4 * x + 31.96 * x4 - 6.868 * x2 * x + 0.4298 * x2 + 0.1191 * x - 0.00232;
    return pow(clamp(outset * x, 0.0, 1.0), vec3(2.2));
}

// The tone curve `curve` (TONEMAP_*) of linear radiance, in [0, 1] linear RGB.
vec3 tonemap(vec3 color, uint curve) {
    color = max(color, vec3(0.0));
    if (curve == TONEMAP_AGX) return tonemap_agx(color);
    if (curve == TONEMAP_ACES) return tonemap_aces(color);
    return clamp(tonemap_neutral(color), 0.0, 1.0);
}

#endif
