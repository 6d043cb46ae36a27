#version 460
// Deliberate GPU faults, for testing recovery (engine/vk/faults.py); never dispatched by rendering.
//   mode 0: every invocation writes through a pointer to unmapped device memory (a GPU driver answers with
//           VK_ERROR_DEVICE_LOST, or its queue stalls);
//   mode 1: every invocation loops forever (a hang; the store that never happens keeps the loop from being removed).
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_buffer_reference_uvec2 : require

layout(local_size_x = 64) in;

layout(buffer_reference, std430, buffer_reference_align = 4) buffer Unmapped { uint words[]; };

layout(push_constant) uniform Push {
    uvec2 address;
    uint mode;
    uint never;  // a value the loop's sequence never takes
} push;

void main() {
    if (push.mode == 0u) {
        Unmapped(push.address).words[gl_GlobalInvocationID.x * 4096u] = 0xDEADBEEFu;
        return;
    }
    // (lavapipe ends any loop after 65,535 iterations: the straight-line steps and the many groups keep it busy for
    // minutes there, far past any GPU timeout a test sets)
    uint x = gl_GlobalInvocationID.x;
    for (;;) {
        x = x * 1664525u + 1013904223u;
        x = x * 1664525u + 1013904223u;
        x = x * 1664525u + 1013904223u;
        x = x * 1664525u + 1013904223u;
        x = x * 1664525u + 1013904223u;
        x = x * 1664525u + 1013904223u;
        x = x * 1664525u + 1013904223u;
        x = x * 1664525u + 1013904223u;
        if (x == push.never && push.mode == 2u) {
            Unmapped(push.address).words[0] = x;
        }
    }
}
