#version 450
#extension GL_GOOGLE_include_directive : require
// G-buffer fragment stage: world position + linear depth, unit normal facing the viewer, albedo.
#include "common.glsl"
FRAME_BLOCK

#define MAX_TEXTURES 16
struct Material {
    vec4 base_color;   // linear RGBA factor
    ivec4 texture;     // x: texture slot or -1
};
layout(std430, set = 0, binding = 1) readonly buffer Materials { Material materials[]; };
layout(set = 0, binding = 2) uniform sampler2D textures[MAX_TEXTURES];
// One draw per material: the material index is dynamically uniform, so indexing textures[] is legal.
layout(push_constant) uniform Push { uint material; } pc;

layout(location = 0) in vec3 v_position;
layout(location = 1) in vec3 v_normal;
layout(location = 2) in vec2 v_uv;

layout(location = 0) out vec4 out_position;  // xyz world, w: linear view depth (> 0 where covered)
layout(location = 1) out vec4 out_normal;    // xyz unit world normal towards the viewer, w: 1 where covered
layout(location = 2) out vec4 out_albedo;    // rgb linear albedo, a: 1

void main() {
    Material m = materials[pc.material];
    vec4 albedo = m.base_color;
    if (m.texture.x >= 0) {
        albedo *= texture(textures[m.texture.x], v_uv);
    }
    vec3 to_eye = frame.eye.xyz - v_position;
    vec3 n = v_normal;
    float len = length(n);
    // Degenerate interpolated normal: fall back to the facet normal from screen-space derivatives.
    n = len > 1e-6 ? n / len : normalize(cross(dFdx(v_position), dFdy(v_position)));
    if (dot(n, to_eye) < 0.0) n = -n;   // two-sided surfaces: shade the side we see
    out_position = vec4(v_position, dot(v_position - frame.eye.xyz, frame.forward.xyz));
    out_normal = vec4(n, 1.0);
    out_albedo = vec4(albedo.rgb, 1.0);
}
