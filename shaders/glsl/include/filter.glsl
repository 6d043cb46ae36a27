// Shared by the temporal accumulation and the a-trous denoiser (accumulate.comp, denoise.comp).
// Both filter two per-pixel signals in one pass: the light masks (one channel per light, light-major:
// [light][y][x]) and ambient occlusion (one channel). Needs common.glsl and FRAME_BLOCK.
#ifndef FILTER_GLSL
#define FILTER_GLSL

// Push flags (interface.glsl): FILTER_MASKS / FILTER_AO: that signal is filtered this frame; FILTER_TEMPORAL
// (accumulate.comp): blend with the reprojected history; FILTER_FIRST (denoise.comp): the first a-trous iteration.

// A light whose mask is random (needs accumulating / denoising): one with an area or a solid angle.
// A zero-size light gives the same binary mask every frame, which is passed through untouched.
bool light_has_extent(Light l) {
    int type = int(l.pos_type.w);
    if (type == LIGHT_RECT) return true;
    if (type == LIGHT_DIRECTIONAL) return l.u.w > 0.0;
    return l.dir_radius.w > 0.0;
}

// World-space size of one pixel at view depth `depth`.
float pixel_footprint(float depth) {
    return max(depth * frame.pixel_footprint, 1e-6);
}

#endif
