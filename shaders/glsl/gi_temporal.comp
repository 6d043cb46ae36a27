#version 450
#extension GL_GOOGLE_include_directive : require
// Temporal accumulation of the diffuse GI's half-resolution cells (gi.comp, gi_cells.glsl).
//
// The cell's traced pixel is reprojected by its motion vector into the previous frame's cell grid and the 2x2
// bilinear footprint of cells there is kept where the pixel each traced then saw the same surface (the same
// instance, normal and tangent plane: accumulate.comp's tests, the plane's tolerance a cell wide). No clipping: one
// cosine ray's neighbourhood says little about a mean that a few of its directions bring (a history clipped to it
// goes dark: measured on tests/test_gi.py's room, clipping doubled the error to the path tracer). Blended as
//     value = mix(history, raw, max(1 / (n + 1), ALPHA_MIN_GI))
// Writes rgb and w = the history length n + 1 (0: not traced).
#include "common.glsl"
FRAME_BLOCK
#include "filter.glsl"
#include "gi_cells.glsl"

layout(local_size_x = 8, local_size_y = 8) in;
layout(set = 0, binding = 4, rgba32f) uniform readonly image2D h_position;   // the previous frame's
layout(set = 0, binding = 5, rgba32f) uniform readonly image2D h_normal;
layout(set = 0, binding = 6, rg32f) uniform readonly image2D g_motion;         // now - then, pixels
layout(set = 0, binding = 7, rgba32f) uniform readonly image2D g_prev_position;
layout(set = 0, binding = 8, rgba16f) uniform readonly image2D g_prev_normal;
layout(set = 0, binding = 9, r32ui) uniform readonly uimage2D g_instance;
layout(set = 0, binding = 10, r32ui) uniform readonly uimage2D h_instance;
layout(std430, set = 0, binding = 11) readonly buffer Raw { vec4 raw[]; };
layout(std430, set = 0, binding = 12) readonly buffer Hist { vec4 hist[]; };
layout(std430, set = 0, binding = 13) writeonly buffer Cur { vec4 cur[]; };
layout(std430, set = 0, binding = 14) readonly buffer Cells { vec4 cells[]; };   // gi.comp: (p, depth), (n, 1 + turn)

const float NORMAL_COS = 0.9;
const float PLANE_REL = 0.01;
const float PLANE_CELLS = 2.0;
const float ALPHA_MIN_GI = 0.05;
const float MAX_GI_HISTORY = 64.0;

// The pixel that the previous frame's cell `q` traced (its first covered pixel from that frame's turn on).
ivec2 traced_then(ivec2 q, uint w, uint h) {
    for (uint k = 0u; k < GI_TURNS; ++k) {
        ivec2 p = gi_turn(q, frame.frame_index + 3u, k, w, h);
        if (imageLoad(h_normal, p).w > 0.0) return p;
    }
    return ivec2(-1);
}

void main() {
    ivec2 cell = ivec2(gl_GlobalInvocationID.xy);
    uint w = frame.width, h = frame.height;
    uvec2 nc = gi_cells(w, h);
    if (cell.x >= int(nc.x) || cell.y >= int(nc.y)) return;
    uint ci = uint(cell.y) * nc.x + uint(cell.x);
    vec4 now = raw[ci];
    if (now.w <= 0.0) {
        cur[ci] = vec4(0.0);
        return;
    }
    ivec2 px = gi_turn(cell, frame.frame_index, uint(cells[2u * ci + 1u].w) - 1u, w, h);
    float wsum = 0.0, hlen = 0.0;
    vec3 hval = vec3(0.0);
    if (frame.history_reset < 0.5) {
        vec3 then = imageLoad(g_prev_position, px).xyz;
        vec3 then_n = imageLoad(g_prev_normal, px).xyz;
        uint inst = imageLoad(g_instance, px).x;
        vec4 clip = frame.prev_view_proj * vec4(then, 1.0);
        if (clip.w > 0.0) {
            // in cells (a cell's centre: its block's)
            vec2 pp = (vec2(px) - imageLoad(g_motion, px).xy - 0.5 * float(GI_CELL - 1u)) / float(GI_CELL);
            ivec2 base = ivec2(floor(pp));
            vec2 f = pp - vec2(base);
            float tol = PLANE_REL * clip.w + PLANE_CELLS * float(GI_CELL) * pixel_footprint(clip.w);
            for (int t = 0; t < 4; ++t) {
                ivec2 q = base + ivec2(t & 1, t >> 1);
                if (q.x < 0 || q.y < 0 || q.x >= int(nc.x) || q.y >= int(nc.y)) continue;
                float bw = ((t & 1) != 0 ? f.x : 1.0 - f.x) * ((t >> 1) != 0 ? f.y : 1.0 - f.y);
                if (bw <= 0.0) continue;
                vec4 hq = hist[uint(q.y) * nc.x + uint(q.x)];
                if (hq.w <= 0.0) continue;   // not traced there
                ivec2 qp = traced_then(q, w, h);
                if (qp.x < 0 || imageLoad(h_instance, qp).x != inst) continue;
                vec4 qn = imageLoad(h_normal, qp);
                if (dot(qn.xyz, then_n) < NORMAL_COS) continue;
                if (abs(dot(imageLoad(h_position, qp).xyz - then, then_n)) > tol) continue;
                wsum += bw;
                hlen += bw * hq.w;
                hval += bw * hq.rgb;
            }
        }
    }
    float n_prev = 0.0;
    if (wsum > 1e-3) {
        n_prev = floor(hlen / wsum + 0.5);
        hval /= wsum;
    }
    float alpha = n_prev > 0.0 ? max(1.0 / (n_prev + 1.0), ALPHA_MIN_GI) : 1.0;
    cur[ci] = vec4(mix(hval, now.rgb, alpha), min(n_prev + 1.0, MAX_GI_HISTORY));
}
