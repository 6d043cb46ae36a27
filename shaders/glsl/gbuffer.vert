#version 450
#extension GL_GOOGLE_include_directive : require
// Visibility pass, vertex stage: object-space positions in, moved by the instance's transform (the draw slot
// visible[gl_InstanceIndex]; gl_InstanceIndex includes the draw's firstInstance), clip space out; the instance's
// first visibility id goes to the fragment.
#include "common.glsl"
#include "instances.glsl"
FRAME_BLOCK
layout(std430, set = 0, binding = 1) readonly buffer Instances { Instance instances[]; };
// gl_InstanceIndex -> draw slot: the unculled list (every instance in order) or a level's list (cull.comp)
layout(std430, set = 0, binding = 2) readonly buffer Visible { uint visible[]; };
// The same through texel views (INSTANCES_TEXEL, CPU devices; instances.glsl): the records as RGBA32F and RGBA32UI,
// the draw slots as R32UI
layout(set = 0, binding = 3) uniform samplerBuffer instance_texels;
layout(set = 0, binding = 4) uniform usamplerBuffer instance_words;
layout(set = 0, binding = 5) uniform usamplerBuffer visible_texels;
layout(constant_id = 1) const bool INSTANCES_TEXEL = false;

layout(location = 0) in vec3 in_position;
layout(location = 0) flat out uint out_prefix;

void main() {
    Instance inst;   // (not a ?: between the two: their struct types differ in SPIR-V)
    if (INSTANCES_TEXEL) {
        inst = instance_from_texels(instance_texels, instance_words, texelFetch(visible_texels, gl_InstanceIndex).x);
    } else {
        inst = instances[visible[gl_InstanceIndex]];
    }
    out_prefix = inst.ids.x;
    gl_Position = frame.view_proj * (inst.model * vec4(in_position, 1.0));
    // the sample point at frame.jitter pixels from the pixel centre: the image moves the other way
    gl_Position.xy -= 2.0 * frame.jitter / vec2(frame.width, frame.height) * gl_Position.w;
}
