#version 450
#extension GL_GOOGLE_include_directive : require
// Per-instance frustum culling and level of detail before the visibility raster (engine/passes/cull.py). One
// invocation per instance (draw order): its mesh's object-space box goes to clip space through view_proj * model;
// the instance is dropped when all 8 corners lie beyond one frustum plane (left, right, top, bottom, near; the far
// plane is at infinity), with a small slack so rounding never drops a visible one. Else it picks the coarsest level
// whose object-space error, scaled by the instance and divided by a pixel's size at the box's nearest view depth,
// stays below pc.lod_pixels, counts itself into that level's indirect draw records (one per material range of its
// run, all counted alike) and writes its draw slot into the level's instance list at the place the count gave.
// An instance whose box projects to at most pc.soft_pixels pixels across, wholly in front of the near plane, of a run
// the software raster can draw, goes to the software raster's list instead (engine/passes/soft_raster.py).
#include "common.glsl"
#include "instances.glsl"
FRAME_BLOCK

layout(local_size_x = 64) in;

// Per run of instances drawn together (mesh, material override, mirroring), engine/passes/cull.py `DrawTables`.
struct Group {
    vec4 box_min;   // the mesh's object-space box
    vec4 box_max;
    vec4 error;     // object-space error of levels 1..4
    uvec4 cmd;      // x: first draw record of the run, y: records per level (material ranges), z: the run's first
                    // draw slot, w: levels
    uvec4 soft;     // x: the software raster's facing mode (soft_raster.comp; 0: hardware raster only)
};
layout(std430, set = 0, binding = 1) readonly buffer Instances { Instance instances[]; };
layout(std430, set = 0, binding = 2) readonly buffer Groups { Group groups[]; };
// VkDrawIndexedIndirectCommand records, 5 words each (instanceCount: word 1), counts zeroed before this pass
layout(std430, set = 0, binding = 3) buffer Commands { uint commands[]; };
// draw slots: level l's lists start at (1 + l) * instance_count (list 0 is every instance in order, unculled)
layout(std430, set = 0, binding = 4) writeonly buffer Visible { uint visible[]; };
// The software raster's list: (draw slot, first index, index count of its level, facing mode) per instance, and its
// indirect dispatch (x: the list's length, zeroed before this pass; one workgroup per instance).
layout(std430, set = 0, binding = 5) writeonly buffer SoftList { uvec4 soft_list[]; };
layout(std430, set = 0, binding = 6) buffer SoftArgs { uint soft_args[]; };
layout(push_constant) uniform Push {
    uint instance_count;
    float lod_pixels;    // largest projected error of a level, in pixels (0: always the full mesh)
    float soft_pixels;   // largest screen extent of an instance the software raster draws (0: none)
} pc;

void main() {
    uint k = gl_GlobalInvocationID.x;
    if (k >= pc.instance_count) return;
    Instance inst = instances[k];
    Group g = groups[inst.flat_ids.z];
    if (g.cmd.y == 0u) return;
    mat4 m = frame.view_proj * inst.model;
    vec3 lo = g.box_min.xyz, hi = g.box_max.xyz;
    uint outside = 31u;
    float w_min = 3.0e38;
    vec2 ndc_lo = vec2(3.0e38), ndc_hi = vec2(-3.0e38);   // the box's screen bound (where every corner has w > 0)
    for (int c = 0; c < 8; c++) {
        vec3 p = vec3((c & 1) != 0 ? hi.x : lo.x, (c & 2) != 0 ? hi.y : lo.y, (c & 4) != 0 ? hi.z : lo.z);
        vec4 q = m * vec4(p, 1.0);
        float slack = 1e-4 * abs(q.w) + 1e-6;
        uint bits = (q.x > q.w + slack ? 1u : 0u) | (q.x < -q.w - slack ? 2u : 0u)
                  | (q.y > q.w + slack ? 4u : 0u) | (q.y < -q.w - slack ? 8u : 0u)
                  | (q.w < frame.near - slack ? 16u : 0u);
        outside &= bits;
        w_min = min(w_min, q.w);
        vec2 ndc = q.xy / q.w;
        ndc_lo = min(ndc_lo, ndc);
        ndc_hi = max(ndc_hi, ndc);
    }
    if (outside != 0u) return;

    uint level = 0u;
    if (w_min > frame.near && g.cmd.w > 1u) {
        mat3 a = mat3(inst.model);
        float scale = max(length(a[0]), max(length(a[1]), length(a[2])));
        float pixels_per_unit = scale / (w_min * frame.pixel_footprint);
        for (uint l = 1u; l < g.cmd.w; l++) {
            if (g.error[l - 1u] * pixels_per_unit < pc.lod_pixels) level = l; else break;
        }
    }
    uint first = g.cmd.x + level * g.cmd.y;
    // wholly in front of the near plane (no clipping), with slack for the vertices' own rounding
    if (pc.soft_pixels > 0.0 && g.soft.x != 0u && w_min > 1.01 * frame.near) {
        vec2 across = (ndc_hi - ndc_lo) * 0.5 * vec2(frame.width, frame.height);
        if (max(across.x, across.y) <= pc.soft_pixels) {
            // the level's triangles: its material ranges' records, which lie in a row in the index buffer
            uint last = first + g.cmd.y - 1u;
            uint start = commands[5u * first + 2u];
            uint count = commands[5u * last + 2u] + commands[5u * last] - start;
            uint slot = atomicAdd(soft_args[0], 1u);
            soft_list[slot] = uvec4(k, start, count, g.soft.x);
            return;
        }
    }
    uint at = atomicAdd(commands[5u * first + 1u], 1u);
    for (uint r = 1u; r < g.cmd.y; r++) atomicAdd(commands[5u * (first + r) + 1u], 1u);
    visible[(1u + level) * pc.instance_count + g.cmd.z + at] = k;
}
