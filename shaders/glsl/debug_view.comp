#version 450
#extension GL_GOOGLE_include_directive : require
// Debug views: replaces the final colour with one AOV (setting `view`), on the GPU so a window can show it.
// Same mappings as engine.frame.aov_to_rgba where it can: normals n * 0.5 + 0.5, albedo gamma 2.2,
// position by the scene bounds, depth 1 (near) .. 0 (far) over the scene's depth range, masks averaged over the
// lights, AO as is, history length / 32 in grey with fresh (disoccluded, n = 1) pixels in red; ids as a colour per
// id; motion as red / green around grey; roughness and metallic in grey; emissive and radiance (the lit linear
// colour before tonemapping) clamped, gamma 2.2 as albedo.
#include "common.glsl"
FRAME_BLOCK

layout(local_size_x = 8, local_size_y = 8) in;
layout(set = 0, binding = 1, rgba32f) uniform readonly image2D g_position;
layout(set = 0, binding = 2, rgba32f) uniform readonly image2D g_normal;
layout(set = 0, binding = 3, rgba16f) uniform readonly image2D g_albedo;
layout(std430, set = 0, binding = 4) readonly buffer MasksRaw { float masks_raw[]; };
layout(std430, set = 0, binding = 5) readonly buffer Masks { float masks[]; };
layout(std430, set = 0, binding = 6) readonly buffer AORaw { float ao_raw[]; };
layout(std430, set = 0, binding = 7) readonly buffer AO { float ao[]; };
layout(std430, set = 0, binding = 8) readonly buffer HistLen { float hist_len[]; };
layout(set = 0, binding = 9, rgba8) uniform writeonly image2D out_color;
layout(set = 0, binding = 10, r32ui) uniform readonly uimage2D g_triangle;
layout(set = 0, binding = 11, r32ui) uniform readonly uimage2D g_object;
layout(set = 0, binding = 12, r32ui) uniform readonly uimage2D g_material;
layout(set = 0, binding = 13, rg32f) uniform readonly image2D g_motion;
layout(set = 0, binding = 14, rgba8) uniform readonly image2D g_pbr;        // roughness, metallic, occlusion
layout(set = 0, binding = 15, rgba16f) uniform readonly image2D g_emissive;
layout(set = 0, binding = 16, rgba16f) uniform readonly image2D g_hdr;        // the lit linear colour
layout(set = 0, binding = 17, r32ui) uniform readonly uimage2D g_instance;
layout(set = 0, binding = 18, rgba16f) uniform readonly image2D taa_hist;    // TAA's resolve; a: frames it holds
layout(std430, set = 0, binding = 19) readonly buffer ReflRaw { vec4 refl_raw[]; };   // reflect.comp's rays
layout(std430, set = 0, binding = 20) readonly buffer Refl { vec4 refl[]; };          // filtered (reflect_filter)
layout(std430, set = 0, binding = 21) readonly buffer GIRaw { vec4 gi_raw[]; };       // gi.comp's rays
layout(std430, set = 0, binding = 22) readonly buffer GI { vec4 gi[]; };              // filtered irradiance / pi
layout(std430, set = 0, binding = 23) readonly buffer Transp { vec4 transp[]; };      // transparency.comp's rays
layout(push_constant) uniform Push { uint view; } pc;

// A colour per id (black for none), different for neighbouring ids.
vec3 id_color(uint id) {
    if (id == 0xFFFFFFFFu) return vec3(0.0);
    uint h = id * 2654435761u;
    h ^= h >> 15;
    h *= 2246822519u;
    h ^= h >> 13;
    return 0.25 + 0.75 * vec3(h & 255u, (h >> 8) & 255u, (h >> 16) & 255u) / 255.0;
}


