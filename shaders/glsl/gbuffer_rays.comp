#version 450
#extension GL_GOOGLE_include_directive : require
// G-buffer from traced primary rays, for the camera models other than the pinhole (engine/passes/camera_rays.py):
// one dispatch generates each pixel's ray, traces it through the scene's BVH and fills the same G-buffer as the
// raster's resolve (include/gbuffer_fill.glsl with CAMERA_RAYS; the ray side in include/camera_rays.glsl).
#define CAMERA_RAYS
#include "gbuffer_fill.glsl"
