"""Buffers, images and samplers: device-local ones filled through staging, host-visible ones for readback.

One allocation per resource: scenes have a handful of buffers, so a sub-allocator would buy nothing.
Each resource registers its own destruction with the Context and can also be freed early.
"""
from __future__ import annotations

import numpy as np
import vulkan as vk

from ..errors import VulkanError
from .context import Context

STORAGE = vk.VK_BUFFER_USAGE_STORAGE_BUFFER_BIT
UNIFORM = vk.VK_BUFFER_USAGE_UNIFORM_BUFFER_BIT
UNIFORM_TEXEL = vk.VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT
STORAGE_TEXEL = vk.VK_BUFFER_USAGE_STORAGE_TEXEL_BUFFER_BIT
VERTEX = vk.VK_BUFFER_USAGE_VERTEX_BUFFER_BIT
INDEX = vk.VK_BUFFER_USAGE_INDEX_BUFFER_BIT
TRANSFER_SRC = vk.VK_BUFFER_USAGE_TRANSFER_SRC_BIT
TRANSFER_DST = vk.VK_BUFFER_USAGE_TRANSFER_DST_BIT
HOST = vk.VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | vk.VK_MEMORY_PROPERTY_HOST_COHERENT_BIT
DEVICE = vk.VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT


_OUT_OF_MEMORY = (vk.VkErrorOutOfDeviceMemory, vk.VkErrorOutOfHostMemory)


def allocate(ctx: Context, req, mtype: int, what: str):
    """Device memory for a resource's requirements `req`, or a VulkanError naming `what` and the size (refused before
    the call when it exceeds the memory heap)."""
    mp = ctx.memory_properties
    heap = mp.memoryHeaps[mp.memoryTypes[mtype].heapIndex].size
    size = f"{req.size / 2**20:.1f} MiB"
    if req.size > heap:
        raise VulkanError(f"{what}: {size} is more than this device's memory heap of {heap / 2**20:.0f} MiB "
                          f"({ctx.device_info['name']}); use a smaller size or scene")
    try:
        memory = vk.vkAllocateMemory(ctx.device, vk.VkMemoryAllocateInfo(allocationSize=req.size,
                                                                         memoryTypeIndex=mtype), None)
    except _OUT_OF_MEMORY as exc:
        kind = "device" if isinstance(exc, vk.VkErrorOutOfDeviceMemory) else "host"
        raise VulkanError(f"{what}: out of {kind} memory allocating {size} on {ctx.device_info['name']}") from None
    ctx.allocations += 1
    return memory


def free(ctx: Context, memory):
    vk.vkFreeMemory(ctx.device, memory, None)
    ctx.allocations -= 1


