#version 450
#extension GL_GOOGLE_include_directive : require
// Spatial filter of the diffuse GI's accumulated cells (gi_temporal.comp), at their half resolution: iterations of
// an edge-aware a-trous 5x5 kernel with holes of pc.step cells, its taps weighted by the normals' agreement, the
// distance to the centre's tangent plane, a Gaussian of the tap's distance that shrinks as the history grows
// (accumulated frames need less spatial help) and, once LUM_FRAMES are accumulated, the luminances' agreement
// (relative, its tolerance shrinking with the noise: the emitters' contact shadows keep their edges). The cells'
// G-buffer is the one their rays left from (gi.comp). Untraced cells (w = 0) pass through and are never taps.
#include "common.glsl"
FRAME_BLOCK
#include "filter.glsl"
#include "gi_cells.glsl"

layout(local_size_x = 8, local_size_y = 8) in;
layout(std430, set = 0, binding = 1) readonly buffer Cells { vec4 cells[]; };   // gi.comp: (p, depth), (n, 1 + turn)
layout(std430, set = 0, binding = 4) readonly buffer Src { vec4 src[]; };
layout(std430, set = 0, binding = 5) writeonly buffer Dst { vec4 dst[]; };
layout(push_constant) uniform Push { uint step; } pc;

const float KERNEL[3] = float[](0.375, 0.25, 0.0625);
const float RADIUS_PIXELS = 24.0;   // the Gaussian's sigma on a first frame
const float PLANE_CELLS = 1.5;
const float LUM_K = 1.0;        // the luminance tolerance, relative, times 1 / sqrt(history)
const float LUM_FRAMES = 4.0;   // the history from which it applies (before, a single ray's noise is all there is)

void main() {
    ivec2 cell = ivec2(gl_GlobalInvocationID.xy);
    uvec2 nc = gi_cells(frame.width, frame.height);
    if (cell.x >= int(nc.x) || cell.y >= int(nc.y)) return;
    uint ci = uint(cell.y) * nc.x + uint(cell.x);
    vec4 c = src[ci];
    if (c.w <= 0.0) {
        dst[ci] = c;
        return;
    }
    vec4 pos = cells[2u * ci];
    vec3 n = cells[2u * ci + 1u].xyz;
    float sigma = RADIUS_PIXELS / float(GI_CELL) * inversesqrt(c.w);   // in cells
    float tol = PLANE_CELLS * float(GI_CELL * pc.step) * pixel_footprint(pos.w);
    float inv_s2 = 1.0 / (sigma * sigma), inv_tol = 1.0 / max(tol, 1e-6);
    vec3 sum = vec3(0.0);
    float wsum = 0.0;
    int step = int(pc.step);
    for (int dy = -2; dy <= 2; ++dy)
        for (int dx = -2; dx <= 2; ++dx) {
            ivec2 q = cell + ivec2(dx, dy) * step;
            if (q.x < 0 || q.y < 0 || q.x >= int(nc.x) || q.y >= int(nc.y)) continue;
            uint qi = uint(q.y) * nc.x + uint(q.x);
            vec4 s = src[qi];
            if (s.w <= 0.0) continue;
            float dist2 = float(dx * dx + dy * dy) * float(step * step);
            float plane = abs(dot(cells[2u * qi].xyz - pos.xyz, n));
            float c2 = max(dot(n, cells[2u * qi + 1u].xyz), 0.0);
            c2 *= c2;
            c2 *= c2;
            c2 *= c2;
            c2 *= c2;   // the normals' cosine to the 16th power: squared below
            float wk = KERNEL[abs(dx)] * KERNEL[abs(dy)] * c2 * c2;
            wk *= exp(-0.5 * dist2 * inv_s2 - plane * inv_tol);   // the distance's Gaussian times the plane's
            if (c.w >= LUM_FRAMES) {
                float lc = luminance(c.rgb), lq = luminance(s.rgb);
                wk *= exp(-abs(lc - lq) / (LUM_K * max(lc, lq) * inversesqrt(c.w) + 1e-4));
            }
            sum += wk * s.rgb;
            wsum += wk;
        }
    dst[ci] = vec4(wsum > 0.0 ? sum / wsum : c.rgb, c.w);
}
