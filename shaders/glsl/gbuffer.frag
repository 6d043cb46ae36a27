#version 450
// Visibility pass, fragment stage: the id of the visible instance's triangle (+1; 0 is the background), nothing
// else. Everything the G-buffer holds is computed from it by gbuffer_resolve.comp, so the raster pass writes 4 bytes
// per pixel (plus depth): on GPUs with few raster units (H100/H200) its cost is the bytes it writes.
layout(push_constant) uniform Push {
    uint first_triangle;   // of this draw within its mesh (a mesh's triangles are sorted by material)
} pc;

layout(location = 0) flat in uint in_prefix;   // the instance's first id - 1 (gl_PrimitiveID restarts per instance)
layout(location = 0) out uint out_id;

void main() {
    out_id = in_prefix + pc.first_triangle + uint(gl_PrimitiveID) + 1u;
}
