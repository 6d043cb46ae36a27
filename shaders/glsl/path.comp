#version 450
#extension GL_GOOGLE_include_directive : require
// Progressive unidirectional path tracer (a megakernel: one invocation follows one pixel's paths to their end).
//
// pc.mode 0 (trace): sample `path.batch.x + pc.index` of each pixel (none where pc.index >= `path.batch.y`, the
// batch's count), added to the pixel's float32 sum in `accum` (xyz: radiance, w: samples; sample 0 starts the sum
// over). One sample per dispatch: llvmpipe caps a loop at 65535 iterations per invocation, counted over all entries
// of a nested loop (the traversal's), so many samples in one invocation would lose rays. Each sample: a
// camera ray through a point of the pixel drawn from the pixel filter, then per surface vertex next-event
// estimation to every analytic light and to one emissive triangle (picked by power), its shadow rays from the
// terminator shift's point where frame.shadow_terminator is on (terminator.glsl), and a BSDF sample (glTF
// metallic-roughness: GGX drawn from its distribution of visible normals, or Lambert, by a lobe probability),
// combined with the power heuristic; Russian roulette from the fourth vertex; paths of at most `max depth` segments
// (Mitsuba's max_depth). Random numbers: PCG, seeded per (seed, sample, pixel), so an image depends only on them.
// pc.mode 1 (resolve): the mean radiance into the HDR target, times exposure and through the tone curve into the
// colour one (as lighting.comp writes them).
//
// Units: radiance as the raster's lighting sees it. The analytic lights' intensities are pi-normalized
// (engine/scene/lights.py), so a light's physical quantity is pi times its value: directional irradiance, point and
// spot intensity, rect radiance. Emissive materials and the environment (environment.glsl: the scene's map or sky,
// or the `ambient` constant) are radiance as given; the environment is sampled by its own importance sampling and
// by BSDF rays that leave the scene, weighted by MIS.
#include "common.glsl"
FRAME_BLOCK
#include "brdf.glsl"
#include "sampling.glsl"
#include "rayutil.glsl"
#include "terminator.glsl"
#define ENV_BINDING 12
#include "environment.glsl"
#define ALPHA_BINDING 6
#define TEXTURES_BINDING 7
#include "alpha.glsl"
#define BVH_SET 1
#define BVH_BINDING 0
#include "bvh.glsl"
#include "shares.glsl"

layout(local_size_x = 8, local_size_y = 8) in;
layout(constant_id = 15) const uint WORK_SHARES = 1u;

layout(std140, set = 0, binding = 1) uniform PathBlock {
    mat4 inv_view_proj;   // NDC -> world (the camera's)
    vec4 eye;             // xyz: the camera's position
    uvec4 batch;          // x: first sample index, y: samples in this batch, z: max depth, w: filter (0 box, 1 gauss)
    uvec4 info;           // x: seed, y: emissive triangles, z: lights
} path;
layout(std430, set = 0, binding = 2) buffer Accum { vec4 accum[]; };   // [y][x]: radiance sum, samples
layout(set = 0, binding = 3) uniform samplerBuffer vertices;      // 2 texels per vertex: (p, n.x), (n.yz, uv)
layout(set = 0, binding = 4) uniform usamplerBuffer triangles;    // 2 per flat triangle: (i0, i1, i2, instance),
                                                                  // (material, emitter + 1 or 0, 0, 0)
layout(set = 0, binding = 5) uniform samplerBuffer materials;     // MATERIAL_TEXELS per material
layout(set = 0, binding = 8) uniform samplerBuffer instances;     // 6 per instance: model rows 0-2, normal rows 3-5
layout(set = 0, binding = 9) uniform samplerBuffer emitters;      // per emissive triangle: (triangle bits, cdf, prob)
layout(set = 0, binding = 10, rgba8) uniform writeonly image2D out_color;
layout(set = 0, binding = 11, rgba16f) uniform writeonly image2D out_hdr;

layout(push_constant) uniform Push { uint mode; uint index; } pc;