void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    uint w = frame.width, h = frame.height;
    if (px.x >= int(w) || px.y >= int(h)) return;
    uint pixel = uint(px.y) * w + uint(px.x);
    uint n_pixels = w * h;
    vec4 nrm = imageLoad(g_normal, px);
    bool covered = nrm.w > 0.0;
    vec4 pos = imageLoad(g_position, px);
    vec3 lo = frame.bounds_min, hi = frame.bounds_max;
    vec3 c = vec3(0.0);
    uint v = pc.view;
    if (v == VIEW_POSITION) {
        c = covered ? clamp((pos.xyz - lo) / max(hi - lo, vec3(1e-12)), 0.0, 1.0) : vec3(0.0);
    } else if (v == VIEW_NORMAL) {
        c = covered ? nrm.xyz * 0.5 + 0.5 : vec3(0.0);
    } else if (v == VIEW_ALBEDO) {
        c = pow(clamp(imageLoad(g_albedo, px).rgb, 0.0, 1.0), vec3(1.0 / 2.2));
    } else if (v == VIEW_DEPTH) {
        float dist = length(frame.eye - 0.5 * (lo + hi));
        float r = 0.5 * length(hi - lo);
        float near = max(dist - r, frame.near), far = max(dist + r, near + 1e-6);
        c = covered ? vec3(clamp(1.0 - (pos.w - near) / (far - near), 0.0, 1.0)) : vec3(0.0);
    } else if (v == VIEW_SHADOW_RAW || v == VIEW_SHADOW) {
        float s = 0.0;
        uint n = frame.light_count;
        for (uint i = 0u; i < n; ++i)
            s += v == VIEW_SHADOW ? masks[i * n_pixels + pixel] : masks_raw[i * n_pixels + pixel];
        c = vec3(n > 0u ? s / float(n) : 1.0);
    } else if (v == VIEW_AO_RAW) {
        c = vec3(ao_raw[pixel]);
    } else if (v == VIEW_AO) {
        c = vec3(ao[pixel]);
    } else if (v == VIEW_TRIANGLE_ID) {
        c = id_color(imageLoad(g_triangle, px).x);
    } else if (v == VIEW_OBJECT_ID) {
        c = id_color(imageLoad(g_object, px).x);
    } else if (v == VIEW_INSTANCE_ID) {
        c = id_color(imageLoad(g_instance, px).x);
    } else if (v == VIEW_MATERIAL_ID) {
        c = id_color(imageLoad(g_material, px).x);
    } else if (v == VIEW_MOTION) {   // x right: red, y down: green, 8 pixels = full
        vec2 m = imageLoad(g_motion, px).xy;
        c = covered ? vec3(0.5 + m / 16.0, 0.5) : vec3(0.0);
    } else if (v == VIEW_ROUGHNESS) {
        c = covered ? vec3(imageLoad(g_pbr, px).x) : vec3(0.0);
    } else if (v == VIEW_METALLIC) {
        c = covered ? vec3(imageLoad(g_pbr, px).y) : vec3(0.0);
    } else if (v == VIEW_EMISSIVE) {
        c = pow(clamp(imageLoad(g_emissive, px).rgb, 0.0, 1.0), vec3(1.0 / 2.2));
    } else if (v == VIEW_RADIANCE) {
        c = pow(clamp(imageLoad(g_hdr, px).rgb, 0.0, 1.0), vec3(1.0 / 2.2));
    } else if (v == VIEW_TAA_HISTORY) {   // red: TAA started over here this frame; grey: 16 frames = white
        float n = imageLoad(taa_hist, px).a;
        c = n <= 1.0 ? vec3(1.0, 0.0, 0.0) : vec3(clamp(n / 16.0, 0.0, 1.0));
    } else if (v == VIEW_REFLECTION_RAW || v == VIEW_REFLECTION || v == VIEW_GI_RAW || v == VIEW_GI) {
        // untraced pixels: dark blue
        vec4 r = v == VIEW_REFLECTION ? refl[pixel]
               : v == VIEW_REFLECTION_RAW ? refl_raw[pixel]
               : v == VIEW_GI ? gi[pixel] : gi_raw[pixel];
        c = r.w > 0.0 ? pow(clamp(r.rgb, 0.0, 1.0), vec3(1.0 / 2.2)) : (covered ? vec3(0.0, 0.0, 0.15) : vec3(0.0));
    } else if (v == VIEW_TRANSPARENCY) {   // the radiance through / behind transparent surfaces; others dark blue
        vec4 r = transp[pixel];
        c = r.w > 0.0 ? pow(clamp(r.rgb, 0.0, 1.0), vec3(1.0 / 2.2)) : (covered ? vec3(0.0, 0.0, 0.15) : vec3(0.0));
    } else if (v == VIEW_HISTORY) {
        float n = hist_len[pixel];
        c = !covered ? vec3(0.0) : (n <= 1.0 ? vec3(1.0, 0.0, 0.0) : vec3(clamp(n / 32.0, 0.0, 1.0)));
    }
    imageStore(out_color, px, vec4(clamp(c, 0.0, 1.0), 1.0));
}
