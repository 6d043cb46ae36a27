"""Putting a rendered colour image on a swapchain image: the window surface, the present command buffer (an
optional compute pass drawing a composite image, then blits), its submit, and reading the colour image back.

The colour image is expected in GENERAL layout (the renderer leaves its targets there) and is only read.
"""

from __future__ import annotations

import numpy as np
import vulkan as vk

from ..errors import VulkanError
from .context import Context
from .resources import TRANSFER_DST, Buffer, Image, image_barrier, memory_barrier

#: The device extension a Context needs for a Swapchain.
SWAPCHAIN_EXTENSION = vk.VK_KHR_SWAPCHAIN_EXTENSION_NAME
#: Descriptor-set stages of a pass that only compute shaders use.
COMPUTE_STAGES = vk.VK_SHADER_STAGE_COMPUTE_BIT

_T = vk.VK_PIPELINE_STAGE_TRANSFER_BIT
_C = vk.VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT
_DST = vk.VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL
_SRC = vk.VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL
_WRITE = vk.VK_ACCESS_TRANSFER_WRITE_BIT
_SUB = vk.VkImageSubresourceLayers(vk.VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1)
_RANGE = vk.VkImageSubresourceRange(vk.VK_IMAGE_ASPECT_COLOR_BIT, 0, 1, 0, 1)


def surface_factory(create_surface):
    """A `Context(surface_factory=...)` from a window library's `create_surface(instance, out) -> VkResult`, which
    writes the new VkSurfaceKHR into `out` (e.g. `glfw.create_window_surface(instance, window, None, out)`)."""

    def factory(instance):
        out = vk.ffi.new("VkSurfaceKHR*")
        res = create_surface(instance, out)
        if res != vk.VK_SUCCESS:
            raise VulkanError(f"could not create a window surface (VkResult {res})")
        return out[0]

    return factory


def composite_image(ctx: Context, width: int, height: int, name: str = "overlay") -> Image:
    """An RGBA8 image that a compute pass writes and a blit reads."""
    return Image(
        ctx,
        width,
        height,
        vk.VK_FORMAT_R8G8B8A8_UNORM,
        vk.VK_IMAGE_USAGE_STORAGE_BIT | vk.VK_IMAGE_USAGE_TRANSFER_SRC_BIT,
        name=name,
    )


def _swap_barrier(cmd, image, old, new, src_stage, dst_stage, src_access, dst_access):
    """image_barrier for a swapchain VkImage handle (no Image object around it)."""
    b = vk.VkImageMemoryBarrier(
        srcAccessMask=src_access,
        dstAccessMask=dst_access,
        oldLayout=old,
        newLayout=new,
        srcQueueFamilyIndex=vk.VK_QUEUE_FAMILY_IGNORED,
        dstQueueFamilyIndex=vk.VK_QUEUE_FAMILY_IGNORED,
        image=image,
        subresourceRange=_RANGE,
    )
    vk.vkCmdPipelineBarrier(cmd, src_stage, dst_stage, 0, 0, None, 0, None, 1, [b])


def _blit(cmd, src, src_layout, src_size, dst, dst_size, linear):
    region = vk.VkImageBlit(
        srcSubresource=_SUB,
        srcOffsets=[vk.VkOffset3D(0, 0, 0), vk.VkOffset3D(*src_size, 1)],
        dstSubresource=_SUB,
        dstOffsets=[vk.VkOffset3D(0, 0, 0), vk.VkOffset3D(*dst_size, 1)],
    )
    vk.vkCmdBlitImage(
        cmd, src, src_layout, dst, _DST, 1, [region], vk.VK_FILTER_LINEAR if linear else vk.VK_FILTER_NEAREST
    )


def record_present(
    cmd, swap_image, extent, color: Image, composite: Image | None = None, rect=(0, 0), draw_composite=None
) -> None:
    """(Re)record `cmd` to put `color` on swapchain image `swap_image` (of size `extent`) and leave it ready to
    present: the colour is blitted over the whole image (scaled where the sizes differ). With a non-empty `rect`
    (w, h), `draw_composite(cmd)` first records compute work that writes `composite`, whose top-left `rect` is then
    blitted over the image's top-left corner."""
    sw, sh = extent
    rw, rh = rect
    vk.vkResetCommandBuffer(cmd, 0)
    vk.vkBeginCommandBuffer(cmd, vk.VkCommandBufferBeginInfo())
    if rw and rh:
        image_barrier(
            cmd,
            composite,
            vk.VK_IMAGE_LAYOUT_UNDEFINED,
            vk.VK_IMAGE_LAYOUT_GENERAL,
            _T,
            _C,
            0,
            vk.VK_ACCESS_SHADER_WRITE_BIT,
        )
        draw_composite(cmd)
        image_barrier(
            cmd,
            composite,
            vk.VK_IMAGE_LAYOUT_GENERAL,
            _SRC,
            _C,
            _T,
            vk.VK_ACCESS_SHADER_WRITE_BIT,
            vk.VK_ACCESS_TRANSFER_READ_BIT,
        )
    _swap_barrier(cmd, swap_image, vk.VK_IMAGE_LAYOUT_UNDEFINED, _DST, _T, _T, 0, _WRITE)
    same = (color.width, color.height) == (sw, sh)
    _blit(
        cmd,
        color.handle,
        vk.VK_IMAGE_LAYOUT_GENERAL,
        (color.width, color.height),
        swap_image,
        (sw, sh),
        linear=not same,
    )
    if rw and rh:
        _swap_barrier(cmd, swap_image, _DST, _DST, _T, _T, _WRITE, _WRITE)
        _blit(cmd, composite.handle, _SRC, (rw, rh), swap_image, (rw, rh), linear=False)
    _swap_barrier(
        cmd,
        swap_image,
        _DST,
        vk.VK_IMAGE_LAYOUT_PRESENT_SRC_KHR,
        _T,
        vk.VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT,
        _WRITE,
        0,
    )
    vk.vkEndCommandBuffer(cmd)


def submit_present(ctx: Context, cmd, image_available, render_done, present_ready, fence) -> None:
    """Submit a command buffer recorded by record_present: its blits wait for the acquired image and for the
    render, its compute pass for the render; signals `present_ready` and `fence`."""
    ctx.submit(
        cmd,
        wait=False,
        wait_semaphores=[image_available, render_done],
        wait_stages=[_T, _C | _T],
        signal_semaphores=[present_ready],
        fence=fence,
    )


def read_rgba8(ctx: Context, image: Image, name: str = "readback") -> np.ndarray:
    """An RGBA8 image in GENERAL layout as an (h, w, 4) uint8 array (runs a one-shot copy and waits for it)."""
    w, h = image.width, image.height
    buf = Buffer(ctx, w * h * 4, TRANSFER_DST, host=True, name=name)
    try:
        with ctx.one_shot() as cmd:
            region = vk.VkBufferImageCopy(
                bufferOffset=0,
                bufferRowLength=0,
                bufferImageHeight=0,
                imageSubresource=_SUB,
                imageOffset=vk.VkOffset3D(0, 0, 0),
                imageExtent=vk.VkExtent3D(w, h, 1),
            )
            vk.vkCmdCopyImageToBuffer(cmd, image.handle, vk.VK_IMAGE_LAYOUT_GENERAL, buf.handle, 1, [region])
            memory_barrier(cmd, _T, vk.VK_PIPELINE_STAGE_HOST_BIT, _WRITE, vk.VK_ACCESS_HOST_READ_BIT)
        return buf.view(np.uint8)[: w * h * 4].reshape(h, w, 4).copy()
    finally:
        buf.destroy()
