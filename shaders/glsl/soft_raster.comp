#version 450
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
#extension GL_EXT_shader_atomic_int64 : require
// Software raster of small instances into the visibility buffer's 64-bit twin (engine/passes/soft_raster.py). One
// workgroup per instance of the culling pass's software list, its threads looping over the level's triangles.
// Vertices go through the vertex shader's math (gbuffer.vert); triangles are set up as Vulkan rasterizes: the
// viewport transform, 8 subpixel bits (positions rounded to 1/256 pixel), the facing of the framebuffer area
// (counter-clockwise front faces), pixel centres at +0.5, the top-left fill rule, and the depth z/w interpolated
// linearly in screen space. Each covered pixel takes atomicMax((depth bits << 32) | visibility id): reversed-Z, so
// the nearest surface wins (positive floats order as their bits). The instance's box spans at most 128 pixels
// (cull.py checks the option), so the integer edge functions of its triangles stay below 2^31.
#include "common.glsl"
#include "instances.glsl"
FRAME_BLOCK

layout(local_size_x = 64) in;

layout(std430, set = 0, binding = 1) readonly buffer Instances { Instance instances[]; };
// (draw slot, first index, index count, facing mode) per instance, written by cull.comp
layout(std430, set = 0, binding = 2) readonly buffer SoftList { uvec4 soft_list[]; };
layout(set = 0, binding = 3) uniform samplerBuffer vertices;    // 2 texels per vertex: (p, n.x), (n.yz, uv)
layout(set = 0, binding = 4) uniform usamplerBuffer indices;
// per pixel (row-major): depth bits << 32 | visibility id, 0 where nothing was drawn (cleared each frame)
layout(std430, set = 0, binding = 5) buffer SoftVisibility { uint64_t soft_visibility[]; };

// facing modes (engine/passes/soft_raster.py FACING)
const uint TWO_SIDED = 1u, CULL_BACK = 2u, CULL_FRONT = 3u;
const int SUBPIXELS = 256;

// Edge function of a -> b at p (> 0 inside a triangle of positive area), in subpixels squared.
int edge(ivec2 a, ivec2 b, ivec2 p) { return (b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x); }

// Top-left rule (framebuffer y down, positive area): a top edge runs left to right, a left edge upwards.
bool top_left(ivec2 a, ivec2 b) { return b.y < a.y || (b.y == a.y && b.x > a.x); }

void main() {
    uvec4 item = soft_list[gl_WorkGroupID.x];
    Instance inst = instances[item.x];
    uint id_base = inst.ids.x - inst.ids.y + 1u;   // id = prefix + triangle within the mesh's levels + 1
    ivec2 size = ivec2(frame.width, frame.height);
    vec2 half_size = 0.5 * vec2(size);
    uint first = item.y / 3u, count = item.z / 3u;
    for (uint j = gl_LocalInvocationID.x; j < count; j += gl_WorkGroupSize.x) {
        uint t = first + j;
        ivec2 p[3];
        float z[3];
        for (int c = 0; c < 3; c++) {
            int v = int(texelFetch(indices, int(3u * t) + c).x);
            vec4 q = frame.view_proj * (inst.model * vec4(texelFetch(vertices, 2 * v).xyz, 1.0));
            vec3 ndc = q.xyz / q.w;
            ndc.xy -= frame.jitter / half_size;   // the sample point at frame.jitter pixels (as gbuffer.vert)
            p[c] = ivec2(round((ndc.xy * half_size + half_size) * float(SUBPIXELS)));
            z[c] = ndc.z;
        }
        int area = edge(p[0], p[1], p[2]);   // Vulkan's framebuffer area is -area / 2: > 0 is counter-clockwise
        if (area == 0 || (item.w == CULL_BACK && area > 0) || (item.w == CULL_FRONT && area < 0)) continue;
        if (area < 0) {   // wind it the other way: the edge functions are then positive inside
            ivec2 tp = p[1]; p[1] = p[2]; p[2] = tp;
            float tz = z[1]; z[1] = z[2]; z[2] = tz;
            area = -area;
        }
        // the pixels whose centres lie in the triangle's box, within the image
        ivec2 lo = min(p[0], min(p[1], p[2])), hi = max(p[0], max(p[1], p[2]));
        ivec2 from = max((lo - SUBPIXELS / 2 + SUBPIXELS - 1) >> 8, ivec2(0));
        ivec2 to = min((hi - SUBPIXELS / 2) >> 8, size - 1);
        // a pixel on an edge that is not top or left is outside: that edge's function must exceed 0 there
        ivec3 bias = ivec3(top_left(p[1], p[2]) ? 0 : 1, top_left(p[2], p[0]) ? 0 : 1, top_left(p[0], p[1]) ? 0 : 1);
        float inv_area = 1.0 / float(area);
        uint id = id_base + t;
        for (int y = from.y; y <= to.y; y++) {
            for (int x = from.x; x <= to.x; x++) {
                ivec2 c = ivec2(x, y) * SUBPIXELS + SUBPIXELS / 2;
                ivec3 e = ivec3(edge(p[1], p[2], c), edge(p[2], p[0], c), edge(p[0], p[1], c));
                if (any(lessThan(e, bias))) continue;
                vec3 b = vec3(e) * inv_area;
                float depth = b.x * z[0] + b.y * z[1] + b.z * z[2];
                uint64_t packed = (uint64_t(floatBitsToUint(depth)) << 32) | uint64_t(id);
                atomicMax(soft_visibility[y * size.x + x], packed);
            }
        }
    }
}
