#version 450
#extension GL_GOOGLE_include_directive : require
// Deferred lighting: albedo, normal, material, per-light visibility masks and AO -> HDR radiance and tonemapped sRGB
// colour, with glTF's metallic-roughness BRDF (brdf.glsl) for every light, the environment (environment.glsl) by
// split-sum image-based lighting (ibl.glsl: SH irradiance for the diffuse lobe, GGX-prefiltered radiance times the BRDF
// table for the specular one) times AO and the material's occlusion, plus the emitted radiance. Where a reflection
// ray was traced (reflect.comp), its filtered radiance is the specular lobe's instead; where a diffuse GI ray was
// (gi.comp), its filtered irradiance lights the diffuse lobe instead of the environment's times AO; where a transparent
// surface was traced (transparency.comp), the radiance through / behind it is mixed in by its weight. The background
// is the environment seen along the pixel's ray, with each directional light's disc drawn where its angle is > 0.
// `out_hdr` holds the radiance (before exposure); `out_color` its tone-mapped image at frame.exposure (auto
// exposure rewrites it: exposure.comp).
#include "common.glsl"
#include "background_ray.glsl"
#include "brdf.glsl"
FRAME_BLOCK
#define ENV_BINDING 10
#include "environment.glsl"
#include "ibl.glsl"

layout(local_size_x = 8, local_size_y = 8) in;
layout(set = 0, binding = 1, rgba32f) uniform readonly image2D g_position;
layout(set = 0, binding = 2, rgba32f) uniform readonly image2D g_normal;
layout(set = 0, binding = 3, rgba16f) uniform readonly image2D g_albedo;
layout(std430, set = 0, binding = 4) readonly buffer Masks { float masks[]; };   // [light][y][x], 1 = lit
layout(std430, set = 0, binding = 5) readonly buffer AO { float ao[]; };         // [y][x], 1 = open
layout(set = 0, binding = 6, rgba8) uniform writeonly image2D out_color;
layout(set = 0, binding = 7, rgba16f) uniform writeonly image2D out_hdr;
layout(set = 0, binding = 8, rgba8) uniform readonly image2D g_pbr;        // roughness, metallic, occlusion
layout(set = 0, binding = 9, rgba16f) uniform readonly image2D g_emissive;
// the filtered reflection radiance per pixel (reflect_filter.comp): rgb, w > 0 where a ray was traced
layout(std430, set = 0, binding = 11) readonly buffer Reflections { vec4 reflections[]; };
layout(set = 0, binding = 12, r32ui) uniform readonly uimage2D g_material;   // the material's index
layout(set = 0, binding = 13) uniform samplerBuffer materials;               // MATERIAL_TEXELS per material
// the filtered diffuse GI per pixel (gi.comp, reflect_filter.comp): irradiance / pi, w > 0 where a ray was traced
layout(std430, set = 0, binding = 14) readonly buffer GI { vec4 gi[]; };
// transparent surfaces (transparency.comp): the radiance through / behind them, rgb, and its weight w (0: opaque)
layout(std430, set = 0, binding = 15) readonly buffer Transparency { vec4 transp[]; };

// Radiance arriving from light `l` at `p` (before visibility and the cosine term), and the unit direction to it.
vec3 incident(Light l, vec3 p, out vec3 wi) {
    int type = int(l.pos_type.w);
    if (type == LIGHT_DIRECTIONAL) {
        wi = -l.dir_radius.xyz;
        return l.color.rgb;
    }
    vec3 d = l.pos_type.xyz - p;
    float dist2 = max(dot(d, d), 1e-8);
    wi = d * inversesqrt(dist2);
    vec3 radiance = l.color.rgb / dist2;
    if (type == LIGHT_SPOT) {
        float cos_axis = dot(-wi, l.dir_radius.xyz);
        radiance *= smoothstep(l.color.w, l.u.w, cos_axis);
    } else if (type == LIGHT_RECT) {
        // One-sided emitter: intensity along its normal, cosine falloff away from it.
        radiance *= max(dot(-wi, l.dir_radius.xyz), 0.0);
    }
    return radiance;
}

