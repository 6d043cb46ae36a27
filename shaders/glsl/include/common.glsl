// Shared structs and helpers for every shader of the renderer.
// Keep in step with engine/passes/frame_data.py (the host-side packing).
#ifndef COMMON_GLSL
#define COMMON_GLSL

#define MAX_LIGHTS 16
#define LIGHT_DIRECTIONAL 0
#define LIGHT_POINT 1
#define LIGHT_SPOT 2
#define LIGHT_RECT 3
#define PI 3.14159265358979

struct Light {
    vec4 pos_type;     // xyz: position (unused for directional); w: type (LIGHT_*)
    vec4 dir_radius;   // xyz: direction the light travels (directional) / spot axis / rect normal; w: radius
    vec4 color;        // rgb: colour * intensity; w: spot cos(outer cone)
    vec4 u;            // rect: full edge vector u; directional: w = tan(angular radius); spot: w = cos(inner)
    vec4 v;            // rect: full edge vector v
};

// Per-frame constants (std140 uniform buffer, binding FRAME_BINDING of set 0).
#define FRAME_BLOCK                                                                                  \
    layout(std140, set = 0, binding = 0) uniform FrameData {                                           \
        mat4 view_proj;                                                                                \
        mat4 prev_view_proj;                                                                           \
        vec4 eye;          /* xyz camera position, w: near */                                          \
        vec4 forward;      /* xyz camera forward */                                                    \
        uvec4 size;        /* x: width, y: height, z: frame index, w: light count */                   \
        vec4 params;       /* x: ao radius, y: ao samples, z: shadow samples, w: exposure */           \
        vec4 ambient;      /* rgb: sky/ambient radiance */                                             \
        vec4 params2;      /* x: scene scale, y: accumulation alpha_min, z: pixel footprint per unit  \
                              depth (2 tan(fov/2) / height), w: 1 = temporal history is invalid */     \
        vec4 bounds_min;   /* xyz: scene bounds (debug views), w: unused */                            \
        vec4 bounds_max;   /* xyz: scene bounds, w: unused */                                          \
        Light lights[MAX_LIGHTS];                                                                      \
    } frame;

float luminance(vec3 c) { return dot(c, vec3(0.2126, 0.7152, 0.0722)); }

vec3 srgb_encode(vec3 c) {
    c = clamp(c, 0.0, 1.0);
    return mix(12.92 * c, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(vec3(0.0031308), c));
}

// Narkowicz's ACES filmic fit: maps HDR radiance to [0, 1].
vec3 tonemap_aces(vec3 x) {
    return clamp((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0);
}

#endif
