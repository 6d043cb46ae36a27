// A dielectric interface (KHR_materials_transmission with KHR_materials_ior, as a solid's boundary, not thin-walled):
// exact unpolarized Fresnel at relative index eta, smooth (specular reflection or refraction, picked by F) or rough
// (GGX microfacets, Walter et al. 2007 "Microfacet models for refraction through rough surfaces", separable Smith
// G, visible-normal sampling: Mitsuba 3's `dielectric` and `roughdielectric`, whose formulas these follow).
// Radiance is scaled by 1 / eta^2 on refraction (the solid angle's compression). Conventions: n the shading normal
// on the viewer's side, v towards the viewer, eta = index of the far side / index of the viewer's side, tint the
// transmitted colour. Needs common.glsl, brdf.glsl (ggx_d), sampling.glsl (basis) and scene_surface.glsl
// (sample_vndf).
#ifndef DIELECTRIC_GLSL
#define DIELECTRIC_GLSL

// Fresnel reflectance for cos_i > 0 on the near side; cos_t: the refracted ray's cosine (magnitude), 0 under total
// internal reflection (F = 1).
float fresnel_dielectric(float cos_i, float eta, out float cos_t) {
    float inv = 1.0 / eta;
    float cos_t2 = 1.0 - (1.0 - cos_i * cos_i) * inv * inv;
    if (cos_t2 <= 0.0) {
        cos_t = 0.0;
        return 1.0;
    }
    cos_t = sqrt(cos_t2);
    float a_s = (eta * cos_t - cos_i) / (eta * cos_t + cos_i);
    float a_p = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    return 0.5 * (a_s * a_s + a_p * a_p);
}

// v refracted through the interface of normal m (on v's side), cos_i = dot(v, m), cos_t from fresnel_dielectric.
vec3 refract_dir(vec3 v, vec3 m, float cos_i, float cos_t, float eta) {
    float inv = 1.0 / eta;
    return m * (cos_i * inv - cos_t) - v * inv;
}

// Smith's G1 of GGX (alpha^2 = a2) for direction w over macro normal n and microfacet normal m; 0 where w sees m's
// back side.
float smith_g1_ggx(vec3 w, vec3 n, vec3 m, float a2) {
    float c = dot(w, n);
    if (dot(w, m) * c <= 0.0) return 0.0;
    float c2 = c * c;
    return 2.0 / (1.0 + sqrt(1.0 + a2 * max(1.0 - c2, 0.0) / c2));
}

// The smooth interface sampled: the reflected (probability F) or refracted direction and its weight f cos / pdf.
vec3 smooth_dielectric_sample(vec3 n, vec3 v, float eta, vec3 tint, float pick, out vec3 weight) {
    float cos_t, cos_i = max(dot(n, v), 0.0);
    float f = fresnel_dielectric(cos_i, eta, cos_t);
    if (pick < f) {
        weight = vec3(1.0);
        return reflect(-v, n);
    }
    weight = tint / (eta * eta);
    return refract_dir(v, n, cos_i, cos_t, eta);
}

// The half vector of (v, l) on n's side, reflection or refraction as l's side says; false where there is none.
bool dielectric_half(vec3 n, vec3 v, vec3 l, float eta, out vec3 m) {
    float cl = dot(n, l);
    if (dot(n, v) <= 0.0 || cl == 0.0) return false;
    vec3 h = v + l * (cl > 0.0 ? 1.0 : eta);
    if (dot(h, h) <= 1e-20) return false;
    m = normalize(h);
    if (dot(m, n) < 0.0) m = -m;
    return dot(v, m) > 0.0 && dot(l, m) * cl > 0.0;
}

// The rough interface's f cos(l) (alpha: GGX's).
vec3 rough_dielectric_eval(vec3 n, vec3 v, vec3 l, float eta, float alpha, vec3 tint) {
    vec3 m;
    if (!dielectric_half(n, v, l, eta, m)) return vec3(0.0);
    float a2 = alpha * alpha, cv = dot(n, v), vm = dot(v, m), lm = dot(l, m), cos_t;
    float f = fresnel_dielectric(vm, eta, cos_t);
    float dg = ggx_d(dot(n, m), a2) * smith_g1_ggx(v, n, m, a2) * smith_g1_ggx(l, n, m, a2);
    if (dot(n, l) > 0.0) return vec3(f * dg / (4.0 * cv));
    float denom = vm + eta * lm;   // (the radiance scale 1 / eta^2 cancels Walter's eta^2)
    return tint * abs((1.0 - f) * dg * vm * lm / (cv * denom * denom));
}

// The solid-angle pdf of rough_dielectric_sample drawing l.
float rough_dielectric_pdf(vec3 n, vec3 v, vec3 l, float eta, float alpha) {
    vec3 m;
    if (!dielectric_half(n, v, l, eta, m)) return 0.0;
    float a2 = alpha * alpha, cv = dot(n, v), vm = dot(v, m), lm = dot(l, m), cos_t;
    float f = fresnel_dielectric(vm, eta, cos_t);
    float visible = ggx_d(dot(n, m), a2) * smith_g1_ggx(v, n, m, a2) * vm / cv;
    if (dot(n, l) > 0.0) return visible * f / (4.0 * lm);
    float denom = vm + eta * lm;
    return visible * (1.0 - f) * eta * eta * abs(lm) / (denom * denom);
}

// A microfacet normal drawn from GGX's visible normals, then its reflection (probability F) or refraction.
vec3 rough_dielectric_sample(vec3 n, vec3 v, float eta, float alpha, vec2 xi, float pick) {
    vec3 t, b;
    basis(n, t, b);
    vec3 h = sample_vndf(vec3(dot(v, t), dot(v, b), max(dot(v, n), 1e-4)), alpha, xi);
    vec3 m = t * h.x + b * h.y + n * h.z;
    float vm = dot(v, m), cos_t;
    if (vm <= 0.0) return reflect(-v, m);   // (rounding: a direction the pdf gives 0)
    float f = fresnel_dielectric(vm, eta, cos_t);
    return pick < f ? reflect(-v, m) : refract_dir(v, m, vm, cos_t, eta);
}

#endif
