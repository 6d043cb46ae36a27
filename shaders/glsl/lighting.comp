#version 450
#extension GL_GOOGLE_include_directive : require
// Deferred lighting: albedo, normal, material, per-light visibility masks and AO -> tonemapped sRGB colour, with
// glTF's metallic-roughness BRDF (brdf.glsl) for every light, the ambient term times AO and the material's
// occlusion, plus the emitted radiance.
#include "common.glsl"
#include "brdf.glsl"
FRAME_BLOCK

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
    if (nrm.w <= 0.0) {
        // Background: a simple sky gradient by the view direction's elevation is not known here
        // (no ray), so use the ambient colour with a vertical gradient over the image.
        float t = float(px.y) / float(max(h, 1u));
        color = frame.ambient * mix(1.2, 0.6, t);
    } else {
        vec3 p = imageLoad(g_position, px).xyz;
        vec3 n = nrm.xyz;
        vec3 albedo = imageLoad(g_albedo, px).rgb;
        vec4 pbr = imageLoad(g_pbr, px);
        float roughness = pbr.x, metallic = pbr.y, occlusion = pbr.z;
        vec3 v = normalize(frame.eye - p);
        uint pixel = uint(px.y) * w + uint(px.x);
        vec3 direct = vec3(0.0);
        for (uint i = 0u; i < frame.light_count; ++i) {
            vec3 wi;
            vec3 li = incident(frame.lights[i], p, wi);
            float cos_theta = max(dot(n, wi), 0.0);
            // Intensities are pi-normalized: a white Lambert surface facing a light of irradiance 1 reflects 1.
            direct += li * cos_theta * masks[i * w * h + pixel] * brdf_pi(n, v, wi, albedo, metallic, roughness);
        }
        vec3 ambient = frame.ambient * (ao[pixel] * occlusion) * ambient_reflectance(n, v, albedo, metallic, roughness);
        color = direct + ambient + imageLoad(g_emissive, px).rgb;
    }
    color *= frame.exposure;   // exposure
    imageStore(out_hdr, px, vec4(color, 1.0));
    imageStore(out_color, px, vec4(srgb_encode(tonemap_aces(color)), 1.0));
}
