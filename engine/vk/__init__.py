"""The only package that calls Vulkan (through the `vulkan` cffi module): context and device capabilities,
resources, descriptors and pipelines (laid out from SPIR-V reflection), command recording with derived barriers,
timestamps, swapchain."""

from ..errors import VulkanError

try:  # the `vulkan` module opens the Vulkan loader when it is imported: say what to install if there is none
    import vulkan  # noqa: F401
except OSError:
    raise VulkanError(
        "the Vulkan loader (libvulkan.so.1) is not installed: install it and a driver, e.g. "
        "apt-get install libvulkan1 mesa-vulkan-drivers"
    ) from None

from .context import Context, choose_device, describe_devices
from .pipelines import ALL, CIS, SB, SI, STB, UB, UTB, ComputePipeline, DescriptorSet, GraphicsPipeline, Timestamps
from .recorder import Recorder
from .reflect import Interface, reflect
from .resources import (
    Buffer,
    BufferView,
    Image,
    Sampler,
    image_barrier,
    memory_barrier,
    update_buffer,
    upload_buffer,
    upload_buffers,
    upload_texture_array,
)

__all__ = [
    "Context",
    "choose_device",
    "describe_devices",
    "ALL",
    "CIS",
    "SB",
    "SI",
    "STB",
    "UB",
    "UTB",
    "ComputePipeline",
    "DescriptorSet",
    "GraphicsPipeline",
    "Timestamps",
    "Recorder",
    "Interface",
    "reflect",
    "Buffer",
    "BufferView",
    "Image",
    "Sampler",
    "image_barrier",
    "memory_barrier",
    "update_buffer",
    "upload_buffer",
    "upload_buffers",
    "upload_texture_array",
]
