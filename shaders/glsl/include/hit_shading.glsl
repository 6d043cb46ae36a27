// The light a secondary ray's hit (scene_surface.glsl) sends back along the ray from the scene's emitters and analytic
// lights, as the path tracer's vertex: its emission and each light sampled once with a shadow ray (light_sample.glsl;
// from the terminator shift's point where frame.shadow_terminator is on). Shared by the reflection and the diffuse
// GI rays (reflect.comp, gi.comp). Needs scene_surface.glsl, light_sample.glsl and sampling.glsl.
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

#endif
