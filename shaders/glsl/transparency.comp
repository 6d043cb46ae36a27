#version 450
#extension GL_GOOGLE_include_directive : require
// Transparent surfaces of the real-time frame, drawn by rays from the G-buffer (engine/passes/transparency.py).
// A transmissive material (KHR_materials_transmission) seen at a pixel: the mirror ray weighted by exact Fresnel at
// its ior (the camera outside) and the refracted ray followed through the solid's interfaces (smooth refraction at
// each, total internal reflection where there is no refracted ray; the other branch left out), up to
// MAX_INTERFACES of them, tinted by each crossed surface's base colour; the first opaque hit is shaded as the
// reflections pass shades its hits (hit_shading.glsl), a ray leaving the scene sees the environment. Roughness
// is not blurred: a rough glass looks smooth here. A BLEND material: the camera ray continued behind the surface,
// its hit shaded the same way, seen with weight 1 - base alpha (the texture's alpha is not read; the G-buffer
// keeps the surface where alpha >= 0.5, as MASK does). Writes per pixel rgb = that radiance, w = its weight against the lit surface (the
// lighting pass mixes): transmission x (1 - metallic) for glass, 1 - base alpha for BLEND, 0 elsewhere.
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
// the interfaces a refracted ray crosses at most (a closed mesh: 2 each)
layout(constant_id = 16) const uint MAX_INTERFACES = 4u;

layout(set = 0, binding = 1, rgba32f) uniform readonly image2D g_position;
layout(set = 0, binding = 2, rgba32f) uniform readonly image2D g_normal;
layout(set = 0, binding = 3, rgba16f) uniform readonly image2D g_albedo;
layout(std430, set = 0, binding = 4) writeonly buffer Out { vec4 transp[]; };
layout(set = 0, binding = 5) uniform samplerBuffer materials;     // MATERIAL_TEXELS per material
layout(set = 0, binding = 8) uniform samplerBuffer instances;     // 6 per instance: model rows 0-2, normal rows 3-5
layout(set = 0, binding = 9) uniform samplerBuffer vertices;      // 2 texels per vertex: (p, n.x), (n.yz, uv)
layout(set = 0, binding = 10) uniform usamplerBuffer triangles;   // 2 per flat triangle (engine/gpu/pathscene.py)
layout(set = 0, binding = 12, r32ui) uniform readonly uimage2D g_material;   // the material's index
layout(set = 0, binding = 13, rgba8) uniform readonly image2D g_pbr;   // roughness, metallic, occlusion

#include "scene_surface.glsl"
#include "dielectric.glsl"
#include "light_sample.glsl"
#define EMITTERS_BINDING 17
#include "emitters.glsl"
#include "filter.glsl"
#define GI_LOOKUP_BINDING 18
#include "gi_lookup.glsl"
#include "hit_shading.glsl"

// The radiance along the ray (o, d): its first hit shaded, or the environment.
vec3 trace_shaded(vec3 o, vec3 d, vec2 rot, vec4 own) {
    BvhHit hit = bvh_intersect(o, d, 0.0, BVH_INF);
    return hit.prim < 0 ? environment_radiance(d) : shade_hit(surface_at(hit, d), d, rot, own);
}

// The radiance refracted along (o, d) inside a solid, followed through up to MAX_INTERFACES interfaces.
vec3 trace_refracted(vec3 o, vec3 d, vec2 rot, vec4 own) {
    vec3 throughput = vec3(1.0);
    for (uint k = 0u; k < MAX_INTERFACES; ++k) {
        BvhHit hit = bvh_intersect(o, d, 0.0, BVH_INF);
        if (hit.prim < 0) return throughput * environment_radiance(d);
        Surface s = surface_at(hit, d);
        if (s.transmission <= 0.0) return throughput * shade_hit(s, d, rot, own);
        vec3 v = -d;
        vec3 n = dot(s.ns, v) > 0.0 ? s.ns : s.ng;
        float cos_t, eta = s.front ? s.ior : 1.0 / s.ior;
        float f = fresnel_dielectric(dot(n, v), eta, cos_t);
        if (f >= 1.0) {   // total internal reflection
            d = reflect(d, n);
            o = offset_ray(s.p, s.ng);
        } else {
            d = refract_dir(v, n, dot(n, v), cos_t, eta);
            o = offset_ray(s.p, -s.ng);
            throughput *= s.base;
        }
    }
    return throughput * environment_radiance(d);
}

void main() {
    ivec2 px = ivec2(share_invocation(WORK_SHARES, gl_WorkGroupSize).xy);
    uint w = frame.width, h = frame.height;
    if (px.x >= int(w) || px.y >= int(h)) return;
    uint pixel = uint(px.y) * w + uint(px.x);
    vec4 nrm = imageLoad(g_normal, px);
    uint mat = imageLoad(g_material, px).x;
    if (nrm.w <= 0.0 || mat >= uint(textureSize(materials)) / uint(MATERIAL_TEXELS)) {
        transp[pixel] = vec4(0.0);
        return;
    }
    int m = MATERIAL_TEXELS * int(mat);
    uint flags = floatBitsToUint(texelFetch(materials, m + 4).y);
    vec4 tr = texelFetch(materials, m + 6);   // transmission, ior
    float metallic = imageLoad(g_pbr, px).y;
    float weight = (flags & MATERIAL_TRANSMISSIVE) != 0u ? tr.x * (1.0 - metallic) : 0.0;
    bool blend = (flags & MATERIAL_BLEND) != 0u && weight <= 0.0;
    if (weight <= 0.0 && !blend) {
        transp[pixel] = vec4(0.0);
        return;
    }
    vec3 n = nrm.xyz, p = imageLoad(g_position, px).xyz;
    vec3 v = normalize(frame.eye - p);
    if (dot(n, v) <= 0.0) n = normalize(n - v * (dot(n, v) - 1e-3));   // seen from behind: bent towards the eye
    vec2 rot = pixel_rotation(uvec2(px), 0x68e31da4u);
    vec4 own = GI_BOUNCE && frame.history_reset < 0.5 ? gi_prev[pixel] : vec4(0.0);
    vec3 radiance;
    if (blend) {   // what lies behind, seen with weight 1 - alpha
        radiance = trace_shaded(offset_ray(p, -n), -v, rot, own);
        weight = 1.0 - texelFetch(materials, m).a;
    } else {
        float cos_t, cos_i = dot(n, v);
        float f = fresnel_dielectric(cos_i, tr.y, cos_t);
        radiance = f * trace_shaded(offset_ray(p, n), reflect(-v, n), rot, own);
        if (f < 1.0) {
            vec3 tint = imageLoad(g_albedo, px).rgb;
            vec3 d = refract_dir(v, n, cos_i, cos_t, tr.y);
            radiance += (1.0 - f) * tint * trace_refracted(offset_ray(p, -n), d, rot, own);
        }
    }
    if (any(isnan(radiance)) || any(isinf(radiance))) radiance = vec3(0.0);
    transp[pixel] = vec4(radiance, weight);
}
