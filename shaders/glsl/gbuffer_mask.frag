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
    uint first_triangle;   // of this draw, in the material-sorted index buffer
    uint material;         // the draw's material
} pc;

layout(set = 0, binding = 1) uniform samplerBuffer materials;   // MATERIAL_TEXELS per material (interface.py)

layout(location = 0) in vec2 v_uv;
layout(location = 0) out uint out_id;

void main() {
    int m = MATERIAL_TEXELS * int(pc.material);
    vec2 dx = dFdx(v_uv), dy = dFdy(v_uv);
    uint handle = floatBitsToUint(texelFetch(materials, m + 1).x);
    float alpha = texelFetch(materials, m).a * sample_texture(handle, v_uv, dx, dy).a;
    if (alpha < texelFetch(materials, m + 3).w) discard;
    out_id = pc.first_triangle + uint(gl_PrimitiveID) + 1u;
}
