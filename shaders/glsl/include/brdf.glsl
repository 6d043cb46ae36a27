// glTF's metallic-roughness BRDF (glTF 2.0 spec, Appendix B): GGX / Trowbridge-Reitz distribution, height-correlated
// Smith visibility, Schlick Fresnel with F0 = mix(0.04, base, metallic), and a Lambert diffuse weighted by
// (1 - F) (1 - metallic). Needs common.glsl.
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

// The BRDF times pi for unit normal n, directions to the viewer v and to the light l (both unit), base colour,
// metallic and perceptual roughness: times the light's pi-normalized radiance and n.l it is the reflected radiance
// (a white Lambert surface facing a light of irradiance 1 reflects 1).
vec3 brdf_pi(vec3 n, vec3 v, vec3 l, vec3 base, float metallic, float roughness) {
    float n_l = dot(n, l);
    if (n_l <= 0.0) return vec3(0.0);
    float n_v = max(dot(n, v), 1e-4);
    vec3 h = normalize(l + v);
    float n_h = max(dot(n, h), 0.0), v_h = max(dot(v, h), 0.0);
    float r = max(roughness, MIN_ROUGHNESS);
    float a2 = r * r * r * r;
    vec3 f0 = mix(vec3(0.04), base, metallic);
    vec3 f = fresnel_schlick(f0, v_h);
    vec3 diffuse = (1.0 - f) * (1.0 - metallic) * base;            // Lambert base / pi, times pi
    vec3 specular = f * (PI * ggx_d(n_h, a2) * smith_vis(n_l, n_v, a2));
    return diffuse + specular;
}

// Directional-albedo approximation of the specular lobe under uniform light (Karis 2014, "Physically based shading
// on mobile"): the scale and bias on F0 of the hemisphere-integrated GGX reflectance.
vec2 env_brdf(float roughness, float n_v) {
    const vec4 c0 = vec4(-1.0, -0.0275, -0.572, 0.022);
    const vec4 c1 = vec4(1.0, 0.0425, 1.04, -0.04);
    vec4 r = roughness * c0 + c1;
    float a004 = min(r.x * r.x, exp2(-9.28 * n_v)) * r.x + r.y;
    return vec2(-1.04, 1.04) * a004 + r.zw;
}

// Reflectance under uniform ambient light: the specular lobe's directional albedo plus the diffuse in what it leaves
// (for a rough dielectric within a few percent of the Lambert albedo).
vec3 ambient_reflectance(vec3 n, vec3 v, vec3 base, float metallic, float roughness) {
    vec2 ab = env_brdf(max(roughness, MIN_ROUGHNESS), max(dot(n, v), 1e-4));
    vec3 f0 = mix(vec3(0.04), base, metallic);
    vec3 spec = f0 * ab.x + ab.y;
    return spec + (1.0 - spec) * (1.0 - metallic) * base;
}

#endif
