"""What a device is and offers, as the engine's tuning needs it: CPU (lavapipe) or GPU, how many shares of a dispatch
run in parallel, whether it has memory the host cannot map, which texel-buffer formats it supports."""

from __future__ import annotations

import os

import vulkan as vk

from .context import Context


def is_cpu(ctx: Context) -> bool:
    """A CPU device (lavapipe / llvmpipe): the traversal and the filters take their CPU-friendly variants."""
    return ctx.device_info["type"] == "CPU"


def lavapipe_threads() -> int:
    """The worker threads llvmpipe runs compute work on: LP_NUM_THREADS, else one per online CPU (Mesa 22.3's
    default), at most its 16. Only a balance hint (shares.glsl): a wrong count is slower, not wrong."""
    try:
        n = int(os.environ.get("LP_NUM_THREADS", ""))
    except ValueError:
        n = os.cpu_count() or 1
    return min(16, max(1, n))


def work_shares(ctx: Context) -> int:
    """How many fixed shares of a dispatch's workgroups this device runs in parallel (shares.glsl): lavapipe's
    worker threads on a CPU device, else 1 (the identity order)."""
    return lavapipe_threads() if is_cpu(ctx) else 1


def has_dedicated_vram(ctx: Context) -> bool:
    """Is there device-local memory the host cannot map (a discrete GPU)? Then batch rays and results go through
    staging copies, so that kernels read VRAM instead of reading across the bus."""
    mp = ctx.memory_properties
    host = vk.VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT
    return any(
        mp.memoryTypes[i].propertyFlags & vk.VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT
        and not mp.memoryTypes[i].propertyFlags & host
        for i in range(mp.memoryTypeCount)
    )


def rgb32f_texel_buffers(ctx: Context) -> bool:
    """Can RGB32F be read as a uniform texel buffer (optional in Vulkan)?"""
    props = vk.vkGetPhysicalDeviceFormatProperties(ctx.physical, vk.VK_FORMAT_R32G32B32_SFLOAT)
    return bool(props.bufferFeatures & vk.VK_FORMAT_FEATURE_UNIFORM_TEXEL_BUFFER_BIT)


def texture_anisotropy(ctx: Context) -> float:
    """The anisotropic filtering ratio of scene textures: up to 16 where the device has samplerAnisotropy, 1
    (trilinear) on CPU devices: lavapipe's anisotropic filter takes the level of the footprint's minor axis without
    enough samples along the major one, so distant stripes alias (docs/scenes.md)."""
    return 1.0 if is_cpu(ctx) else min(16.0, ctx.max_anisotropy)
