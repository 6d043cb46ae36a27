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

#endif
