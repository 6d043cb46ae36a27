#version 450
// Visibility pass, fragment stage: the id of the visible triangle (+1; 0 is the background), nothing else.
// Everything the G-buffer holds is computed from it by gbuffer_resolve.comp, so the raster pass writes 4 bytes
// per pixel (plus depth): on GPUs with few raster units (H100/H200) its cost is the bytes it writes.
layout(push_constant) uniform Push {
    uint first_triangle;   // of this draw, in the material-sorted index buffer
} pc;

layout(location = 0) out uint out_id;

void main() {
    out_id = pc.first_triangle + uint(gl_PrimitiveID) + 1u;
}
