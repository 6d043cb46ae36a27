#version 460
// A deliberate GPU fault, for testing recovery (engine/vk/faults.py): every invocation writes through a pointer to
// unmapped device memory, which a GPU driver answers with VK_ERROR_DEVICE_LOST. Never dispatched by rendering.
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_buffer_reference_uvec2 : require

layout(local_size_x = 64) in;

layout(buffer_reference, std430, buffer_reference_align = 4) buffer Unmapped { uint words[]; };

layout(push_constant) uniform Push { uvec2 address; } push;

void main() {
    Unmapped(push.address).words[gl_GlobalInvocationID.x * 4096u] = 0xDEADBEEFu;
}
