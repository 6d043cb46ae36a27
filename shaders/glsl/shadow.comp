#version 450
#extension GL_GOOGLE_include_directive : require
// Shadow rays from the G-buffer: per pixel, per light, the visible fraction of the light (1 = lit).
// Hard mode traces one ray to the light's centre; soft mode traces `frame.params.z` rays to points of the
// light's area / solid angle from an R2 sequence rotated per pixel and advanced per frame.
#include "common.glsl"
FRAME_BLOCK
#include "sampling.glsl"
#include "lights.glsl"
#include "rayutil.glsl"
#define BVH_SET 1
#define BVH_BINDING 0
#include "bvh.glsl"

layout(local_size_x = 8, local_size_y = 8) in;
layout(set = 0, binding = 1, rgba32f) uniform readonly image2D g_position;
layout(set = 0, binding = 2, rgba32f) uniform readonly image2D g_normal;
layout(std430, set = 0, binding = 3) writeonly buffer Masks { float masks[]; };   // [light][y][x]

#define SHADOW_HARD 0u
#define SHADOW_SOFT 1u
layout(push_constant) uniform Push { uint mode; } pc;

void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    uint w = frame.size.x, h = frame.size.y;
    if (px.x >= int(w) || px.y >= int(h)) return;
    uint pixel = uint(px.y) * w + uint(px.x);
    uint n_pixels = w * h;
    vec4 nrm = imageLoad(g_normal, px);
    if (nrm.w <= 0.0) {                       // background: nothing to shadow
        for (uint i = 0u; i < frame.size.w; ++i) masks[i * n_pixels + pixel] = 1.0;
        return;
    }
    vec3 p = imageLoad(g_position, px).xyz;
    vec3 n = nrm.xyz;
    vec3 o = offset_ray(p, n);
    bool soft = pc.mode == SHADOW_SOFT;
    uint k = soft ? max(uint(frame.params.z), 1u) : 1u;
    for (uint i = 0u; i < frame.size.w; ++i) {
        Light l = frame.lights[i];
        vec2 rot = pixel_rotation(uvec2(px), i);
        float visible = 0.0;
        for (uint s = 0u; s < k; ++s) {
            vec2 xi = soft ? r2(frame.size.z * k + s, rot) : vec2(-1.0);
            float tmax;
            vec3 d = light_ray(l, o, xi, frame.params2.x, tmax);
            if (dot(d, n) <= 0.0) continue;   // the light point is below the surface's horizon
            visible += bvh_occluded(o, d, 0.0, tmax) ? 0.0 : 1.0;
        }
        masks[i * n_pixels + pixel] = visible / float(k);
    }
}
