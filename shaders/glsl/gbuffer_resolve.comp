#version 450
#extension GL_GOOGLE_include_directive : require
// G-buffer resolve: the visibility raster's triangle per pixel to the G-buffer (include/gbuffer_fill.glsl).
#include "gbuffer_fill.glsl"
