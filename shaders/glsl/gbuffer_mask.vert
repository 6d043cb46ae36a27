#version 450
#extension GL_GOOGLE_include_directive : require
// Visibility pass of alpha-tested materials, vertex stage: clip-space position and the UV (for the alpha test).
#include "common.glsl"
FRAME_BLOCK

layout(location = 0) in vec3 in_position;
layout(location = 1) in vec2 in_uv;
layout(location = 0) out vec2 v_uv;

void main() {
    gl_Position = frame.view_proj * vec4(in_position, 1.0);
    v_uv = in_uv;
}
