#version 450
#extension GL_GOOGLE_include_directive : require
// The diffuse GI's half-resolution cells (gi_filter.comp) to full resolution: a joint bilateral upsampling. Each
// covered non-metal pixel takes the 3x3 cells about its own, weighted by a Gaussian of the distance to the pixel
// each traced from, the normals' agreement and the distance to the pixel's tangent plane, so the irradiance of a
// surface does not leak across a silhouette or a crease; where none agrees, the nearest traced cell. The same
// weights bring this frame's raw rays up to the `raw_full` debug AOV (gi_raw).
// Writes rgb and w = 1 (0: no cell traced about the pixel, or a metal or the background).
#include "common.glsl"
FRAME_BLOCK
#include "filter.glsl"
#include "gi_cells.glsl"

layout(local_size_x = 8, local_size_y = 8) in;
layout(set = 0, binding = 1, rgba32f) uniform readonly image2D g_position;
layout(set = 0, binding = 2, rgba32f) uniform readonly image2D g_normal;
layout(set = 0, binding = 3, rgba8) uniform readonly image2D g_pbr;
layout(std430, set = 0, binding = 4) readonly buffer Cells { vec4 cells[]; };   // gi.comp: (p, depth), (n, 1 + turn)
layout(std430, set = 0, binding = 5) readonly buffer Half { vec4 half_res[]; };  // filtered cells
layout(std430, set = 0, binding = 6) readonly buffer Raw { vec4 raw[]; };        // this frame's rays, per cell
layout(std430, set = 0, binding = 7) writeonly buffer Final { vec4 final_gi[]; };
layout(std430, set = 0, binding = 8) writeonly buffer RawFull { vec4 raw_full[]; };

const float SIGMA_PIXELS = 1.5;
const float PLANE_PIXELS = 2.0;

void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    uint w = frame.width, h = frame.height;
    if (px.x >= int(w) || px.y >= int(h)) return;
    uint pixel = uint(px.y) * w + uint(px.x);
    vec4 nrm = imageLoad(g_normal, px);
    if (nrm.w <= 0.0 || imageLoad(g_pbr, px).y >= 1.0) {
        final_gi[pixel] = vec4(0.0);
        raw_full[pixel] = vec4(0.0);
        return;
    }
    vec4 pos = imageLoad(g_position, px);
    uvec2 nc = gi_cells(w, h);
    ivec2 own = px / int(GI_CELL);
    float tol = PLANE_PIXELS * pixel_footprint(pos.w);
    vec3 sum = vec3(0.0), rsum = vec3(0.0);
    float wsum = 0.0, nearest = 1e30;
    vec3 near_val = vec3(0.0), near_raw = vec3(0.0);
    bool found = false;
    for (int t = 0; t < 9; ++t) {
        if (GI_CELL == 1u && t != 4) continue;   // (full resolution: the pixel's own cell)
        ivec2 q = own + ivec2(t % 3 - 1, t / 3 - 1);
        if (q.x < 0 || q.y < 0 || q.x >= int(nc.x) || q.y >= int(nc.y)) continue;
        uint qi = uint(q.y) * nc.x + uint(q.x);
        vec4 qn = cells[2u * qi + 1u];
        vec4 s = half_res[qi];
        if (qn.w <= 0.0 || s.w <= 0.0) continue;
        vec2 d = vec2(gi_turn(q, frame.frame_index, uint(qn.w) - 1u, w, h) - px);
        float dist2 = dot(d, d);
        float plane = abs(dot(cells[2u * qi].xyz - pos.xyz, nrm.xyz));
        float wk = exp(-0.5 * dist2 / (SIGMA_PIXELS * SIGMA_PIXELS) - plane / tol);   // distance and plane
        float c = max(dot(nrm.xyz, qn.xyz), 0.0);
        c *= c;
        c *= c;
        c *= c;
        c *= c;
        wk *= c * c;   // the normals' cosine to the 32nd power
        vec3 r = raw[qi].rgb;
        sum += wk * s.rgb;
        rsum += wk * r;
        wsum += wk;
        if (dist2 < nearest) {
            nearest = dist2;
            near_val = s.rgb;
            near_raw = r;
            found = true;
        }
    }
    if (wsum > 1e-6) {
        final_gi[pixel] = vec4(sum / wsum, 1.0);
        raw_full[pixel] = vec4(rsum / wsum, 1.0);
    } else {
        final_gi[pixel] = found ? vec4(near_val, 1.0) : vec4(0.0);
        raw_full[pixel] = found ? vec4(near_raw, 1.0) : vec4(0.0);
    }
}
