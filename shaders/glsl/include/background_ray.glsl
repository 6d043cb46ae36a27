// A background pixel's view direction handed from a G-buffer pass to the lighting in g_position.w (which holds the
// depth, 0, on the raster's background): traced cameras (camera_rays.glsl) store their ray's direction there,
// whatever their model; the lighting looks the environment up along it. One float that any store keeps exactly:
// -(1 + 4096 qx + qy), (qx, qy) the direction's octahedral coordinates quantized to 12 bits (about 0.05 degrees);
// -0.5 for a pixel the camera has no ray for (black).
#ifndef BACKGROUND_RAY_GLSL
#define BACKGROUND_RAY_GLSL

const float BACKGROUND_NO_RAY = -0.5;

float encode_background_ray(vec3 d) {
    if (d == vec3(0.0)) return BACKGROUND_NO_RAY;
    d /= abs(d.x) + abs(d.y) + abs(d.z);
    vec2 s = vec2(d.x >= 0.0 ? 1.0 : -1.0, d.y >= 0.0 ? 1.0 : -1.0);
    vec2 o = d.z >= 0.0 ? d.xy : (1.0 - abs(d.yx)) * s;
    uvec2 q = uvec2(clamp(round((o * 0.5 + 0.5) * 4095.0), 0.0, 4095.0));
    return -(1.0 + float(q.x * 4096u + q.y));
}

vec3 decode_background_ray(float w) {
    uint code = uint(-w - 1.0 + 0.5);
    vec2 o = vec2(float(code >> 12), float(code & 4095u)) / 4095.0 * 2.0 - 1.0;
    vec3 d = vec3(o, 1.0 - abs(o.x) - abs(o.y));
    if (d.z < 0.0) d.xy = (1.0 - abs(d.yx)) * vec2(d.x >= 0.0 ? 1.0 : -1.0, d.y >= 0.0 ? 1.0 : -1.0);
    return normalize(d);
}

#endif
