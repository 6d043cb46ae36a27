// The diffuse GI's irradiance (over pi) of the previous frame at a world point, read where the previous frame's
// G-buffer saw the same surface (its `gi_prev`, upsampled, at the point's reprojected pixel): the bounced light the
// GI rays (gi.comp) and the reflection and transmission rays' hits (hit_shading.glsl) light a surface with. The
// including shader defines GI_LOOKUP_BINDING (three set-0 bindings from it: the previous G-buffer's position and
// normal, and the GI) and includes common.glsl (the frame block), filter.glsl and scene_surface.glsl first.
#ifndef GI_LOOKUP_GLSL
#define GI_LOOKUP_GLSL

layout(set = 0, binding = GI_LOOKUP_BINDING, rgba32f) uniform readonly image2D h_position;
layout(set = 0, binding = GI_LOOKUP_BINDING + 1, rgba32f) uniform readonly image2D h_normal;
layout(std430, set = 0, binding = GI_LOOKUP_BINDING + 2) readonly buffer GIPrev { vec4 gi_prev[]; };

const float GI_NORMAL_COS = 0.8;   // the previous frame's pixel saw the point's surface: normals within ~37 degrees
const float GI_PLANE_REL = 0.01;   // and its point within 1% of the depth plus GI_PLANE_PIXELS pixels of that plane
const float GI_PLANE_PIXELS = 2.0;

// The irradiance at s's point last frame where the previous frame's G-buffer saw its surface; else `own`
// (w = 0: none). None after a history reset.
vec4 gi_irradiance_at(Surface s, vec4 own) {
    if (frame.history_reset > 0.5) return vec4(0.0);
    vec4 clip = frame.prev_view_proj * vec4(s.p, 1.0);
    if (clip.w <= 0.0) return own;
    vec2 ndc = clip.xy / clip.w;
    if (any(greaterThanEqual(abs(ndc), vec2(1.0)))) return own;
    ivec2 q = ivec2((ndc * 0.5 + 0.5) * vec2(frame.width, frame.height));
    q = clamp(q, ivec2(0), ivec2(int(frame.width) - 1, int(frame.height) - 1));
    vec4 qn = imageLoad(h_normal, q);
    if (qn.w <= 0.0 || dot(qn.xyz, s.ns) < GI_NORMAL_COS) return own;
    float tol = GI_PLANE_REL * clip.w + GI_PLANE_PIXELS * pixel_footprint(clip.w);
    if (abs(dot(imageLoad(h_position, q).xyz - s.p, qn.xyz)) > tol) return own;
    vec4 e = gi_prev[uint(q.y) * frame.width + uint(q.x)];
    return e.w > 0.0 ? e : own;
}

// s's diffuse lobe towards v lit by the irradiance (over pi) e.
vec3 gi_diffuse(Surface s, vec3 v, vec3 e) {
    vec3 spec = ibl_specular_albedo(s.ns, v, s.base, s.metallic, s.roughness, s.spec);
    return (1.0 - spec) * (1.0 - s.metallic) * s.base * e;
}

#endif
