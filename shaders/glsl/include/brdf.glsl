// glTF's metallic-roughness BRDF (glTF 2.0 spec, Appendix B): GGX / Trowbridge-Reitz distribution, height-correlated
// Smith visibility, Schlick Fresnel with F0 = mix(0.04, base, metallic), and a Lambert diffuse weighted by
// (1 - F) (1 - metallic); KHR_materials_specular's factors scale the dielectric F0 and F90 (brdf_pi_spec). Needs
// common.glsl.
#ifndef BRDF_GLSL
#define BRDF_GLSL

// Smallest perceptual roughness: below it the GGX lobe of a point light is a single pixel's spike and its D term
// overflows half floats (alpha = 0.045^2 ~ 0.002, as Filament clamps).
#define MIN_ROUGHNESS 0.045

// GGX normal distribution D(h) with alpha = roughness^2.
float ggx_d(float n_h, float a2) {
    float d = n_h * n_h * (a2 - 1.0) + 1.0;
    return a2 / (PI * d * d);
}

// Height-correlated Smith masking-shadowing, with the 1 / (4 n.l n.v) of the microfacet BRDF folded in.
float smith_vis(float n_l, float n_v, float a2) {
    float gv = n_l * sqrt(n_v * n_v * (1.0 - a2) + a2);
    float gl = n_v * sqrt(n_l * n_l * (1.0 - a2) + a2);
    return 0.5 / max(gv + gl, 1e-12);
}

vec3 fresnel_schlick(vec3 f0, float v_h) {
    float m = 1.0 - clamp(v_h, 0.0, 1.0);
    float m2 = m * m;
    return f0 + (1.0 - f0) * (m2 * m2 * m);
}

// KHR_materials_specular's Fresnel (its implementation section), spec = (specular colour, specular factor): the
// dielectric F0 = min(0.04 colour, 1) factor and F90 = factor, mixed towards the metal's (base, 1) by metallic.
// spec = vec4(1) is the core material's fresnel_schlick(mix(0.04, base, metallic), v_h), to the bit.
vec3 gltf_f0(vec3 base, float metallic, vec4 spec) {
    return mix(min(0.04 * spec.rgb, vec3(1.0)) * spec.a, base, metallic);
}
float gltf_f90(float metallic, vec4 spec) { return spec.a + (1.0 - spec.a) * metallic; }
vec3 fresnel_gltf(vec3 base, float metallic, vec4 spec, float v_h) {
    vec3 f0 = gltf_f0(base, metallic, spec);
    float f90 = gltf_f90(metallic, spec);
    float m = 1.0 - clamp(v_h, 0.0, 1.0);
    float m2 = m * m;
    return f0 + (f90 - f0) * (m2 * m2 * m);
}

// The BRDF times pi for unit normal n, directions to the viewer v and to the light l (both unit), base colour,
// metallic and perceptual roughness: times the light's pi-normalized radiance and n.l it is the reflected radiance
// (a white Lambert surface facing a light of irradiance 1 reflects 1).
// (brdf_pi_spec: with KHR_materials_specular's spec, as fresnel_gltf takes it)
vec3 brdf_pi_spec(vec3 n, vec3 v, vec3 l, vec3 base, float metallic, float roughness, vec4 spec) {
    float n_l = dot(n, l);
    if (n_l <= 0.0) return vec3(0.0);
    float n_v = max(dot(n, v), 1e-4);
    vec3 h = normalize(l + v);
    float n_h = max(dot(n, h), 0.0), v_h = max(dot(v, h), 0.0);
    float r = max(roughness, MIN_ROUGHNESS);
    float a2 = r * r * r * r;
    vec3 f = fresnel_gltf(base, metallic, spec, v_h);
    vec3 diffuse = (1.0 - f) * (1.0 - metallic) * base;            // Lambert base / pi, times pi
    vec3 specular = f * (PI * ggx_d(n_h, a2) * smith_vis(n_l, n_v, a2));
    return diffuse + specular;
}

vec3 brdf_pi(vec3 n, vec3 v, vec3 l, vec3 base, float metallic, float roughness) {
    return brdf_pi_spec(n, v, l, base, metallic, roughness, vec4(1.0));
}

#endif
