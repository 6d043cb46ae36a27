// The scene's triangles as the path tracer and the reflection rays see them at a hit: vertices, normals, uvs and
// materials (the PathScene's texel buffers, engine/gpu/pathscene.py), the surface at a BVH hit, and glTF's
// metallic-roughness BSDF (brdf.glsl) evaluated and its GGX lobe sampled by visible normals. The including shader
// declares the samplers `vertices`, `triangles`, `materials` and `instances` first; needs common.glsl (the frame
// block: shadow_terminator), brdf.glsl, sampling.glsl, terminator.glsl, alpha.glsl (textures) and bvh.glsl (BvhHit).
#ifndef SCENE_SURFACE_GLSL
#define SCENE_SURFACE_GLSL

// ---- the scene's triangles ------------------------------------------------------------------------------------
struct Tri { vec3 p0, p1, p2; vec4 a0, a1, a2, b0, b1, b2; uint inst, material, emitter; };

Tri load_tri(uint prim) {
    uvec4 t0 = texelFetch(triangles, 2 * int(prim)), t1 = texelFetch(triangles, 2 * int(prim) + 1);
    Tri t;
    t.inst = t0.w;
    t.material = t1.x;
    t.emitter = t1.y;
    t.a0 = texelFetch(vertices, 2 * int(t0.x));
    t.a1 = texelFetch(vertices, 2 * int(t0.y));
    t.a2 = texelFetch(vertices, 2 * int(t0.z));
    t.b0 = texelFetch(vertices, 2 * int(t0.x) + 1);
    t.b1 = texelFetch(vertices, 2 * int(t0.y) + 1);
    t.b2 = texelFetch(vertices, 2 * int(t0.z) + 1);
    int k = 6 * int(t.inst);
    vec4 r0 = texelFetch(instances, k), r1 = texelFetch(instances, k + 1), r2 = texelFetch(instances, k + 2);
    t.p0 = vec3(dot(r0.xyz, t.a0.xyz) + r0.w, dot(r1.xyz, t.a0.xyz) + r1.w, dot(r2.xyz, t.a0.xyz) + r2.w);
    t.p1 = vec3(dot(r0.xyz, t.a1.xyz) + r0.w, dot(r1.xyz, t.a1.xyz) + r1.w, dot(r2.xyz, t.a1.xyz) + r2.w);
    t.p2 = vec3(dot(r0.xyz, t.a2.xyz) + r0.w, dot(r1.xyz, t.a2.xyz) + r1.w, dot(r2.xyz, t.a2.xyz) + r2.w);
    return t;
}

vec4 texture_at(uint handle, vec2 uv) {
    return handle == TEXTURE_NONE ? vec4(1.0) : sample_texture_lod(handle, uv, 0.0, texture_bit(handle));
}

// Emitted radiance of a triangle's material at barycentrics (u, v) (its front face: the winding's side).
vec3 tri_emission(Tri t, float u, float v) {
    int m = MATERIAL_TEXELS * int(t.material);
    vec3 e = texelFetch(materials, m + 3).rgb;
    uint handle = floatBitsToUint(texelFetch(materials, m + 1).w);
    if (handle != TEXTURE_NONE) {
        vec2 uv = (1.0 - u - v) * t.b0.zw + u * t.b1.zw + v * t.b2.zw;
        e *= texture_at(handle, uv).rgb;
    }
    return e;
}

struct Surface {
    vec3 p, ng, ns;       // point, geometric and shading normals (both on the side the ray came from)
    vec3 po;              // where its shadow rays start (before offset_ray): p, or the terminator shift's point
    vec3 base, emission;  // base colour; emitted radiance towards the ray (0 from the back face)
    float metallic, roughness;
    vec4 spec;            // KHR_materials_specular: colour, factor (brdf.glsl fresnel_gltf)
    float area;           // the triangle's world area (emitters' pdf)
    uint emitter;         // 1 + its emitter record, or 0
    bool front;           // the ray came from the winding's front side (outside a closed mesh)
    float transmission;   // KHR_materials_transmission's part of the dielectric (0 where not transmissive)
    float ior;            // KHR_materials_ior
};

