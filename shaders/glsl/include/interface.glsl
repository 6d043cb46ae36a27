// Generated from engine/passes/interface.py by tools/compile_shaders.py: do not edit.
#ifndef INTERFACE_GLSL
#define INTERFACE_GLSL

#define MAX_LIGHTS 16
#define MAX_TEXTURE_ARRAYS 16
#define TEXTURE_NONE 0xffffffffu
#define MATERIAL_TEXELS 7
#define INSTANCE_TEXELS 16
#define MATERIAL_ALPHA_TESTED 1u
#define MATERIAL_DOUBLE_SIDED 2u
#define MATERIAL_BLEND 4u
#define MATERIAL_TRANSMISSIVE 8u
#define MAX_HISTORY 255.0
#define LIGHT_DIRECTIONAL 0
#define LIGHT_POINT 1
#define LIGHT_SPOT 2
#define LIGHT_RECT 3
#define VIEW_POSITION 1u
#define VIEW_NORMAL 2u
#define VIEW_ALBEDO 3u
#define VIEW_DEPTH 4u
#define VIEW_SHADOW_RAW 5u
#define VIEW_SHADOW 6u
#define VIEW_AO_RAW 7u
#define VIEW_AO 8u
#define VIEW_HISTORY 9u
#define VIEW_TRIANGLE_ID 10u
#define VIEW_OBJECT_ID 11u
#define VIEW_MATERIAL_ID 12u
#define VIEW_MOTION 13u
#define VIEW_ROUGHNESS 14u
#define VIEW_METALLIC 15u
#define VIEW_EMISSIVE 16u
#define VIEW_RADIANCE 17u
#define VIEW_INSTANCE_ID 18u
#define VIEW_TAA_HISTORY 19u
#define VIEW_REFLECTION_RAW 20u
#define VIEW_REFLECTION 21u
#define VIEW_GI_RAW 22u
#define VIEW_GI 23u
#define VIEW_TRANSPARENCY 24u
#define SHADOW_HARD 0u
#define SHADOW_SOFT 1u
#define SHADOW_SEED_DELTA 2u
#define SHADOW_REFERENCE 3u
#define TONEMAP_NEUTRAL 0u
#define TONEMAP_AGX 1u
#define TONEMAP_ACES 2u
#define FILTER_MASKS 1u
#define FILTER_AO 2u
#define FILTER_TEMPORAL 4u
#define FILTER_FIRST 8u

struct Light {
    vec4 pos_type;                  // xyz: position (unused for directional); w: type (LIGHT_*)
    vec4 dir_radius;                // xyz: direction the light travels / spot axis / rect normal; w: radius
    vec4 color;                     // rgb: colour * intensity; w: spot cos(outer cone)
    vec4 u;                         // rect: edge u; directional: w = tan(angular radius); spot: w = cos(inner)
    vec4 v;                         // rect: edge v
};

struct FrameData {
    mat4 view_proj;
    mat4 prev_view_proj;            // the previous frame's (temporal reprojection)
    vec3 eye;
    float near;                     // near plane distance
    vec3 forward;
    uint width;
    uint height;
    uint frame_index;               // frames rendered so far (sample sequences)
    uint light_count;
    float ao_radius;
    float ao_samples;               // AO rays per pixel this frame
    float shadow_samples;           // soft shadows: rays per pixel per light
    float exposure;                 // the factor 2^EV on the radiance before the tone curve
    vec3 ambient;                   // the constant environment's radiance where environment_constant is 1
    float scene_scale;              // the scene's bounding-box diagonal
    float accum_alpha;              // the temporal blend's smallest weight
    float pixel_footprint;          // a pixel's size per unit of view depth
    float history_reset;            // 1: the temporal history is invalid
    float objects_moved;            // 1: an instance moved since the last frame (accumulate.comp clamps the history)
    vec3 bounds_min;                // scene bounds (debug views)
    vec3 bounds_max;
    float environment_constant;     // 1: the environment is the constant `ambient` (the `ambient` setting), not the map
    mat4 inv_view_proj;             // inverse of view_proj (the background's view directions)
    uint tonemap;                   // the tone curve (TONEMAP_*)
    uint auto_exposure;             // 1: exposure.comp scales by the key over the log-average luminance
    float shadow_terminator;        // 1: shadow rays start from the terminator shift (terminator.glsl)
    vec2 jitter;                    // the raster's sample point within each pixel, in pixels from its centre (TAA, spp)
    float taa_alpha;                // taa.comp's smallest weight of the new frame
    float camera_cut;               // 1: the camera jumped since the last frame (taa.comp starts over)
    Light lights[16];
};

// The per-frame constants: set 0, binding 0 of every pass that reads them.
#define FRAME_BLOCK layout(std140, set = 0, binding = 0) uniform Frame { FrameData frame; };

#endif
