#version 450
#extension GL_GOOGLE_include_directive : require
// Spatial filter of the accumulated reflections (reflect_temporal.comp): iterations of an edge-aware a-trous 5x5
// kernel with holes of pc.step pixels, its taps weighted by the normals' agreement, the distance to the centre's
// tangent plane, the roughness difference, and a Gaussian of the tap's distance whose width grows with the centre's
// roughness (a mirror keeps its own pixel: a sharp reflection stays sharp) and shrinks as the history grows
// (accumulated frames need less spatial help). Untraced pixels (w = 0) pass through and are never taps.
// DIFFUSE (the diffuse GI's irradiance, gi.comp): every pixel a lobe of roughness 1.
#include "common.glsl"
FRAME_BLOCK
#include "filter.glsl"

layout(local_size_x = 8, local_size_y = 8) in;
layout(constant_id = 0) const uint DIFFUSE = 0u;   // 1: the diffuse GI (gi.comp)
layout(set = 0, binding = 1, rgba32f) uniform readonly image2D g_position;
layout(set = 0, binding = 2, rgba32f) uniform readonly image2D g_normal;
layout(set = 0, binding = 3, rgba8) uniform readonly image2D g_pbr;
layout(std430, set = 0, binding = 4) readonly buffer Src { vec4 src[]; };
layout(std430, set = 0, binding = 5) writeonly buffer Dst { vec4 dst[]; };
layout(push_constant) uniform Push { uint step; } pc;

const float KERNEL[3] = float[](0.375, 0.25, 0.0625);
const float RADIUS_PER_ROUGHNESS = 24.0;   // the Gaussian's sigma in pixels at roughness 1 (a first frame)
const float NORMAL_POWER = 32.0;
const float PLANE_PIXELS = 1.5;
const float ROUGHNESS_SIGMA = 0.1;

void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    uint w = frame.width, h = frame.height;
    if (px.x >= int(w) || px.y >= int(h)) return;
    uint pixel = uint(px.y) * w + uint(px.x);
    vec4 c = src[pixel];
    if (c.w <= 0.0) {
        dst[pixel] = c;
        return;
    }
    vec3 n = imageLoad(g_normal, px).xyz;
    vec4 pos = imageLoad(g_position, px);
    float rough = DIFFUSE != 0u ? 1.0 : imageLoad(g_pbr, px).x;
    float sigma = RADIUS_PER_ROUGHNESS * rough * inversesqrt(c.w);
    if (sigma < 0.25) {   // a mirror-like lobe: nothing to blur
        dst[pixel] = c;
        return;
    }
    float tol = PLANE_PIXELS * float(pc.step) * pixel_footprint(pos.w);
    vec3 sum = vec3(0.0);
    float wsum = 0.0;
    int step = int(pc.step);
    for (int dy = -2; dy <= 2; ++dy)
        for (int dx = -2; dx <= 2; ++dx) {
            ivec2 q = px + ivec2(dx, dy) * step;
            if (q.x < 0 || q.y < 0 || q.x >= int(w) || q.y >= int(h)) continue;
            uint qi = uint(q.y) * w + uint(q.x);
            vec4 s = src[qi];
            if (s.w <= 0.0) continue;
            vec4 qn = imageLoad(g_normal, q);
            if (qn.w <= 0.0) continue;
            float dist2 = float(dx * dx + dy * dy) * float(step * step);
            float wk = KERNEL[abs(dx)] * KERNEL[abs(dy)] * exp(-0.5 * dist2 / (sigma * sigma));
            wk *= pow(max(dot(n, qn.xyz), 0.0), NORMAL_POWER);
            float plane = abs(dot(imageLoad(g_position, q).xyz - pos.xyz, n));
            wk *= exp(-plane / max(tol, 1e-6));
            if (DIFFUSE == 0u) wk *= exp(-abs(imageLoad(g_pbr, q).x - rough) / ROUGHNESS_SIGMA);
            sum += wk * s.rgb;
            wsum += wk;
        }
    dst[pixel] = vec4(wsum > 0.0 ? sum / wsum : c.rgb, c.w);
}
