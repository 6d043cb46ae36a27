// Split-sum image-based lighting of the environment (environment.glsl) for glTF's metallic-roughness BRDF: the
// specular lobe's directional albedo F0 A + F90 B from the BRDF table (F0 and F90 with KHR_materials_specular's
// factors), the diffuse lobe by SH irradiance, the specular one by GGX-prefiltered radiance along the lobe's dominant
// direction. Needs brdf.glsl and environment.glsl.
#ifndef IBL_GLSL
#define IBL_GLSL

// The specular lobe's directional albedo F0 A + F90 B (what the lobe reflects of a uniform environment of radiance 1);
// spec: KHR_materials_specular's (colour, factor), as brdf.glsl fresnel_gltf takes it (vec4(1): the core material).
vec3 ibl_specular_albedo(vec3 n, vec3 v, vec3 base, float metallic, float roughness, vec4 spec) {
    float r = max(roughness, MIN_ROUGHNESS), n_v = max(dot(n, v), 1e-4);
    vec2 ab = environment_brdf(n_v, r);
    return gltf_f0(base, metallic, spec) * ab.x + gltf_f90(metallic, spec) * ab.y;
}

// The diffuse lobe lit by the environment, given the specular albedo `spec` (the light the lobe leaves over).
vec3 ibl_diffuse(vec3 n, vec3 spec, vec3 base, float metallic) {
    return (1.0 - spec) * (1.0 - metallic) * base * environment_irradiance(n);
}

// The environment's prefiltered radiance along the GGX lobe's dominant direction, which leans from the mirror
// direction towards the normal as the lobe widens (Lagarde and de Rousiers 2014, "Moving Frostbite to PBR", 4.9.3).
vec3 ibl_specular_radiance(vec3 n, vec3 v, float roughness) {
    float r = max(roughness, MIN_ROUGHNESS);
    float a = r * r, smooth_ = 1.0 - a;
    vec3 dominant = normalize(mix(n, reflect(-v, n), smooth_ * (sqrt(smooth_) + a)));
    return environment_specular(dominant, r);
}

#endif
