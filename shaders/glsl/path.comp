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
// (Mitsuba's max_depth). A transmissive material (KHR_materials_transmission) is at each vertex its dielectric
// interface with probability transmission x (1 - metallic), else the opaque BRDF: smooth (roughness below
// MIN_ROUGHNESS: a delta lobe, no light sampling) or rough GGX (dielectric.glsl); its surfaces occlude shadow rays
// (light through them comes by BSDF sampling, as in Mitsuba's path tracer). BLEND surfaces are hit with probability
// alpha by every ray, shadow rays too (alpha.glsl with ALPHA_RANDOM). Random numbers: PCG, seeded per (seed, sample, pixel), so an image depends only on them.
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

// ---- random numbers ------------------------------------------------------------------------------------------
uint rng;
float rnd() {
    rng = rng * 747796405u + 2891336453u;
    uint w = ((rng >> ((rng >> 28u) + 4u)) ^ rng) * 277803737u;
    return float(((w >> 22u) ^ w) >> 8) * (1.0 / 16777216.0);
}
vec2 rnd2() { return vec2(rnd(), rnd()); }

#define ALPHA_BINDING 6
#define TEXTURES_BINDING 7
#define ALPHA_RANDOM rnd   // BLEND surfaces: hit with probability alpha, by every ray (alpha.glsl)
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
layout(set = 0, binding = 10, rgba8) uniform writeonly image2D out_color;
layout(set = 0, binding = 11, rgba16f) uniform writeonly image2D out_hdr;

layout(push_constant) uniform Push { uint mode; uint index; } pc;

#include "scene_surface.glsl"
#include "dielectric.glsl"
#include "light_sample.glsl"
#define EMITTERS_BINDING 9   // per emissive triangle: (triangle bits, cdf, prob)
#include "emitters.glsl"

// ---- the BSDF sampled ----------------------------------------------------------------------------------------
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

// ---- lights hit by BSDF rays -------------------------------------------------------------------------------
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

// ---- a vertex's BSDF: the opaque glTF BRDF or the dielectric interface -----------------------------------------
struct Vertex {
    bool glass;   // the surface acts as its dielectric interface here (dielectric.glsl)
    float eta;    // the index of its far side over its near side's
};

// Draws whether a transmissive surface acts as its dielectric (probability transmission x (1 - metallic)): the
// material is the mix of the two BSDFs by that weight, estimated one at a time.
Vertex vertex_of(inout Surface s) {
    Vertex vx;
    vx.glass = s.transmission > 0.0 && rnd() < s.transmission * (1.0 - s.metallic);
    vx.eta = s.front ? s.ior : 1.0 / s.ior;
    if (vx.glass) s.po = s.p;   // (no terminator shift: light may come from either side)
    return vx;
}

// The normal to move a ray leaving towards l off the surface: the geometric one on l's side.
vec3 side_normal(Surface s, Vertex vx, vec3 l) {
    return vx.glass && dot(l, s.ng) < 0.0 ? -s.ng : s.ng;
}

vec3 vertex_light_eval(Surface s, Vertex vx, Lobes lb, vec3 v, vec3 l) {
    return vx.glass ? rough_dielectric_eval(s.ns, v, l, vx.eta, lb.alpha, s.base) : light_eval(s, v, l);
}

float vertex_pdf(Surface s, Vertex vx, Lobes lb, vec3 v, vec3 l) {
    return vx.glass ? rough_dielectric_pdf(s.ns, v, l, vx.eta, lb.alpha) : bsdf_pdf(s, lb, v, l);
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
        Vertex vx = vertex_of(s);
        bool smooth_glass = vx.glass && s.roughness < MIN_ROUGHNESS;
        // next-event estimation: every analytic light, one emissive triangle (none through a delta lobe)
        for (uint i = 0u; i < frame.light_count && !smooth_glass; ++i) {
            vec3 wi, li;
            float dist, pdf;
            if (!sample_light(frame.lights[i], s.po, rnd2(), wi, dist, li, pdf)) continue;
            vec3 f = vertex_light_eval(s, vx, lb, v, wi);
            if (all(equal(f * li, vec3(0.0))) || !visible(s.po, side_normal(s, vx, wi), wi, dist, frame.scene_scale))
                continue;
            float w = pdf > 0.0 ? power_heuristic(pdf, vertex_pdf(s, vx, lb, v, wi)) : 1.0;
            radiance += throughput * f * li * (pdf > 0.0 ? w / pdf : 1.0);
        }
        if (!env_black && !smooth_glass) {   // the environment
            float pdf;
            vec3 wi = environment_sample(rnd2(), pdf);
            vec3 f = vertex_light_eval(s, vx, lb, v, wi);
            if (pdf > 0.0 && any(greaterThan(f, vec3(0.0)))) {
                vec3 li = environment_radiance(wi);
                if (any(greaterThan(li, vec3(0.0))) &&
                    visible(s.po, side_normal(s, vx, wi), wi, -1.0, frame.scene_scale))
                    radiance += throughput * f * li * (power_heuristic(pdf, vertex_pdf(s, vx, lb, v, wi)) / pdf);
            }
        }
        if (path.info.y > 0u && !smooth_glass) {
            vec3 wi, target, li;
            float pdf;
            float pick = rnd();
            vec2 xi = rnd2();
            if (sample_emitter(s.po, vec3(pick, xi), wi, target, li, pdf)) {
                vec3 f = vertex_light_eval(s, vx, lb, v, wi);
                vec3 o = offset_ray(s.po, side_normal(s, vx, wi));
                if (any(greaterThan(f * li, vec3(0.0))) && !bvh_occluded(o, target - o, 0.0, 1.0))
                    radiance += throughput * f * li * (power_heuristic(pdf, vertex_pdf(s, vx, lb, v, wi)) / pdf);
            }
        }
        // the BSDF sample: the next segment
        vec3 l;
        float pdf = 0.0;   // (0 after a delta lobe: what it hits next counts without MIS)
        if (smooth_glass) {
            vec3 weight;
            l = smooth_dielectric_sample(s.ns, v, vx.eta, s.base, rnd(), weight);
            throughput *= weight;
        } else {
            l = vx.glass ? rough_dielectric_sample(s.ns, v, vx.eta, lb.alpha, rnd2(), rnd()) : sample_bsdf(s, lb, v);
            pdf = vertex_pdf(s, vx, lb, v, l);
            vec3 f = vx.glass ? rough_dielectric_eval(s.ns, v, l, vx.eta, lb.alpha, s.base) : bsdf_eval(s, v, l);
            if (pdf <= 0.0 || all(equal(f, vec3(0.0)))) break;
            throughput *= f / pdf;
        }
        last_pdf = pdf;
        if (depth >= 3u) {   // Russian roulette
            float q = min(max(throughput.r, max(throughput.g, throughput.b)), 0.95);
            if (rnd() >= q) break;
            throughput /= q;
        }
        o = offset_ray(s.p, side_normal(s, vx, l));
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
