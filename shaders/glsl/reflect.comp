#version 450
#extension GL_GOOGLE_include_directive : require
// Ray-traced reflections from the G-buffer: per pixel one reflection ray, its direction the mirror image of the view
// about a half vector drawn from GGX's distribution of visible normals (Heitz 2018; a mirror-smooth surface's is its
// normal), traced on the scene's BVH. At the hit the surface (scene_surface.glsl) is shaded as the path tracer's first
// vertex is: its emission, each analytic light sampled once with a shadow ray (light_sample.glsl; from the terminator
// shift's point where frame.shadow_terminator is on, as the path tracer's and the raster's shadow pass), and the
// environment by split sum (ibl.glsl); a ray that leaves the scene sees the environment. Analytic lights seen along
// the ray are left out: the lighting pass's direct term holds their highlights. Pixels rougher than
// MAX_ROUGHNESS, and the background, are not traced (w = 0: the lighting keeps the prefiltered environment).
// Writes the radiance along the ray: rgb, w = 1 where traced.
#include "common.glsl"
FRAME_BLOCK
#include "brdf.glsl"
#include "sampling.glsl"
#include "rayutil.glsl"
#include "terminator.glsl"
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
// the roughest surface traced (perceptual roughness): rougher lobes are wide, their split-sum term close to the truth
layout(constant_id = 16) const float MAX_ROUGHNESS = 0.6;

layout(set = 0, binding = 1, rgba32f) uniform readonly image2D g_position;
layout(set = 0, binding = 2, rgba32f) uniform readonly image2D g_normal;
layout(set = 0, binding = 3, rgba8) uniform readonly image2D g_pbr;   // roughness, metallic, occlusion
layout(std430, set = 0, binding = 4) writeonly buffer Raw { vec4 raw[]; };
layout(set = 0, binding = 5) uniform samplerBuffer materials;     // MATERIAL_TEXELS per material
layout(set = 0, binding = 8) uniform samplerBuffer instances;     // 6 per instance: model rows 0-2, normal rows 3-5
layout(set = 0, binding = 9) uniform samplerBuffer vertices;      // 2 texels per vertex: (p, n.x), (n.yz, uv)
layout(set = 0, binding = 10) uniform usamplerBuffer triangles;   // 2 per flat triangle (engine/gpu/pathscene.py)

#include "scene_surface.glsl"
#include "light_sample.glsl"
#define EMITTERS_BINDING 17
#include "emitters.glsl"
#include "filter.glsl"
#define GI_LOOKUP_BINDING 12
#include "gi_lookup.glsl"
#include "hit_shading.glsl"

void main() {
    ivec2 px = ivec2(share_invocation(WORK_SHARES, gl_WorkGroupSize).xy);
    uint w = frame.width, h = frame.height;
    if (px.x >= int(w) || px.y >= int(h)) return;
    uint pixel = uint(px.y) * w + uint(px.x);
    vec4 nrm = imageLoad(g_normal, px);
    float roughness = imageLoad(g_pbr, px).x;
    if (nrm.w <= 0.0 || roughness > MAX_ROUGHNESS) {
        raw[pixel] = vec4(0.0);
        return;
    }
    vec3 n = nrm.xyz, p = imageLoad(g_position, px).xyz;
    vec3 v = normalize(frame.eye - p);
    if (dot(n, v) <= 0.0) n = normalize(n - v * (dot(n, v) - 1e-3));   // seen from behind: bent towards the eye
    vec2 rot = pixel_rotation(uvec2(px), 0x5bd1e995u);
    vec3 t, b;
    basis(n, t, b);
    float r = max(roughness, MIN_ROUGHNESS);
    vec3 ve = vec3(dot(v, t), dot(v, b), max(dot(v, n), 1e-4));
    vec3 hl = sample_vndf(ve, r * r, r2(frame.frame_index, pixel_rotation(uvec2(px), 0x27d4eb2fu)));
    vec3 d = reflect(-v, t * hl.x + b * hl.y + n * hl.z);
    if (dot(d, n) <= 0.0) d = reflect(-v, n);   // below the surface (a grazing view of a rough lobe): the mirror ray
    vec3 o = offset_ray(p, n);
    BvhHit hit = bvh_intersect(o, d, 0.0, BVH_INF);
    vec4 own = GI_BOUNCE && frame.history_reset < 0.5 ? gi_prev[pixel] : vec4(0.0);
    vec3 radiance = hit.prim < 0 ? environment_radiance(d) : shade_hit(surface_at(hit, d), d, rot, own);
    if (any(isnan(radiance)) || any(isinf(radiance))) radiance = vec3(0.0);
    raw[pixel] = vec4(radiance, 1.0);
}
