// The light a secondary ray's hit (scene_surface.glsl) sends back along the ray, as the real-time frame's ray passes
// shade it. hit_direct: its emission and each analytic light sampled once with a shadow ray (light_sample.glsl; from
// the terminator shift's point where frame.shadow_terminator is on), the path tracer's vertex, for the diffuse GI rays
// (gi.comp). shade_hit: that plus the environment by split sum (ibl.glsl), for the reflection and transmission rays
// (reflect.comp, transparency.comp). Needs scene_surface.glsl, light_sample.glsl, ibl.glsl and sampling.glsl.
#ifndef HIT_SHADING_GLSL
#define HIT_SHADING_GLSL

// Emission plus next-event estimation at `s` towards v (= -ray direction); `rot` decorrelates the pixels' light
// samples (sampling.glsl r2). A shading normal facing away from v becomes the geometric one (in s).
vec3 hit_direct(inout Surface s, vec3 v, vec2 rot) {
    if (dot(s.ns, v) <= 0.0) s.ns = s.ng;
    vec3 color = s.emission;
    for (uint i = 0u; i < frame.light_count; ++i) {
        vec3 wi, li;
        float dist, pdf;
        vec2 xi = r2(frame.frame_index * MAX_LIGHTS + i, rot);
        if (!sample_light(frame.lights[i], s.po, xi, wi, dist, li, pdf)) continue;
        vec3 f = light_eval(s, v, wi);
        if (all(equal(f, vec3(0.0))) || !visible(s.po, s.ng, wi, dist, frame.scene_scale)) continue;
        // area lights: one uniform sample of the light's solid angle (pdf); delta lights: their radiance as is
        color += f * li * (pdf > 0.0 ? 1.0 / pdf : 1.0);
    }
    return color;
}

// The radiance leaving the hit `s` towards -d (the ray's origin): hit_direct and the split-sum environment.
vec3 shade_hit(Surface s, vec3 d, vec2 rot) {
    vec3 v = -d;
    vec3 color = hit_direct(s, v, rot);
    vec3 spec = ibl_specular_albedo(s.ns, v, s.base, s.metallic, s.roughness, s.spec);
    color += ibl_diffuse(s.ns, spec, s.base, s.metallic) + spec * ibl_specular_radiance(s.ns, v, s.roughness);
    return color;
}

#endif
