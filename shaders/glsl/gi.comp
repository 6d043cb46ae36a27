#version 450
#extension GL_GOOGLE_include_directive : require
// Diffuse global illumination from the G-buffer at half resolution: per 2x2 cell one cosine-weighted ray about the
// normal of the cell's pixel whose turn it is this frame (gi_cells.glsl), traced on the scene's BVH, and one
// emissive triangle sampled with a shadow ray (emitters.glsl; the two weighted by the power heuristic where the ray
// hits an emitter). A ray that leaves the scene sees the environment; at a hit the surface is shaded as the path
// tracer's vertex (hit_shading.glsl: its emission, each analytic light sampled once with a shadow ray) plus its
// diffuse lobe lit by the irradiance this pass found there in the previous frame, read back where the previous
// frame's G-buffer saw the same surface (gi_lookup.glsl): each frame adds a bounce, so the light converges over
// frames to all bounces between the surfaces the camera sees. Past a hit the previous frame did not see (off screen,
// hidden) the path goes on for BOUNCES diffuse bounces until one can be read back (hit_shading.glsl diffuse_path),
// and past those the ray's own pixel's irradiance stands in (the classic ambient estimate of the bounces beyond:
// close in a room, where what a point sees is lit as it is). A frame without history traces FIRST_RAYS rays of
// FIRST_BOUNCES bounces per cell.
// Analytic lights are never hit: the lighting pass's direct term holds them.
// With cosine-weighted directions the ray's radiance is an estimate of the irradiance over pi, the quantity the
// lighting's diffuse lobe multiplies (as ibl.glsl's environment_irradiance). Metals (no diffuse lobe) and the
// background are not traced (w = 0). Writes rgb, w = 1 where traced, per cell; and the cell's G-buffer (the traced
// pixel's position, view depth and normal; w = 0 where none) for the temporal, filter and upsampling passes.
#include "common.glsl"
FRAME_BLOCK
#include "brdf.glsl"
#include "sampling.glsl"
#include "rayutil.glsl"
#include "terminator.glsl"
#include "filter.glsl"
#define ENV_BINDING 11
#include "environment.glsl"
#include "ibl.glsl"
#define ALPHA_BINDING 6
#define TEXTURES_BINDING 7
#include "alpha.glsl"
#define BVH_SET 1
#define BVH_BINDING 0
#include "bvh.glsl"
#include "shares.glsl"
#include "gi_cells.glsl"

layout(local_size_x = 8, local_size_y = 8) in;
layout(constant_id = 15) const uint WORK_SHARES = 1u;

layout(set = 0, binding = 1, rgba32f) uniform readonly image2D g_position;
layout(set = 0, binding = 2, rgba32f) uniform readonly image2D g_normal;
layout(set = 0, binding = 3, rgba8) uniform readonly image2D g_pbr;   // roughness, metallic, occlusion
layout(std430, set = 0, binding = 4) writeonly buffer Raw { vec4 raw[]; };
layout(set = 0, binding = 5) uniform samplerBuffer materials;     // MATERIAL_TEXELS per material
layout(set = 0, binding = 8) uniform samplerBuffer instances;     // 6 per instance: model rows 0-2, normal rows 3-5
layout(set = 0, binding = 9) uniform samplerBuffer vertices;      // 2 texels per vertex: (p, n.x), (n.yz, uv)
layout(set = 0, binding = 10) uniform usamplerBuffer triangles;   // 2 per flat triangle (engine/gpu/pathscene.py)
layout(std430, set = 0, binding = 16) writeonly buffer Cells { vec4 cells[]; };  // 2 per cell: (p, depth), (n, 1 + turn)

#include "scene_surface.glsl"
#include "light_sample.glsl"
#define EMITTERS_BINDING 17
#include "emitters.glsl"
#define GI_LOOKUP_BINDING 12
#include "gi_lookup.glsl"
#include "hit_shading.glsl"

const uint BOUNCES = 2u;         // the diffuse bounces a ray follows past its hit until it finds light read back
const uint FIRST_RAYS = 8u;      // rays per cell on a frame without history (a first frame, a reset)
const uint FIRST_BOUNCES = 3u;   // and their bounces (no light to read back anywhere)

