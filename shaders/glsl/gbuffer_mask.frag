#version 450
#extension GL_GOOGLE_include_directive : require
// Visibility pass of alpha-tested materials (MASK; BLEND is cut out at 0.5), fragment stage: the triangle id where
// base alpha (factor x texture alpha) reaches the material's cutoff, nothing where it does not. Drawn after the
// opaque materials with its own pipeline: only these draws lose early depth testing to `discard`.
#include "interface.glsl"
#define TEXTURES_SET 0
#define TEXTURES_BINDING 2
#define TEXTURE_ARRAYS_ID 0
#include "textures.glsl"

layout(push_constant) uniform Push {
    uint first_triangle;   // of this draw within its mesh (a mesh's triangles are sorted by material)
    uint material;         // the draw's material (an instance's override, else the mesh's)
} pc;

layout(set = 0, binding = 1) uniform samplerBuffer materials;   // MATERIAL_TEXELS per material (interface.py)

layout(location = 0) in vec2 v_uv;
layout(location = 1) flat in uint in_prefix;   // the instance's first id - 1 (gl_PrimitiveID restarts per instance)
layout(location = 0) out uint out_id;

void main() {
    int m = MATERIAL_TEXELS * int(pc.material);
    vec2 dx = dFdx(v_uv), dy = dFdy(v_uv);
    uint handle = floatBitsToUint(texelFetch(materials, m + 1).x);
    float alpha = texelFetch(materials, m).a * sample_texture(handle, v_uv, dx, dy).a;
    if (alpha < texelFetch(materials, m + 3).w) discard;
    out_id = in_prefix + pc.first_triangle + uint(gl_PrimitiveID) + 1u;
}