// ---- random numbers ------------------------------------------------------------------------------------------
uint rng;
float rnd() {
    rng = rng * 747796405u + 2891336453u;
    uint w = ((rng >> ((rng >> 28u) + 4u)) ^ rng) * 277803737u;
    return float(((w >> 22u) ^ w) >> 8) * (1.0 / 16777216.0);
}
vec2 rnd2() { return vec2(rnd(), rnd()); }

float power_heuristic(float a, float b) {
    float a2 = a * a, b2 = b * b;
    return a2 + b2 > 0.0 ? a2 / (a2 + b2) : 0.0;
}

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
            if (ml > 1e-6) ns = side * mapped / ml;
        }
    }
    return s;
}

// ---- the BSDF: glTF metallic-roughness (brdf.glsl), sampled ------------------------------------------------------
struct Lobes { float p_spec; float alpha; };

Lobes lobes(Surface s, vec3 v) {
    float n_v = max(dot(s.ns, v), 1e-4);
    vec3 f = fresnel_gltf(s.base, s.metallic, s.spec, n_v);
    float spec = luminance(f), diff = luminance((1.0 - f) * (1.0 - s.metallic) * s.base);
    Lobes l;   // (no specular lobe: KHR_materials_specular's factor 0 on a dielectric, pure Lambert)
    l.p_spec = diff <= 0.0 ? 1.0 : (spec <= 0.0 ? 0.0 : clamp(spec / (spec + diff), 0.1, 0.9));
    float r = max(s.roughness, MIN_ROUGHNESS);
    l.alpha = r * r;
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

vec3 sample_bsdf(Surface s, Lobes lb, vec3 v) {
    vec3 t, b;
    basis(s.ns, t, b);
    float pick = rnd();
    vec2 xi = rnd2();
    if (pick < lb.p_spec) {
        vec3 ve = vec3(dot(v, t), dot(v, b), max(dot(v, s.ns), 1e-4));
        vec3 h = sample_vndf(ve, lb.alpha, xi);
        vec3 hw = t * h.x + b * h.y + s.ns * h.z;
        return reflect(-v, hw);
    }
    return cosine_hemisphere(s.ns, xi);
}

// ---- lights ---------------------------------------------------------------------------------------------------
// A spot light's falloff at cosine `c` to its axis: 1 inside the inner cone, 0 outside the outer one, smoothstep
// between (a hard edge where the cones are one: smoothstep's edges may not be equal).
float spot_falloff(Light l, float c) {
    float outer = l.color.w, inner = l.u.w;
    return inner > outer ? smoothstep(outer, inner, c) : (c >= outer ? 1.0 : 0.0);
}

// A sample of light `l` from p: direction wi, distance to the emitting point (or -1: at infinity), the radiance (for
// delta lights: the irradiance-like quantity that times f cos gives the reflected radiance), its solid-angle pdf
// (0: a delta light, no MIS). False where the light sends nothing towards p.
bool sample_light(Light l, vec3 p, vec2 xi, out vec3 wi, out float dist, out vec3 li, out float pdf) {
    int type = int(l.pos_type.w);
    vec3 power = PI * l.color.rgb;
    if (type == LIGHT_DIRECTIONAL) {
        vec3 axis = -l.dir_radius.xyz;
        float tan_a = l.u.w;
        dist = -1.0;
        if (tan_a > 0.0) {
            float cos_max = inversesqrt(1.0 + tan_a * tan_a);
            wi = sample_cone(axis, cos_max, xi);
            pdf = 1.0 / (2.0 * PI * (1.0 - cos_max));
            li = power / (PI * (1.0 - cos_max * cos_max));   // a disc of uniform radiance: irradiance E at normal
        } else {
            wi = axis;
            pdf = 0.0;
            li = power;
        }
        return true;
    }
    if (type == LIGHT_RECT) {
        vec3 q = l.pos_type.xyz + (xi.x - 0.5) * l.u.xyz + (xi.y - 0.5) * l.v.xyz;
        vec3 to = q - p;
        float d2 = dot(to, to);
        dist = sqrt(d2);
        wi = to / dist;
        float cos_l = dot(-wi, l.dir_radius.xyz);
        if (cos_l <= 0.0) return false;
        pdf = d2 / (length(cross(l.u.xyz, l.v.xyz)) * cos_l);
        li = power;
        return true;
    }
    vec3 c = l.pos_type.xyz;
    vec3 to = c - p;
    float d2 = dot(to, to);
    float r = l.dir_radius.w;
    vec3 axis = to * inversesqrt(d2);
    if (r > 0.0) {
        if (d2 <= r * r) return false;
        float cos_max = sqrt(max(0.0, 1.0 - r * r / d2));
        wi = sample_cone(axis, cos_max, xi);
        pdf = 1.0 / (2.0 * PI * (1.0 - cos_max));
        // the distance to the sphere's near side along wi
        float b = dot(to, wi);
        dist = b - sqrt(max(0.0, b * b - (d2 - r * r)));
        li = power / (PI * r * r);   // a sphere of intensity I has radiance I / (pi r^2)
    } else {
        wi = axis;
        dist = sqrt(d2);
        pdf = 0.0;
        li = power / d2;
    }
    if (type == LIGHT_SPOT) li *= spot_falloff(l, dot(-axis, l.dir_radius.xyz));
    return true;
}

// Light reaching the ray (o, d) from the analytic lights with area before distance t_max (inf: the sky, where a
// sun with a disc is), weighted against the BSDF sample's pdf `bsdf_pdf_` (0: a camera ray, weight 1).
vec3 lights_hit(vec3 o, vec3 d, float t_max, float bsdf_pdf_) {
    vec3 sum = vec3(0.0);
    for (uint i = 0u; i < frame.light_count; ++i) {
        Light l = frame.lights[i];
        int type = int(l.pos_type.w);
        vec3 power = PI * l.color.rgb;
        vec3 li = vec3(0.0);
        float pdf = 0.0;
        if (type == LIGHT_DIRECTIONAL) {
            float tan_a = l.u.w;
            if (tan_a <= 0.0 || !isinf(t_max)) continue;
            float cos_max = inversesqrt(1.0 + tan_a * tan_a);
            if (dot(d, -l.dir_radius.xyz) < cos_max) continue;
            pdf = 1.0 / (2.0 * PI * (1.0 - cos_max));
            li = power / (PI * (1.0 - cos_max * cos_max));
        } else if (type == LIGHT_RECT) {
            vec3 n = l.dir_radius.xyz;
            float dn = dot(d, n);
            if (dn >= 0.0) continue;   // one-sided: seen from the front only
            float t = dot(l.pos_type.xyz - o, n) / dn;
            if (t <= 0.0 || t >= t_max) continue;
            vec3 q = o + t * d - l.pos_type.xyz;
            float uu = dot(q, l.u.xyz) / dot(l.u.xyz, l.u.xyz), vv = dot(q, l.v.xyz) / dot(l.v.xyz, l.v.xyz);
            if (abs(uu) > 0.5 || abs(vv) > 0.5) continue;
            pdf = t * t / (length(cross(l.u.xyz, l.v.xyz)) * -dn);
            li = power;
        } else {
            float r = l.dir_radius.w;
            if (r <= 0.0) continue;
            vec3 to = l.pos_type.xyz - o;
            float d2 = dot(to, to);
            if (d2 <= r * r) continue;
            float b = dot(to, d), disc = b * b - (d2 - r * r);
            if (disc < 0.0) continue;
            float t = b - sqrt(disc);
            if (t <= 0.0 || t >= t_max) continue;
            float cos_max = sqrt(max(0.0, 1.0 - r * r / d2));
            pdf = 1.0 / (2.0 * PI * (1.0 - cos_max));
            li = power / (PI * r * r);
            if (type == LIGHT_SPOT) li *= spot_falloff(l, dot(-to * inversesqrt(d2), l.dir_radius.xyz));
        }
        sum += li * (bsdf_pdf_ > 0.0 ? power_heuristic(bsdf_pdf_, pdf) : 1.0);
    }
    return sum;
}

// One emissive triangle picked by power (the host's CDF), a uniform point on it: its radiance towards p, the
// direction, the point moved off its triangle towards p (the shadow ray's end: a ray that ended on the triangle
// would hit it short of its end where it is seen edge-on), and the solid-angle pdf.
bool sample_emitter(vec3 p, out vec3 wi, out vec3 target, out vec3 li, out float pdf) {
    uint n = path.info.y;
    float x = rnd();
    uint lo = 0u, hi = n - 1u;   // the first record whose cdf > x
    while (lo < hi) {
        uint mid = (lo + hi) >> 1;
        if (texelFetch(emitters, int(mid)).y > x) hi = mid; else lo = mid + 1u;
    }
    vec4 rec = texelFetch(emitters, int(lo));
    Tri t = load_tri(floatBitsToUint(rec.x));
    vec2 xi = rnd2();
    float su = sqrt(xi.x);
    float u = su * (1.0 - xi.y), v = su * xi.y;   // barycentrics of p1, p2
    vec3 q = (1.0 - u - v) * t.p0 + u * t.p1 + v * t.p2;
    vec3 c = cross(t.p1 - t.p0, t.p2 - t.p0);
    float area = 0.5 * length(c);
    vec3 to = q - p;
    float d2 = dot(to, to);
    wi = to * inversesqrt(d2);
    float cos_l = -dot(wi, c) / (2.0 * area);
    if (cos_l <= 0.0 || area <= 0.0) return false;   // its back face (no emission) or degenerate
    target = offset_ray(q, c / (2.0 * area));
    li = tri_emission(t, u, v);
    pdf = rec.z * d2 / (area * cos_l);
    return true;
}

// The solid-angle pdf with which sample_emitter picks the point a BSDF ray hit at distance t.
float emitter_pdf(Surface s, vec3 d, float t) {
    float prob = texelFetch(emitters, int(s.emitter) - 1).z;
    return prob * t * t / (s.area * max(dot(s.ng, -d), 1e-8));
}

bool visible(vec3 p, vec3 ng, vec3 wi, float dist, float scene_scale) {
    vec3 o = offset_ray(p, ng);
    float tmax = dist < 0.0 ? 4.0 * scene_scale : dist * (1.0 - 1e-4);
    return !bvh_occluded(o, wi, 0.0, tmax);
}

// ---- one path ------------------------------------------------------------------------------------------------
vec3 trace_path(vec3 o, vec3 d) {
    vec3 radiance = vec3(0.0), throughput = vec3(1.0);
    float last_pdf = 0.0;   // the BSDF pdf of the last bounce (0: the camera ray)
    uint max_depth = path.batch.z;
    // a constant black environment (`ambient` 0) is not sampled: the same for every invocation, so no lane pays
    bool env_black = env_constant() && all(equal(frame.ambient, vec3(0.0)));
    for (uint depth = 1u;; ++depth) {
        BvhHit hit = bvh_intersect(o, d, 0.0, BVH_INF);
        radiance += throughput * lights_hit(o, d, hit.t, last_pdf);
        if (hit.prim < 0) {
            float w = last_pdf > 0.0 ? power_heuristic(last_pdf, environment_pdf(d)) : 1.0;
            radiance += throughput * environment_radiance(d) * w;
            break;
        }
        Surface s = surface_at(hit, d);
        if (s.emitter != 0u || any(greaterThan(s.emission, vec3(0.0)))) {
            float w = (last_pdf > 0.0 && s.emitter != 0u) ? power_heuristic(last_pdf, emitter_pdf(s, d, hit.t)) : 1.0;
            radiance += throughput * s.emission * w;
        }
        if (depth >= max_depth) break;
        vec3 v = -d;
        if (dot(s.ns, v) <= 0.0) s.ns = s.ng;   // a shading normal facing away from the viewer: the geometric one
        Lobes lb = lobes(s, v);
        // next-event estimation: every analytic light, one emissive triangle
        for (uint i = 0u; i < frame.light_count; ++i) {
            vec3 wi, li;
            float dist, pdf;
            if (!sample_light(frame.lights[i], s.po, rnd2(), wi, dist, li, pdf)) continue;
            vec3 f = light_eval(s, v, wi);
            if (all(equal(f, vec3(0.0))) || !visible(s.po, s.ng, wi, dist, frame.scene_scale)) continue;
            float w = pdf > 0.0 ? power_heuristic(pdf, bsdf_pdf(s, lb, v, wi)) : 1.0;
            radiance += throughput * f * li * (pdf > 0.0 ? w / pdf : 1.0);
        }
        if (!env_black) {   // the environment
            float pdf;
            vec3 wi = environment_sample(rnd2(), pdf);
            vec3 f = light_eval(s, v, wi);
            if (pdf > 0.0 && any(greaterThan(f, vec3(0.0)))) {
                vec3 li = environment_radiance(wi);
                if (any(greaterThan(li, vec3(0.0))) && visible(s.po, s.ng, wi, -1.0, frame.scene_scale))
                    radiance += throughput * f * li * (power_heuristic(pdf, bsdf_pdf(s, lb, v, wi)) / pdf);
            }
        }
        if (path.info.y > 0u) {
            vec3 wi, target, li;
            float pdf;
            if (sample_emitter(s.po, wi, target, li, pdf)) {
                vec3 f = light_eval(s, v, wi);
                vec3 o = offset_ray(s.po, s.ng);
                if (any(greaterThan(f * li, vec3(0.0))) && !bvh_occluded(o, target - o, 0.0, 1.0))
                    radiance += throughput * f * li * (power_heuristic(pdf, bsdf_pdf(s, lb, v, wi)) / pdf);
            }
        }
        // the BSDF sample: the next segment
        vec3 l = sample_bsdf(s, lb, v);
        float pdf = bsdf_pdf(s, lb, v, l);
        vec3 f = bsdf_eval(s, v, l);
        if (pdf <= 0.0 || all(equal(f, vec3(0.0)))) break;
        throughput *= f / pdf;
        last_pdf = pdf;
        if (depth >= 3u) {   // Russian roulette
            float q = min(max(throughput.r, max(throughput.g, throughput.b)), 0.95);
            if (rnd() >= q) break;
            throughput /= q;
        }
        o = offset_ray(s.p, s.ng);
        d = l;
    }
    return radiance;
}

// A point of the pixel (pixel units, from its top-left corner) drawn from the pixel filter.
vec2 filter_sample() {
    vec2 xi = rnd2();
    if (path.batch.w == 1u) {   // Gaussian, standard deviation 0.5 pixel (Box-Muller)
        float r = 0.5 * sqrt(-2.0 * log(max(1.0 - xi.x, 1e-12)));
        return vec2(0.5) + r * vec2(cos(2.0 * PI * xi.y), sin(2.0 * PI * xi.y));
    }
    return xi;   // box
}

void main() {
    ivec2 px = ivec2(share_invocation(WORK_SHARES, gl_WorkGroupSize).xy);
    uint w = frame.width, h = frame.height;
    if (px.x >= int(w) || px.y >= int(h)) return;
    uint pixel = uint(px.y) * w + uint(px.x);
    if (pc.mode == 1u) {
        vec4 a = accum[pixel];
        vec3 color = a.rgb / max(a.w, 1.0);
        imageStore(out_hdr, px, vec4(color, 1.0));
        imageStore(out_color, px, vec4(srgb_encode(tonemap(color * frame.exposure, frame.tonemap)), 1.0));
        return;
    }
    if (pc.index >= path.batch.y) return;
    uint sample_index = path.batch.x + pc.index;
    rng = pcg_hash(pixel + pcg_hash(sample_index + pcg_hash(path.info.x)));
    vec2 at = (vec2(px) + filter_sample()) / vec2(w, h) * 2.0 - 1.0;
    vec4 far = path.inv_view_proj * vec4(at, 0.5, 1.0);
    vec3 d = normalize(far.xyz / far.w - path.eye.xyz);
    vec3 c = trace_path(path.eye.xyz, d);
    if (any(isnan(c)) || any(isinf(c))) c = vec3(0.0);   // (a lost sample counts as black)
    vec4 prev = sample_index == 0u ? vec4(0.0) : accum[pixel];
    accum[pixel] = prev + vec4(c, 1.0);
}