void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    uint w = frame.width, h = frame.height;
    if (px.x >= int(w) || px.y >= int(h)) return;
    vec4 nrm = imageLoad(g_normal, px);
    vec3 color;
    float ray = nrm.w <= 0.0 ? imageLoad(g_position, px).w : 0.0;   // a traced camera's ray (background_ray.glsl)
    if (ray == BACKGROUND_NO_RAY) {
        color = vec3(0.0);   // no ray: outside a fisheye's circle, past a folding distortion
    } else if (nrm.w <= 0.0) {
        vec2 ndc = (vec2(px) + 0.5) / vec2(w, h) * 2.0 - 1.0;
        vec4 far = frame.inv_view_proj * vec4(ndc, 1.0, 1.0);
        vec3 dir = ray < 0.0 ? decode_background_ray(ray) : normalize(far.xyz / far.w - frame.eye);
        color = environment_radiance(dir);
        for (uint i = 0u; i < frame.light_count; ++i) {   // sun discs: irradiance over the disc's solid angle
            Light l = frame.lights[i];
            float tan_r = l.u.w;
            if (int(l.pos_type.w) != LIGHT_DIRECTIONAL || tan_r <= 0.0) continue;
            float cos_r = inversesqrt(1.0 + tan_r * tan_r);
            if (dot(dir, -l.dir_radius.xyz) >= cos_r) color += l.color.rgb * PI / (2.0 * PI * (1.0 - cos_r));
        }
    } else {
        vec3 p = imageLoad(g_position, px).xyz;
        vec3 n = nrm.xyz;
        vec3 albedo = imageLoad(g_albedo, px).rgb;
        vec4 pbr = imageLoad(g_pbr, px);
        float roughness = pbr.x, metallic = pbr.y, occlusion = pbr.z;
        // KHR_materials_specular's factors (brdf.glsl fresnel_gltf): the material's texel 5 (the core's without one)
        uint mat = imageLoad(g_material, px).x;
        bool known = mat < uint(textureSize(materials)) / uint(MATERIAL_TEXELS);
        vec4 spec_f = known ? texelFetch(materials, MATERIAL_TEXELS * int(mat) + 5) : vec4(1.0);
        vec3 v = normalize(frame.eye - p);
        uint pixel = uint(px.y) * w + uint(px.x);
        vec3 direct = vec3(0.0);
        for (uint i = 0u; i < frame.light_count; ++i) {
            vec3 wi;
            vec3 li = incident(frame.lights[i], p, wi);
            float cos_theta = max(dot(n, wi), 0.0);
            // Intensities are pi-normalized: a white Lambert surface facing a light of irradiance 1 reflects 1.
            vec3 f = brdf_pi_spec(n, v, wi, albedo, metallic, roughness, spec_f);
            direct += li * cos_theta * masks[i * w * h + pixel] * f;
        }
        // split sum (ibl.glsl); where a reflection ray was traced (reflect.comp, filtered), its radiance replaces
        // the prefiltered environment in the specular lobe: it already holds the occlusion that AO stands in for
        vec3 spec = ibl_specular_albedo(n, v, albedo, metallic, roughness, spec_f);
        // the diffuse GI, where traced, holds the occlusion AO stands in for (the material's occlusion map stays)
        vec4 bounce = gi[pixel];
        vec3 ambient = bounce.w > 0.0 ? (1.0 - spec) * (1.0 - metallic) * albedo * bounce.rgb * occlusion
                                      : ibl_diffuse(n, spec, albedo, metallic) * (ao[pixel] * occlusion);
        vec4 traced = reflections[pixel];
        if (traced.w > 0.0) ambient += spec * traced.rgb;
        else ambient += spec * ibl_specular_radiance(n, v, roughness) * (ao[pixel] * occlusion);
        color = direct + ambient + imageLoad(g_emissive, px).rgb;
        vec4 through = transp[pixel];
        color = mix(color, through.rgb, through.w);
    }
    imageStore(out_hdr, px, vec4(color, 1.0));
    imageStore(out_color, px, vec4(srgb_encode(tonemap(color * frame.exposure, frame.tonemap)), 1.0));
}
