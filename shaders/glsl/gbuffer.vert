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

layout(location = 0) in vec3 in_position;
layout(location = 0) flat out uint out_prefix;

void main() {
    Instance inst = instances[visible[gl_InstanceIndex]];
    out_prefix = inst.ids.x;
    gl_Position = frame.view_proj * (inst.model * vec4(in_position, 1.0));
}
