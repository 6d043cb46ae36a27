#version 450
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_samplerless_texture_functions : require
// Merge of the software raster into the visibility image (engine/passes/soft_raster.py), before the resolve: per
// pixel the nearer of the hardware raster's surface (its reversed-Z depth attachment: 0 where nothing was drawn)
// and the software raster's (depth bits and visibility id), so the resolve sees one visibility image.
#include "common.glsl"
FRAME_BLOCK

layout(local_size_x = 8, local_size_y = 8) in;

layout(set = 0, binding = 1, r32ui) uniform uimage2D visibility;
layout(set = 0, binding = 2) uniform texture2D depth;
// per pixel: (visibility id, depth bits) of the software raster's 64-bit atomics, (0, 0) where it drew nothing
layout(std430, set = 0, binding = 3) readonly buffer SoftVisibility { uvec2 soft_visibility[]; };

void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    if (px.x >= int(frame.width) || px.y >= int(frame.height)) return;
    uvec2 soft = soft_visibility[px.y * int(frame.width) + px.x];
    if (soft.x != 0u && uintBitsToFloat(soft.y) > texelFetch(depth, px, 0).r) imageStore(visibility, px, uvec4(soft.x));
}
