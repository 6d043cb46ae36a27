#version 450
// Viewer text overlay: composite a small premultiplied-RGBA text image over the rendered colour.
//
// The result goes into a separate image the size of the overlay rectangle (the viewer blits it over the
// swapchain image after the full-frame blit), so the renderer's colour target stays untouched: screenshots
// read it back without the overlay. Blending happens on the sRGB-encoded values, as UI compositing does.

layout(local_size_x = 8, local_size_y = 8) in;
layout(set = 0, binding = 0, rgba8) uniform readonly image2D src_color;  // renderer's colour (sRGB values)
layout(set = 0, binding = 1, rgba8) uniform writeonly image2D dst;       // the overlay rectangle
layout(std430, set = 0, binding = 2) readonly buffer Text {
    uvec4 header;    // x: row stride and width of the text image (pixels), y: its height; z, w: unused
    uint pixels[];   // RGBA8 premultiplied, row-major, header.y rows of header.x pixels
};
layout(push_constant) uniform Push {
    ivec4 rect;      // xy: unused (the rectangle's origin on screen), zw: rectangle size = dst size
    vec4 scale;      // xy: colour-target pixels per screen pixel (render scale), zw: colour-target size
} pc;

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (p.x >= pc.rect.z || p.y >= pc.rect.w) return;
    ivec2 src = ivec2((vec2(pc.rect.xy + p) + 0.5) * pc.scale.xy);
    src = clamp(src, ivec2(0), ivec2(pc.scale.zw) - 1);
    vec3 c = imageLoad(src_color, src).rgb;
    if (p.x < int(header.x) && p.y < int(header.y)) {
        vec4 o = unpackUnorm4x8(pixels[uint(p.y) * header.x + uint(p.x)]);
        c = o.rgb + c * (1.0 - o.a);
    }
    imageStore(dst, p, vec4(c, 1.0));
}