Surface surface_at(BvhHit hit, vec3 d) {
    Tri t = load_tri(uint(hit.prim));
    float u = hit.u, v = hit.v, w = 1.0 - u - v;
    Surface s;
    s.p = w * t.p0 + u * t.p1 + v * t.p2;
    vec3 c = cross(t.p1 - t.p0, t.p2 - t.p0);
    s.area = 0.5 * length(c);
    vec3 ng = normalize(c);
    int k = 6 * int(t.inst);
    vec3 n_obj = w * vec3(t.a0.w, t.b0.xy) + u * vec3(t.a1.w, t.b1.xy) + v * vec3(t.a2.w, t.b2.xy);
    vec3 ns = vec3(dot(texelFetch(instances, k + 3).xyz, n_obj), dot(texelFetch(instances, k + 4).xyz, n_obj),
                   dot(texelFetch(instances, k + 5).xyz, n_obj));
    float len = length(ns);
    ns = len > 1e-6 ? ns / len : ng;
    bool front = dot(ng, d) < 0.0;
    float side = front ? 1.0 : -1.0;   // two-sided surfaces: the side the ray sees
    ng *= side;
    float nside = dot(ns, ng) < 0.0 ? -1.0 : 1.0;
    ns *= nside;
    s.ng = ng;
    s.ns = ns;
    // the shadow rays' origin off the flat triangle towards the smooth surface (Hanika 2021), as the raster's
    s.po = s.p;
    if (frame.shadow_terminator > 0.5) {
        mat3 nrm = transpose(mat3(texelFetch(instances, k + 3).xyz, texelFetch(instances, k + 4).xyz,
                                  texelFetch(instances, k + 5).xyz));
        vec3 m0 = nrm * vec3(t.a0.w, t.b0.xy), m1 = nrm * vec3(t.a1.w, t.b1.xy), m2 = nrm * vec3(t.a2.w, t.b2.xy);
        if (min(dot(m0, m0), min(dot(m1, m1), dot(m2, m2))) > 1e-12) {
            vec3 po = terminator_offset(s.p, vec3(w, u, v), t.p0, t.p1, t.p2, nside * normalize(m0),
                                        nside * normalize(m1), nside * normalize(m2));
            // (a flat-shaded triangle's shift is rounding only: it keeps its point, and light_eval its facet test)
            vec3 shift = po - s.p;
            if (dot(shift, shift) > 1e-10 * s.area) s.po = po;
        }
    }
    vec2 uv = w * t.b0.zw + u * t.b1.zw + v * t.b2.zw;

    int m = MATERIAL_TEXELS * int(t.material);
    uvec4 handles = floatBitsToUint(texelFetch(materials, m + 1));
    vec4 factors = texelFetch(materials, m + 2);   // metallic, roughness, occlusion strength, normal scale
    s.base = texelFetch(materials, m).rgb * texture_at(handles.x, uv).rgb;
    vec4 mr = texture_at(handles.y, uv);
    s.metallic = factors.x * mr.b;
    s.roughness = factors.y * mr.g;
    s.spec = texelFetch(materials, m + 5);
    s.emission = front ? texelFetch(materials, m + 3).rgb * texture_at(handles.w, uv).rgb : vec3(0.0);
    s.emitter = front ? t.emitter : 0u;
    s.front = front;
    vec4 tr = texelFetch(materials, m + 6);   // transmission, ior
    s.transmission = tr.x;
    s.ior = tr.y;
    // the normal map, in the tangent frame the G-buffer resolve uses (T = dP/du orthonormalized, B = +-N x T)
    vec2 d1 = t.b1.zw - t.b0.zw, d2 = t.b2.zw - t.b0.zw;
    float det = d1.x * d2.y - d2.x * d1.y;
    if (handles.z != TEXTURE_NONE && abs(det) > 1e-20) {
        vec3 e1 = t.p1 - t.p0, e2 = t.p2 - t.p0;
        vec3 dp_du = (e1 * d2.y - e2 * d1.y) / det, dp_dv = (e2 * d1.x - e1 * d2.x) / det;
        vec3 n0 = ns * side;   // the front's shading normal: the map's frame is the front's
        vec3 tan_ = dp_du - n0 * dot(n0, dp_du);
        if (dot(tan_, tan_) > 1e-30) {
            tan_ = normalize(tan_);
            vec3 bit = cross(n0, tan_);
            if (dot(bit, dp_dv) > 0.0) bit = -bit;
            vec3 tn = texture_at(handles.z, uv).xyz * 2.0 - 1.0;
            vec3 mapped = tan_ * (tn.x * factors.w) + bit * (tn.y * factors.w) + n0 * tn.z;
            float ml = length(mapped);
            if (ml > 1e-6) s.ns = side * mapped / ml;
        }
    }
    return s;
}

