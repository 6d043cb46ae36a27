"""A thin layer over the `vulkan` cffi module: context, resources, descriptors, pipelines, timestamps."""
from .context import Context, choose_device, describe_devices
from .pipelines import (ALL, CIS, SB, SI, STB, UB, UTB, ComputePipeline, DescriptorSet, GraphicsPipeline,
                        Timestamps)
from .resources import Buffer, BufferView, Image, Sampler, image_barrier, memory_barrier, upload_buffer, upload_texture

__all__ = [
    "Context", "choose_device", "describe_devices", "ALL", "CIS", "SB", "SI", "STB", "UB", "UTB", "ComputePipeline",
    "DescriptorSet", "GraphicsPipeline", "Timestamps", "Buffer", "BufferView", "Image", "Sampler", "image_barrier",
    "memory_barrier", "upload_buffer", "upload_texture",
]
