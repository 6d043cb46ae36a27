// The light a secondary ray's hit (scene_surface.glsl) sends back along the ray, as the real-time frame's ray passes
// shade it. hit_direct: its emission and each analytic light sampled once with a shadow ray (light_sample.glsl; from
// the terminator shift's point where frame.shadow_terminator is on), the path tracer's vertex, for the diffuse GI rays
// (gi.comp); emitter_direct: one emissive triangle sampled likewise (emitters.glsl). shade_hit: both plus the
// environment by split sum (ibl.glsl), for the reflection and transmission rays (reflect.comp, transparency.comp).
// Needs scene_surface.glsl, light_sample.glsl, emitters.glsl, ibl.glsl and sampling.glsl.
#ifndef HIT_SHADING_GLSL
#define HIT_SHADING_GLSL

// Emission (times `emission_weight`: a multiple-importance weight where the emitters are also sampled) plus
// next-event estimation at `s` towards v (= -ray direction); `rot` decorrelates the pixels' light samples
// (sampling.glsl r2). A shading normal facing away from v becomes the geometric one (in s).
vec3 hit_direct(inout Surface s, vec3 v, vec2 rot, float emission_weight) {
    if (dot(s.ns, v) <= 0.0) s.ns = s.ng;
    vec3 color = s.emission * emission_weight;
    for (uint i = 0u; i < frame.light_count; ++i) {
        vec3 wi, li;
        float dist, pdf;
        vec2 xi = r2(frame.frame_index * MAX_LIGHTS + i, rot);
        if (!sample_light(frame.lights[i], s.po, xi, wi, dist, li, pdf)) continue;
        vec3 f = light_eval(s, v, wi);
        if (all(equal(f * li, vec3(0.0))) || !visible(s.po, s.ng, wi, dist, frame.scene_scale)) continue;
        // area lights: one uniform sample of the light's solid angle (pdf); delta lights: their radiance as is
        color += f * li * (pdf > 0.0 ? 1.0 / pdf : 1.0);
    }
    return color;
}

// Frame i's numbers for an emitter sample (emitters.glsl sample_emitter): the triangle's pick (golden-ratio sequence)
// and the point on it (R2), both rotated per pixel by `rot`.
vec3 emitter_xi(uint i, vec2 rot) {
    return vec3(fract(rot.x + 0.6180339887 * float(i)), r2(i, fract(rot.yx + vec2(0.5, 0.25))));
}

// One emissive triangle's light at `s` towards v, sampled once with a shadow ray (none without emitters).
vec3 emitter_direct(Surface s, vec3 v, vec2 rot) {
    if (emitter_count() == 0u) return vec3(0.0);
    vec3 wi, target, li;
    float pdf;
    if (!sample_emitter(s.po, emitter_xi(frame.frame_index, rot), wi, target, li, pdf) || pdf <= 0.0)
        return vec3(0.0);
    vec3 f = light_eval(s, v, wi);
    if (all(equal(f * li, vec3(0.0)))) return vec3(0.0);
    vec3 o = offset_ray(s.po, s.ng);
    return bvh_occluded(o, target - o, 0.0, 1.0) ? vec3(0.0) : f * li / pdf;
}

#ifdef GI_LOOKUP_BINDING
// the frame traces diffuse GI: a hit's diffuse lobe takes its irradiance where the last frame's GI saw its surface
layout(constant_id = 18) const bool GI_BOUNCE = false;

// The light that arrives along the diffuse ray (o, d), followed as a path of up to `bounces` + 1 hits: each hit
// lit by its emission (times the power heuristic against the emitter sampled at the ray's origin, whose normal is n0;
// past the first hit, the hit's emission counts through the emitter samples alone), its analytic lights and one
// emitter, ending at the first hit whose irradiance the previous frame's GI read back (gi_lookup.glsl;
// that holds the emitters' light too) and, past the last, taking `own` as the irradiance there (w = 0: none). The
// first hit's light samples use `rot` (the pixel's low-discrepancy rotation), the later ones random numbers from seed.
// One loop over one traversal: the hits share their code (llvmpipe runs untaken branches too).
vec3 diffuse_path(vec3 o, vec3 d, vec3 n0, vec4 own, vec2 rot, uint seed, uint bounces) {
    vec3 radiance = vec3(0.0), throughput = vec3(1.0);
    vec2 r = rot;
    for (uint k = 0u;; ++k) {
        BvhHit hit = bvh_intersect(o, d, 0.0, BVH_INF);
        if (hit.prim < 0) return radiance + throughput * environment_radiance(d);
        Surface s = surface_at(hit, d);
        vec3 v = -d;
        float w = k > 0u ? 0.0 : s.emitter != 0u ? power_heuristic(dot(n0, d) / PI, emitter_pdf(s, d, hit.t)) : 1.0;
        radiance += throughput * hit_direct(s, v, r, w);
        vec4 e = gi_irradiance_at(s, vec4(0.0));
        if (e.w > 0.0) return radiance + throughput * gi_diffuse(s, v, e.rgb);
        radiance += throughput * emitter_direct(s, v, r);
        if (k >= bounces) return radiance + (own.w > 0.0 ? throughput * gi_diffuse(s, v, own.rgb) : vec3(0.0));
        throughput *= gi_diffuse(s, v, vec3(1.0));   // the diffuse lobe's albedo: its cosine-sampled weight
        if (all(equal(throughput, vec3(0.0)))) return radiance;
        seed = pcg_hash(seed + k);
        d = cosine_hemisphere(s.ns, vec2(u01(seed), u01(pcg_hash(seed))));
        o = offset_ray(s.p, s.ng);
        r = vec2(u01(pcg_hash(seed + 1u)), u01(pcg_hash(seed + 2u)));
    }
}

// The light the hit s sends towards v beyond its emission and the analytic lights' (hit_direct): its diffuse lobe
// lit by the previous frame's GI irradiance where that frame saw its surface, else by `own`, the ray's pixel's
// (the classic ambient stand-in, as gi.comp's paths end); with neither (no history), one emitter sampled and the
// environment's diffuse light.
vec3 bounced_light(Surface s, vec3 v, vec3 spec, vec2 rot, vec4 own) {
    vec4 e = gi_irradiance_at(s, own);
    if (e.w > 0.0) return gi_diffuse(s, v, e.rgb);
    return emitter_direct(s, v, rot) + ibl_diffuse(s.ns, spec, s.base, s.metallic);
}
#endif

// The radiance leaving the hit `s` towards -d (the ray's origin): hit_direct, emitter_direct and the split-sum
// environment; where GI_BOUNCE is on, bounced_light (`own`: the ray's pixel's GI irradiance last frame) in place of
// the emitter and the environment's diffuse part (where the GI is read back, an emitter's highlight there is lost).
vec3 shade_hit(Surface s, vec3 d, vec2 rot, vec4 own) {
    vec3 v = -d;
    vec3 color = hit_direct(s, v, rot, 1.0);
    vec3 spec = ibl_specular_albedo(s.ns, v, s.base, s.metallic, s.roughness, s.spec);
    color += spec * ibl_specular_radiance(s.ns, v, s.roughness);
#ifdef GI_LOOKUP_BINDING
    if (GI_BOUNCE) return color + bounced_light(s, v, spec, rot, own);
#endif
    return color + emitter_direct(s, v, rot) + ibl_diffuse(s.ns, spec, s.base, s.metallic);
}
#endif
