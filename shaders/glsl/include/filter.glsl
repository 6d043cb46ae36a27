// Shared by the temporal accumulation and the a-trous denoiser (accumulate.comp, denoise.comp).
// Both filter two per-pixel signals in one pass: the light masks (one channel per light, light-major:
// [light][y][x]) and ambient occlusion (one channel). Needs common.glsl and FRAME_BLOCK.
#ifndef FILTER_GLSL
#define FILTER_GLSL

#define FILTER_MASKS 1u      // push flag: the light masks are filtered this frame
#define FILTER_AO 2u         // push flag: AO is filtered this frame
#define FILTER_TEMPORAL 4u   // push flag (accumulate.comp): blend with the reprojected history
#define FILTER_FIRST 8u      // push flag (denoise.comp): the first a-trous iteration (estimates the variance)
#define MAX_HISTORY 255.0    // history lengths are clamped here

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
    return max(depth * frame.params2.z, 1e-6);
}

#endif