// The emissive triangles' light at the traced pixel (p, normal n) over pi, as the cosine-weighted ray's radiance
// estimates it: one emitter sampled with a shadow ray, weighted against the cosine ray's chance of hitting the same
// point (the power heuristic; the cosine ray's emission hit takes the other weight).
vec3 pixel_emitters(vec3 p, vec3 n, vec2 rot) {
    if (emitter_count() == 0u) return vec3(0.0);
    vec3 wi, target, li;
    float pdf;
    if (!sample_emitter(p, emitter_xi(frame.frame_index, rot), wi, target, li, pdf) || pdf <= 0.0) return vec3(0.0);
    float c = dot(n, wi);
    if (c <= 0.0 || all(equal(li, vec3(0.0)))) return vec3(0.0);
    vec3 o = offset_ray(p, n);
    if (bvh_occluded(o, target - o, 0.0, 1.0)) return vec3(0.0);
    return li * (c / (PI * pdf)) * power_heuristic(pdf, c / PI);
}

void main() {
    ivec2 cell = ivec2(share_invocation(WORK_SHARES, gl_WorkGroupSize).xy);
    uint w = frame.width, h = frame.height;
    uvec2 nc = gi_cells(w, h);
    if (cell.x >= int(nc.x) || cell.y >= int(nc.y)) return;
    uint ci = uint(cell.y) * nc.x + uint(cell.x);
    ivec2 px = ivec2(-1);
    vec4 nrm = vec4(0.0);
    uint turn = 0u;
    for (uint k = 0u; k < GI_TURNS && px.x < 0; ++k) {
        ivec2 q = gi_turn(cell, frame.frame_index, k, w, h);
        vec4 qn = imageLoad(g_normal, q);
        if (qn.w > 0.0 && imageLoad(g_pbr, q).y < 1.0) {
            px = q;
            nrm = qn;
            turn = k;
        }
    }
    if (px.x < 0) {
        raw[ci] = vec4(0.0);
        cells[2u * ci] = vec4(0.0);
        cells[2u * ci + 1u] = vec4(0.0);
        return;
    }
    uint pixel = uint(px.y) * w + uint(px.x);
    vec4 pos = imageLoad(g_position, px);
    cells[2u * ci] = pos;
    cells[2u * ci + 1u] = vec4(nrm.xyz, float(turn + 1u));
    vec3 n = nrm.xyz, p = pos.xyz;
    vec3 v = normalize(frame.eye - p);
    if (dot(n, v) <= 0.0) n = normalize(n - v * (dot(n, v) - 1e-3));   // seen from behind: bent towards the eye
    // one ray, FIRST_RAYS on a frame without history
    uint rays = frame.history_reset > 0.5 ? FIRST_RAYS : 1u;
    vec3 radiance = vec3(0.0);
    for (uint k = 0u; k < rays; ++k) {
        uint stream = 0x68e31da4u + 0x9e3779b9u * k;
        // the 16 cells of a 4x4 tile take consecutive points of one sequence: stratified over the tile
        uvec2 tc = uvec2(cell) & 3u;
        uint slot = (tc.y << 2u) | tc.x;
        vec3 d = cosine_hemisphere(n, r2(frame.frame_index * 16u + slot, pixel_rotation(uvec2(cell) >> 2u, stream)));
        vec2 rot = pixel_rotation(uvec2(px), stream ^ 0x1b873593u);
        vec4 own = frame.history_reset > 0.5 ? vec4(0.0) : gi_prev[pixel];
        uint seed = pcg_hash(pixel ^ stream) + frame.frame_index;
        uint bounces = frame.history_reset > 0.5 ? FIRST_BOUNCES : BOUNCES;
        radiance += diffuse_path(offset_ray(p, n), d, n, own, rot, seed, bounces);
        radiance += pixel_emitters(p, n, pixel_rotation(uvec2(px), stream ^ 0x85ebca6bu));
    }
    radiance /= float(rays);
    if (any(isnan(radiance)) || any(isinf(radiance))) radiance = vec3(0.0);
    raw[ci] = vec4(radiance, 1.0);
}