// ---- the BSDF: glTF metallic-roughness (brdf.glsl): its lobes, pdf, value and GGX visible-normal sampling -----
struct Lobes { float p_spec; float alpha; };

// The lobe to sample: GGX with probability p_spec, by the lobes' Fresnel weights, times (1 - alpha) where there is a
// diffuse lobe: the cosine lobe covers a broad GGX one, which drawn instead only adds noise. Pure metals draw GGX.
Lobes lobes(Surface s, vec3 v) {
    float n_v = max(dot(s.ns, v), 1e-4);
    vec3 f = fresnel_gltf(s.base, s.metallic, s.spec, n_v);
    float spec = luminance(f), diff = luminance((1.0 - f) * (1.0 - s.metallic) * s.base);
    Lobes l;   // (no specular lobe: KHR_materials_specular's factor 0 on a dielectric, pure Lambert)
    float r = max(s.roughness, MIN_ROUGHNESS);
    l.alpha = r * r;
    l.p_spec = diff <= 0.0 ? 1.0 : (spec <= 0.0 ? 0.0 : clamp(spec / (spec + diff), 0.1, 0.9) * (1.0 - l.alpha));
    return l;
}

// Solid-angle pdf of sampling direction l: the lobe mixture (GGX visible normals reflected, cosine hemisphere).
float bsdf_pdf(Surface s, Lobes lb, vec3 v, vec3 l) {
    float n_l = dot(s.ns, l);
    if (n_l <= 0.0) return 0.0;
    float n_v = max(dot(s.ns, v), 1e-4);
    vec3 h = normalize(v + l);
    float a2 = lb.alpha * lb.alpha;
    float g1 = 2.0 * n_v / (n_v + sqrt(a2 + (1.0 - a2) * n_v * n_v));
    float spec = ggx_d(max(dot(s.ns, h), 0.0), a2) * g1 / (4.0 * n_v);
    return lb.p_spec * spec + (1.0 - lb.p_spec) * n_l / PI;
}

vec3 bsdf_eval(Surface s, vec3 v, vec3 l) {   // f(v, l) cos(l) (the BRDF times the cosine at l)
    if (dot(s.ng, l) <= 0.0) return vec3(0.0);
    return brdf_pi_spec(s.ns, v, l, s.base, s.metallic, s.roughness, s.spec) * (max(dot(s.ns, l), 0.0) / PI);
}

// f cos for a light sample at l: where the shadow ray starts from the terminator shift's point, past the flat
// triangle's horizon too (the smooth surface the shading normals describe is lit there; the ray from the shifted
// point decides), else as bsdf_eval.
vec3 light_eval(Surface s, vec3 v, vec3 l) {
    if (s.po == s.p) return bsdf_eval(s, v, l);
    return brdf_pi_spec(s.ns, v, l, s.base, s.metallic, s.roughness, s.spec) * (max(dot(s.ns, l), 0.0) / PI);
}

// Heitz 2018, "Sampling the GGX distribution of visible normals": a half vector in the frame (t, b, n).
vec3 sample_vndf(vec3 ve, float alpha, vec2 u) {
    vec3 vh = normalize(vec3(alpha * ve.x, alpha * ve.y, ve.z));
    float lensq = vh.x * vh.x + vh.y * vh.y;
    vec3 t1 = lensq > 0.0 ? vec3(-vh.y, vh.x, 0.0) * inversesqrt(lensq) : vec3(1.0, 0.0, 0.0);
    vec3 t2 = cross(vh, t1);
    float r = sqrt(u.x), phi = 2.0 * PI * u.y;
    float a = r * cos(phi), b = r * sin(phi);
    float sv = 0.5 * (1.0 + vh.z);
    b = (1.0 - sv) * sqrt(max(0.0, 1.0 - a * a)) + sv * b;
    vec3 nh = a * t1 + b * t2 + sqrt(max(0.0, 1.0 - a * a - b * b)) * vh;
    return normalize(vec3(alpha * nh.x, alpha * nh.y, max(0.0, nh.z)));
}

#endif
