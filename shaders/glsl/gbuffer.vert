#version 450
#extension GL_GOOGLE_include_directive : require
// Visibility pass, vertex stage: world-space positions in, clip space out (nothing else is interpolated).
#include "common.glsl"
FRAME_BLOCK

layout(location = 0) in vec3 in_position;

void main() {
    gl_Position = frame.view_proj * vec4(in_position, 1.0);
}
