#version 450
#extension GL_GOOGLE_include_directive : require
// G-buffer vertex stage: world-space vertices in, clip space out.
#include "common.glsl"
FRAME_BLOCK

layout(location = 0) in vec3 in_position;
layout(location = 1) in vec3 in_normal;
layout(location = 2) in vec2 in_uv;

layout(location = 0) out vec3 v_position;
layout(location = 1) out vec3 v_normal;
layout(location = 2) out vec2 v_uv;

void main() {
    v_position = in_position;
    v_normal = in_normal;
    v_uv = in_uv;
    gl_Position = frame.view_proj * vec4(in_position, 1.0);
}
