// The environment seen by rays that leave the scene: radiance arriving from direction `dir` (unit, world space).
// Today a constant: the scene's background / ambient colour (frame.ambient), which the path tracer reaches by BSDF
// sampling only (not light-sampled). Needs common.glsl and FRAME_BLOCK.
#ifndef ENVIRONMENT_GLSL
#define ENVIRONMENT_GLSL

vec3 environment_radiance(vec3 dir) {
    return frame.ambient;
}

#endif
