#version 450
#extension GL_GOOGLE_include_directive : require
// tests/test_environment.py: environment.glsl's functions at given points, for comparison with envtables.py.
#include "common.glsl"
FRAME_BLOCK
#define ENV_BINDING 1
#include "environment.glsl"

layout(local_size_x = 64) in;
layout(std430, set = 0, binding = 2) readonly buffer U { vec2 u[]; };
layout(std430, set = 0, binding = 3) writeonly buffer Out { vec4 result[]; };   // 3 per point
layout(push_constant) uniform Push { uint count; } pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.count) return;
    float pdf;
    vec3 d = environment_sample(u[i], pdf);
    result[3 * i] = vec4(d, pdf);
    result[3 * i + 1] = vec4(environment_irradiance(d), environment_pdf(d));
    result[3 * i + 2] = vec4(environment_radiance(d), 0.0);
}
