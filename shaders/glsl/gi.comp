#version 450
#extension GL_GOOGLE_include_directive : require
// Diffuse global illumination from the G-buffer: per pixel one cosine-weighted ray about the surface's normal, traced
// on the scene's BVH. A ray that leaves the scene sees the environment; at a hit the surface is shaded as the path
// tracer's vertex (hit_shading.glsl: its emission, each analytic light sampled once with a shadow ray) plus its
// diffuse lobe lit by the irradiance this pass found there in the previous frame, read back where the previous
// frame's G-buffer saw the same surface (the previous frame's filtered `prev` at the hit's reprojected pixel): each
// frame adds a bounce, so the light converges over frames to all bounces between the surfaces the camera sees. A hit
// the previous frame did not see (off screen, hidden) takes the ray's own pixel's irradiance instead (the classic
// ambient estimate of the bounces beyond: close in a room, where what a point sees is lit as it is). Analytic
// lights are never hit: the lighting pass's direct term holds them.
// With cosine-weighted directions the ray's radiance is an estimate of the irradiance over pi, the quantity the
// lighting's diffuse lobe multiplies (as ibl.glsl's environment_irradiance). Metals (no diffuse lobe) and the
// background are not traced (w = 0). Writes rgb, w = 1 where traced.
#include "common.glsl"
FRAME_BLOCK
#include "brdf.glsl"
#include "sampling.glsl"
#include "rayutil.glsl"
#include "terminator.glsl"
#include "filter.glsl"
#define ENV_BINDING 11
#include "environment.glsl"
#include "ibl.glsl"
#define ALPHA_BINDING 6
#define TEXTURES_BINDING 7
#include "alpha.glsl"
#define BVH_SET 1
#define BVH_BINDING 0
#include "bvh.glsl"
#include "shares.glsl"

layout(local_size_x = 8, local_size_y = 8) in;
layout(constant_id = 15) const uint WORK_SHARES = 1u;

layout(set = 0, binding = 1, rgba32f) uniform readonly image2D g_position;
layout(set = 0, binding = 2, rgba32f) uniform readonly image2D g_normal;
layout(set = 0, binding = 3, rgba8) uniform readonly image2D g_pbr;   // roughness, metallic, occlusion
layout(std430, set = 0, binding = 4) writeonly buffer Raw { vec4 raw[]; };
layout(set = 0, binding = 5) uniform samplerBuffer materials;     // MATERIAL_TEXELS per material
layout(set = 0, binding = 8) uniform samplerBuffer instances;     // 6 per instance: model rows 0-2, normal rows 3-5
layout(set = 0, binding = 9) uniform samplerBuffer vertices;      // 2 texels per vertex: (p, n.x), (n.yz, uv)
layout(set = 0, binding = 10) uniform usamplerBuffer triangles;   // 2 per flat triangle (engine/gpu/pathscene.py)
layout(set = 0, binding = 12, rgba32f) uniform readonly image2D h_position;   // the previous frame's G-buffer
layout(set = 0, binding = 13, rgba32f) uniform readonly image2D h_normal;
layout(std430, set = 0, binding = 14) readonly buffer Prev { vec4 prev[]; };  // the previous frame's filtered GI

#include "scene_surface.glsl"
#include "light_sample.glsl"
#include "hit_shading.glsl"

const float NORMAL_COS = 0.8;     // the previous frame's pixel saw the hit's surface: normals within ~37 degrees
const float PLANE_REL = 0.01;     // and its point within 1% of the depth plus PLANE_PIXELS pixels of the hit's plane
const float PLANE_PIXELS = 2.0;

// The irradiance (over pi) at the hit last frame: where the previous frame's G-buffer saw its surface, the GI found
// there; else `own` (the ray's pixel's: w = 0 where there is none).
vec4 irradiance_at(Surface s, vec4 own) {
    vec4 clip = frame.prev_view_proj * vec4(s.p, 1.0);
    if (clip.w <= 0.0) return own;
    vec2 ndc = clip.xy / clip.w;
    if (any(greaterThanEqual(abs(ndc), vec2(1.0)))) return own;
    ivec2 q = ivec2((ndc * 0.5 + 0.5) * vec2(frame.width, frame.height));
    q = clamp(q, ivec2(0), ivec2(int(frame.width) - 1, int(frame.height) - 1));
    vec4 qn = imageLoad(h_normal, q);
    if (qn.w <= 0.0 || dot(qn.xyz, s.ns) < NORMAL_COS) return own;
    float tol = PLANE_REL * clip.w + PLANE_PIXELS * pixel_footprint(clip.w);
    if (abs(dot(imageLoad(h_position, q).xyz - s.p, qn.xyz)) > tol) return own;
    vec4 e = prev[uint(q.y) * frame.width + uint(q.x)];
    return e.w > 0.0 ? e : own;
}

// The hit's diffuse lobe lit by the irradiance at it last frame (none on a first frame).
vec3 bounced(Surface s, vec3 v, uint pixel) {
    if (frame.history_reset > 0.5 || s.metallic >= 1.0) return vec3(0.0);
    vec4 e = irradiance_at(s, prev[pixel]);
    if (e.w <= 0.0) return vec3(0.0);
    vec3 spec = ibl_specular_albedo(s.ns, v, s.base, s.metallic, s.roughness, s.spec);
    return (1.0 - spec) * (1.0 - s.metallic) * s.base * e.rgb;
}

void main() {
    ivec2 px = ivec2(share_invocation(WORK_SHARES, gl_WorkGroupSize).xy);
    uint w = frame.width, h = frame.height;
    if (px.x >= int(w) || px.y >= int(h)) return;
    uint pixel = uint(px.y) * w + uint(px.x);
    vec4 nrm = imageLoad(g_normal, px);
    if (nrm.w <= 0.0 || imageLoad(g_pbr, px).y >= 1.0) {
        raw[pixel] = vec4(0.0);
        return;
    }
    vec3 n = nrm.xyz, p = imageLoad(g_position, px).xyz;
    vec3 v = normalize(frame.eye - p);
    if (dot(n, v) <= 0.0) n = normalize(n - v * (dot(n, v) - 1e-3));   // seen from behind: bent towards the eye
    vec3 d = cosine_hemisphere(n, r2(frame.frame_index, pixel_rotation(uvec2(px), 0x68e31da4u)));
    BvhHit hit = bvh_intersect(offset_ray(p, n), d, 0.0, BVH_INF);
    vec3 radiance;
    if (hit.prim < 0) {
        radiance = environment_radiance(d);
    } else {
        Surface s = surface_at(hit, d);
        radiance = hit_direct(s, -d, pixel_rotation(uvec2(px), 0x1b873593u));
        radiance += bounced(s, -d, pixel);
    }
    if (any(isnan(radiance)) || any(isinf(radiance))) radiance = vec3(0.0);
    raw[pixel] = vec4(radiance, 1.0);
}