class Buffer:
    """A VkBuffer with its own memory. `host=True` maps it persistently (`.view(dtype)`)."""

    def __init__(self, ctx: Context, size: int, usage: int, host: bool = False, name: str = ""):
        self.ctx, self.size, self.host, self.name = ctx, max(int(size), 4), host, name
        dev = ctx.device
        self.handle = vk.vkCreateBuffer(dev, vk.VkBufferCreateInfo(
            size=self.size, usage=usage, sharingMode=vk.VK_SHARING_MODE_EXCLUSIVE), None)
        req = vk.vkGetBufferMemoryRequirements(dev, self.handle)
        if host:
            mtype = ctx.memory_type(req.memoryTypeBits, HOST | vk.VK_MEMORY_PROPERTY_HOST_CACHED_BIT)
        else:
            mtype = ctx.memory_type(req.memoryTypeBits, DEVICE)
        try:
            self.memory = allocate(ctx, req, mtype, f"buffer {name!r}" if name else "a buffer")
        except VulkanError:
            vk.vkDestroyBuffer(dev, self.handle, None)
            raise
        vk.vkBindBufferMemory(dev, self.handle, self.memory, 0)
        self._mapped = vk.vkMapMemory(dev, self.memory, 0, self.size, 0) if host else None
        self._alive = True
        ctx.defer_destroy(self.destroy)

    def view(self, dtype=np.uint8) -> np.ndarray:
        """A numpy view on the mapped memory (host buffers only)."""
        assert self._mapped is not None, "not a host-visible buffer"
        return np.frombuffer(self._mapped, dtype=dtype, count=self.size // np.dtype(dtype).itemsize)

    def write(self, data, offset: int = 0):
        """Copy bytes into a host buffer."""
        raw = np.ascontiguousarray(data).view(np.uint8).reshape(-1)
        self.view()[offset:offset + raw.nbytes] = raw

    def destroy(self):
        if self._alive:
            self._alive = False
            if self._mapped is not None:
                vk.vkUnmapMemory(self.ctx.device, self.memory)
                self._mapped = None
            vk.vkDestroyBuffer(self.ctx.device, self.handle, None)
            free(self.ctx, self.memory)


class BufferView:
    """A typed view of a buffer, for binding it as a texel buffer (the buffer needs UNIFORM_TEXEL usage, or
    STORAGE_TEXEL for a storage texel buffer)."""

    def __init__(self, buf: Buffer, fmt: int = vk.VK_FORMAT_R32G32B32A32_UINT, offset: int = 0,
                 size: int | None = None):
        """The bytes [offset, offset + size) of `buf` (default: from offset to its end)."""
        self.ctx, self.buffer = buf.ctx, buf
        self.handle = vk.vkCreateBufferView(buf.ctx.device, vk.VkBufferViewCreateInfo(
            buffer=buf.handle, format=fmt, offset=int(offset),
            range=0xFFFFFFFFFFFFFFFF if size is None else int(size)), None)
        self._alive = True
        buf.ctx.defer_destroy(self.destroy)

    def destroy(self):
        if self._alive:
            self._alive = False
            vk.vkDestroyBufferView(self.ctx.device, self.handle, None)


def upload_buffer(ctx: Context, data: np.ndarray, usage: int, name: str = "") -> Buffer:
    """A device-local buffer filled with `data` through a staging buffer."""
    raw = np.ascontiguousarray(data).view(np.uint8).reshape(-1)
    buf = Buffer(ctx, raw.nbytes, usage | TRANSFER_DST, name=name)
    if raw.nbytes:
        staging = Buffer(ctx, raw.nbytes, TRANSFER_SRC, host=True)
        staging.write(raw)
        with ctx.one_shot() as cmd:
            vk.vkCmdCopyBuffer(cmd, staging.handle, buf.handle, 1, [vk.VkBufferCopy(0, 0, raw.nbytes)])
        staging.destroy()
    return buf


def update_buffer(ctx: Context, buf: Buffer, parts, staging: Buffer | None = None) -> None:
    """Overwrite ranges of a device-local buffer: `parts` = [(byte offset, array)], copied through `staging` (a
    host TRANSFER_SRC buffer large enough for all of them; None: a temporary one). Runs at once, ordered after
    every earlier use of `buf` on the queue and before every later one."""
    raws = [(int(off), np.ascontiguousarray(a).view(np.uint8).reshape(-1)) for off, a in parts]
    total = sum(r.nbytes for _, r in raws)
    if total == 0:
        return
    own = staging is None or staging.size < total
    if own:
        staging = Buffer(ctx, total, TRANSFER_SRC, host=True, name="update staging")
    try:
        regions, at = [], 0
        for off, raw in raws:
            staging.write(raw, at)
            regions.append(vk.VkBufferCopy(at, off, raw.nbytes))
            at += raw.nbytes
        with ctx.one_shot() as cmd:
            all_ = vk.VK_PIPELINE_STAGE_ALL_COMMANDS_BIT
            memory_barrier(cmd, all_, vk.VK_PIPELINE_STAGE_TRANSFER_BIT, vk.VK_ACCESS_MEMORY_READ_BIT,
                           vk.VK_ACCESS_TRANSFER_WRITE_BIT)
            vk.vkCmdCopyBuffer(cmd, staging.handle, buf.handle, len(regions), regions)
            memory_barrier(cmd, vk.VK_PIPELINE_STAGE_TRANSFER_BIT, all_, vk.VK_ACCESS_TRANSFER_WRITE_BIT,
                           vk.VK_ACCESS_MEMORY_READ_BIT | vk.VK_ACCESS_SHADER_READ_BIT)
    finally:
        if own:
            staging.destroy()


def _aspect(fmt):
    if fmt in (vk.VK_FORMAT_D32_SFLOAT, vk.VK_FORMAT_D16_UNORM):
        return vk.VK_IMAGE_ASPECT_DEPTH_BIT
    return vk.VK_IMAGE_ASPECT_COLOR_BIT


class Image:
    """A 2D image (optionally mipmapped) with one view over all its levels."""

    def __init__(self, ctx: Context, width: int, height: int, fmt: int, usage: int, mip_levels: int = 1, name=""):
        self.ctx, self.width, self.height, self.format, self.name = ctx, width, height, fmt, name
        self.mip_levels = mip_levels
        self.aspect = _aspect(fmt)
        dev = ctx.device
        self.handle = vk.vkCreateImage(dev, vk.VkImageCreateInfo(
            imageType=vk.VK_IMAGE_TYPE_2D, format=fmt, extent=vk.VkExtent3D(width, height, 1),
            mipLevels=mip_levels, arrayLayers=1, samples=vk.VK_SAMPLE_COUNT_1_BIT,
            tiling=vk.VK_IMAGE_TILING_OPTIMAL, usage=usage, sharingMode=vk.VK_SHARING_MODE_EXCLUSIVE,
            initialLayout=vk.VK_IMAGE_LAYOUT_UNDEFINED), None)
        req = vk.vkGetImageMemoryRequirements(dev, self.handle)
        try:
            self.memory = allocate(ctx, req, ctx.memory_type(req.memoryTypeBits, DEVICE),
                                   f"image {name!r} ({width}x{height})" if name else f"a {width}x{height} image")
        except VulkanError:
            vk.vkDestroyImage(dev, self.handle, None)
            raise
        vk.vkBindImageMemory(dev, self.handle, self.memory, 0)
        self.view = vk.vkCreateImageView(dev, vk.VkImageViewCreateInfo(
            image=self.handle, viewType=vk.VK_IMAGE_VIEW_TYPE_2D, format=fmt,
            subresourceRange=self.range()), None)
        self._alive = True
        ctx.defer_destroy(self.destroy)

    def range(self, base_mip=0, levels=None):
        return vk.VkImageSubresourceRange(aspectMask=self.aspect, baseMipLevel=base_mip,
                                          levelCount=self.mip_levels if levels is None else levels,
                                          baseArrayLayer=0, layerCount=1)

    def destroy(self):
        if self._alive:
            self._alive = False
            vk.vkDestroyImageView(self.ctx.device, self.view, None)
            vk.vkDestroyImage(self.ctx.device, self.handle, None)
            free(self.ctx, self.memory)


def image_barrier(cmd, image: Image, old, new, src_stage, dst_stage, src_access, dst_access, base_mip=0, levels=None):
    barrier = vk.VkImageMemoryBarrier(
        srcAccessMask=src_access, dstAccessMask=dst_access, oldLayout=old, newLayout=new,
        srcQueueFamilyIndex=vk.VK_QUEUE_FAMILY_IGNORED, dstQueueFamilyIndex=vk.VK_QUEUE_FAMILY_IGNORED,
        image=image.handle, subresourceRange=image.range(base_mip, levels))
    vk.vkCmdPipelineBarrier(cmd, src_stage, dst_stage, 0, 0, None, 0, None, 1, [barrier])


def memory_barrier(cmd, src_stage, dst_stage, src_access, dst_access):
    barrier = vk.VkMemoryBarrier(srcAccessMask=src_access, dstAccessMask=dst_access)
    vk.vkCmdPipelineBarrier(cmd, src_stage, dst_stage, 0, 1, [barrier], 0, None, 0, None)


def upload_texture(ctx: Context, rgba: np.ndarray, srgb: bool = True) -> Image:
    """An RGBA8 texture with a full mip chain, filled through staging and blits, left SHADER_READ_ONLY."""
    h, w = rgba.shape[:2]
    levels = int(np.floor(np.log2(max(w, h)))) + 1
    fmt = vk.VK_FORMAT_R8G8B8A8_SRGB if srgb else vk.VK_FORMAT_R8G8B8A8_UNORM
    img = Image(ctx, w, h, fmt, vk.VK_IMAGE_USAGE_SAMPLED_BIT | vk.VK_IMAGE_USAGE_TRANSFER_DST_BIT
                | vk.VK_IMAGE_USAGE_TRANSFER_SRC_BIT, mip_levels=levels, name="texture")
    staging = Buffer(ctx, rgba.nbytes, TRANSFER_SRC, host=True)
    staging.write(np.ascontiguousarray(rgba, dtype=np.uint8))
    T, TW, TR = (vk.VK_PIPELINE_STAGE_TRANSFER_BIT, vk.VK_ACCESS_TRANSFER_WRITE_BIT, vk.VK_ACCESS_TRANSFER_READ_BIT)
    with ctx.one_shot() as cmd:
        image_barrier(cmd, img, vk.VK_IMAGE_LAYOUT_UNDEFINED, vk.VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                      vk.VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, T, 0, TW)
        region = vk.VkBufferImageCopy(
            bufferOffset=0, bufferRowLength=0, bufferImageHeight=0,
            imageSubresource=vk.VkImageSubresourceLayers(vk.VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1),
            imageOffset=vk.VkOffset3D(0, 0, 0), imageExtent=vk.VkExtent3D(w, h, 1))
        vk.vkCmdCopyBufferToImage(cmd, staging.handle, img.handle, vk.VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 1, [region])
        mw, mh = w, h
        for level in range(1, levels):
            image_barrier(cmd, img, vk.VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, vk.VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL,
                          T, T, TW, TR, base_mip=level - 1, levels=1)
            nw, nh = max(mw // 2, 1), max(mh // 2, 1)
            blit = vk.VkImageBlit(
                srcSubresource=vk.VkImageSubresourceLayers(vk.VK_IMAGE_ASPECT_COLOR_BIT, level - 1, 0, 1),
                srcOffsets=[vk.VkOffset3D(0, 0, 0), vk.VkOffset3D(mw, mh, 1)],
                dstSubresource=vk.VkImageSubresourceLayers(vk.VK_IMAGE_ASPECT_COLOR_BIT, level, 0, 1),
                dstOffsets=[vk.VkOffset3D(0, 0, 0), vk.VkOffset3D(nw, nh, 1)])
            vk.vkCmdBlitImage(cmd, img.handle, vk.VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, img.handle,
                              vk.VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 1, [blit], vk.VK_FILTER_LINEAR)
            image_barrier(cmd, img, vk.VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL,
                          vk.VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL, T,
                          vk.VK_PIPELINE_STAGE_FRAGMENT_SHADER_BIT, TR, vk.VK_ACCESS_SHADER_READ_BIT,
                          base_mip=level - 1, levels=1)
            mw, mh = nw, nh
        image_barrier(cmd, img, vk.VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, vk.VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL,
                      T, vk.VK_PIPELINE_STAGE_FRAGMENT_SHADER_BIT, TW, vk.VK_ACCESS_SHADER_READ_BIT,
                      base_mip=levels - 1, levels=1)
    staging.destroy()
    return img


class Sampler:
    def __init__(self, ctx: Context, linear=True, repeat=True, max_lod=16.0):
        self.ctx = ctx
        filt = vk.VK_FILTER_LINEAR if linear else vk.VK_FILTER_NEAREST
        mode = vk.VK_SAMPLER_ADDRESS_MODE_REPEAT if repeat else vk.VK_SAMPLER_ADDRESS_MODE_CLAMP_TO_EDGE
        self.handle = vk.vkCreateSampler(ctx.device, vk.VkSamplerCreateInfo(
            magFilter=filt, minFilter=filt, mipmapMode=vk.VK_SAMPLER_MIPMAP_MODE_LINEAR,
            addressModeU=mode, addressModeV=mode, addressModeW=mode, maxLod=max_lod, minLod=0.0,
            maxAnisotropy=1.0, borderColor=vk.VK_BORDER_COLOR_FLOAT_OPAQUE_WHITE), None)
        ctx.defer_destroy(vk.vkDestroySampler, ctx.device, self.handle, None)
