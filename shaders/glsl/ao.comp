#version 450
#extension GL_GOOGLE_include_directive : require
// Ambient occlusion from the G-buffer: `frame.params.y` cosine-weighted hemisphere rays of length
// `frame.params.x` per pixel; writes the unoccluded fraction (1 = open).
#include "common.glsl"
FRAME_BLOCK
#include "sampling.glsl"
#include "rayutil.glsl"
#define BVH_SET 1
#define BVH_BINDING 0
#include "bvh.glsl"

layout(local_size_x = 8, local_size_y = 8) in;
layout(set = 0, binding = 1, rgba32f) uniform readonly image2D g_position;
layout(set = 0, binding = 2, rgba32f) uniform readonly image2D g_normal;
layout(std430, set = 0, binding = 3) writeonly buffer AO { float ao[]; };

void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    uint w = frame.size.x, h = frame.size.y;
    if (px.x >= int(w) || px.y >= int(h)) return;
    uint pixel = uint(px.y) * w + uint(px.x);
    vec4 nrm = imageLoad(g_normal, px);
    if (nrm.w <= 0.0) {
        ao[pixel] = 1.0;
        return;
    }
    vec3 n = nrm.xyz;
    vec3 o = offset_ray(imageLoad(g_position, px).xyz, n);
    uint k = max(uint(frame.params.y), 1u);
    float radius = frame.params.x;
    vec2 rot = pixel_rotation(uvec2(px), 0x9e3779b9u);
    float open = 0.0;
    for (uint s = 0u; s < k; ++s) {
        vec3 d = cosine_hemisphere(n, r2(frame.size.z * k + s, rot));
        open += bvh_occluded(o, d, 0.0, radius) ? 0.0 : 1.0;
    }
    ao[pixel] = open / float(k);
}
