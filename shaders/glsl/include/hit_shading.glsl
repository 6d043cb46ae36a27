// The radiance leaving a ray's hit towards the ray's origin as the real-time frame's ray passes shade it
// (reflect.comp, transparency.comp): emission, each analytic light sampled once (an R2 point rotated per pixel,
// `rot`) with a shadow ray, and the environment by split sum (ibl.glsl). Needs scene_surface.glsl,
// light_sample.glsl, ibl.glsl and sampling.glsl.
#ifndef HIT_SHADING_GLSL
#define HIT_SHADING_GLSL

// The radiance leaving the hit `s` towards -d (the ray's origin).
vec3 shade_hit(Surface s, vec3 d, vec2 rot) {
    vec3 v = -d;
    if (dot(s.ns, v) <= 0.0) s.ns = s.ng;   // a shading normal facing away from the viewer: the geometric one
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
    vec3 spec = ibl_specular_albedo(s.ns, v, s.base, s.metallic, s.roughness, s.spec);
    color += ibl_diffuse(s.ns, spec, s.base, s.metallic) + spec * ibl_specular_radiance(s.ns, v, s.roughness);
    return color;
}

#endif
