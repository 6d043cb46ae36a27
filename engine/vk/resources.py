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


def allocate(ctx: Context, req, mtype: int, what: str, pnext=None):
    """Device memory for a resource's requirements `req`, or a VulkanError naming `what` and the size (refused before
    the call when it exceeds the memory heap). `pnext`: extension structures of the allocation (export, ...)."""
    mp = ctx.memory_properties
    heap = mp.memoryHeaps[mp.memoryTypes[mtype].heapIndex].size
    size = f"{req.size / 2**20:.1f} MiB"
    if req.size > heap:
        raise VulkanError(
            f"{what}: {size} is more than this device's memory heap of {heap / 2**20:.0f} MiB "
            f"({ctx.device_info['name']}); use a smaller size or scene"
        )
    try:
        memory = vk.vkAllocateMemory(
            ctx.device, vk.VkMemoryAllocateInfo(pNext=pnext, allocationSize=req.size, memoryTypeIndex=mtype), None
        )
    except _OUT_OF_MEMORY as exc:
        kind = "device" if isinstance(exc, vk.VkErrorOutOfDeviceMemory) else "host"
        raise VulkanError(f"{what}: out of {kind} memory allocating {size} on {ctx.device_info['name']}") from None
    ctx.allocations += 1
    return memory


def _all_device_memory_mappable(ctx: Context) -> bool:
    """Is every device-local memory type host-visible and coherent (no VRAM that only the device reaches)?"""
    mp = ctx.memory_properties
    return all(
        mp.memoryTypes[i].propertyFlags & HOST == HOST
        for i in range(mp.memoryTypeCount)
        if mp.memoryTypes[i].propertyFlags & DEVICE
    )


def free(ctx: Context, memory):
    vk.vkFreeMemory(ctx.device, memory, None)
    ctx.allocations -= 1


class Buffer:
    """A VkBuffer with its own memory. `host=True` maps it persistently (`.view(dtype)`)."""

    def __init__(self, ctx: Context, size: int, usage: int, host: bool = False, name: str = ""):
        self.ctx, self.size, self.host, self.name = ctx, max(int(size), 4), host, name
        dev = ctx.device
        self.handle = vk.vkCreateBuffer(
            dev, vk.VkBufferCreateInfo(size=self.size, usage=usage, sharingMode=vk.VK_SHARING_MODE_EXCLUSIVE), None
        )
        req = vk.vkGetBufferMemoryRequirements(dev, self.handle)
        if host:
            mtype = ctx.memory_type(req.memoryTypeBits, HOST | vk.VK_MEMORY_PROPERTY_HOST_CACHED_BIT)
        else:
            mtype = ctx.memory_type(req.memoryTypeBits, DEVICE)
        # device-local memory that the host may write without a copy: where every device-local type is host-visible
        # and coherent (a CPU device, an integrated GPU; not a discrete GPU's small mappable window)
        self.host_writable = (
            ctx.memory_properties.memoryTypes[mtype].propertyFlags & HOST
        ) == HOST and _all_device_memory_mappable(ctx)
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
        self.view()[offset : offset + raw.nbytes] = raw

    def destroy(self):
        if self._alive:
            self._alive = False
            if self.ctx.hung:  # the GPU may still use it: left to the driver (Context._abandon)
                return
            if self._mapped is not None:
                vk.vkUnmapMemory(self.ctx.device, self.memory)
                self._mapped = None
            vk.vkDestroyBuffer(self.ctx.device, self.handle, None)
            free(self.ctx, self.memory)


class BufferView:
    """A typed view of a buffer, for binding it as a texel buffer (the buffer needs UNIFORM_TEXEL usage, or
    STORAGE_TEXEL for a storage texel buffer)."""

    def __init__(
        self, buf: Buffer, fmt: int = vk.VK_FORMAT_R32G32B32A32_UINT, offset: int = 0, size: int | None = None
    ):
        """The bytes [offset, offset + size) of `buf` (default: from offset to its end)."""
        self.ctx, self.buffer = buf.ctx, buf
        self.handle = vk.vkCreateBufferView(
            buf.ctx.device,
            vk.VkBufferViewCreateInfo(
                buffer=buf.handle,
                format=fmt,
                offset=int(offset),
                range=0xFFFFFFFFFFFFFFFF if size is None else int(size),
            ),
            None,
        )
        self._alive = True
        buf.ctx.defer_destroy(self.destroy)

    def destroy(self):
        if self._alive:
            self._alive = False
            if self.ctx.hung:  # (as Buffer.destroy)
                return
            vk.vkDestroyBufferView(self.ctx.device, self.handle, None)


def upload_buffer(ctx: Context, data: np.ndarray, usage: int, name: str = "") -> Buffer:
    """A device-local buffer filled with `data` (as `upload_buffers`)."""
    return upload_buffers(ctx, [(data, usage, name)])[0]


def upload_buffers(ctx: Context, items) -> list[Buffer]:
    """Device-local buffers filled with the arrays of `items`, (data, usage, name) each: written in place where the
    host may write the device memory (`Buffer.host_writable`), else through one staging buffer and one submission
    for all of them."""
    raws = [np.ascontiguousarray(data).view(np.uint8).reshape(-1) for data, _, _ in items]
    bufs = [Buffer(ctx, raw.nbytes, usage | TRANSFER_DST, name=name) for raw, (_, usage, name) in zip(raws, items)]
    staged = []
    for raw, buf in zip(raws, bufs):
        if raw.nbytes and buf.host_writable:  # written in place: no staging buffer, no submission to wait for
            ptr = vk.vkMapMemory(ctx.device, buf.memory, 0, raw.nbytes, 0)
            try:
                np.frombuffer(ptr, np.uint8, raw.nbytes)[:] = raw
            finally:
                vk.vkUnmapMemory(ctx.device, buf.memory)
        elif raw.nbytes:
            staged.append((raw, buf))
    if staged:
        staging = Buffer(ctx, sum(raw.nbytes for raw, _ in staged), TRANSFER_SRC, host=True)
        regions, at = [], 0
        for raw, buf in staged:
            staging.write(raw, at)
            regions.append((buf, vk.VkBufferCopy(at, 0, raw.nbytes)))
            at += raw.nbytes
        with ctx.one_shot() as cmd:
            for buf, region in regions:
                vk.vkCmdCopyBuffer(cmd, staging.handle, buf.handle, 1, [region])
        staging.destroy()
    return bufs


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
            memory_barrier(
                cmd,
                all_,
                vk.VK_PIPELINE_STAGE_TRANSFER_BIT,
                vk.VK_ACCESS_MEMORY_READ_BIT,
                vk.VK_ACCESS_TRANSFER_WRITE_BIT,
            )
            vk.vkCmdCopyBuffer(cmd, staging.handle, buf.handle, len(regions), regions)
            memory_barrier(
                cmd,
                vk.VK_PIPELINE_STAGE_TRANSFER_BIT,
                all_,
                vk.VK_ACCESS_TRANSFER_WRITE_BIT,
                vk.VK_ACCESS_MEMORY_READ_BIT | vk.VK_ACCESS_SHADER_READ_BIT,
            )
    finally:
        if own:
            staging.destroy()


def read_buffer(ctx: Context, buf: Buffer, dtype=np.uint8) -> np.ndarray:
    """A copy of a device-local buffer's contents (it needs TRANSFER_SRC usage), after every earlier use of it on
    the queue (for tests and diagnostics: it waits for the device)."""
    staging = Buffer(ctx, buf.size, TRANSFER_DST, host=True, name="read staging")
    try:
        with ctx.one_shot() as cmd:
            all_ = vk.VK_PIPELINE_STAGE_ALL_COMMANDS_BIT
            memory_barrier(
                cmd,
                all_,
                vk.VK_PIPELINE_STAGE_TRANSFER_BIT,
                vk.VK_ACCESS_MEMORY_WRITE_BIT,
                vk.VK_ACCESS_TRANSFER_READ_BIT,
            )
            vk.vkCmdCopyBuffer(cmd, buf.handle, staging.handle, 1, [vk.VkBufferCopy(0, 0, buf.size)])
            memory_barrier(
                cmd,
                vk.VK_PIPELINE_STAGE_TRANSFER_BIT,
                vk.VK_PIPELINE_STAGE_HOST_BIT,
                vk.VK_ACCESS_TRANSFER_WRITE_BIT,
                vk.VK_ACCESS_HOST_READ_BIT,
            )
        return staging.view(dtype).copy()
    finally:
        staging.destroy()


def _aspect(fmt):
    if fmt in (vk.VK_FORMAT_D32_SFLOAT, vk.VK_FORMAT_D16_UNORM):
        return vk.VK_IMAGE_ASPECT_DEPTH_BIT
    return vk.VK_IMAGE_ASPECT_COLOR_BIT


class Image:
    """A 2D image (optionally mipmapped, optionally an array of `layers`) with one view over all its levels and
    layers (a 2D view, or a 2D array view when `array`)."""

    def __init__(
        self,
        ctx: Context,
        width: int,
        height: int,
        fmt: int,
        usage: int,
        mip_levels: int = 1,
        name="",
        layers: int = 1,
        array: bool = False,
    ):
        self.ctx, self.width, self.height, self.format, self.name = ctx, width, height, fmt, name
        self.mip_levels, self.layers = mip_levels, layers
        self.aspect = _aspect(fmt)
        dev = ctx.device
        self.handle = vk.vkCreateImage(
            dev,
            vk.VkImageCreateInfo(
                imageType=vk.VK_IMAGE_TYPE_2D,
                format=fmt,
                extent=vk.VkExtent3D(width, height, 1),
                mipLevels=mip_levels,
                arrayLayers=layers,
                samples=vk.VK_SAMPLE_COUNT_1_BIT,
                tiling=vk.VK_IMAGE_TILING_OPTIMAL,
                usage=usage,
                sharingMode=vk.VK_SHARING_MODE_EXCLUSIVE,
                initialLayout=vk.VK_IMAGE_LAYOUT_UNDEFINED,
            ),
            None,
        )
        req = vk.vkGetImageMemoryRequirements(dev, self.handle)
        try:
            self.memory = allocate(
                ctx,
                req,
                ctx.memory_type(req.memoryTypeBits, DEVICE),
                f"image {name!r} ({width}x{height}x{layers})" if name else f"a {width}x{height} image",
            )
        except VulkanError:
            vk.vkDestroyImage(dev, self.handle, None)
            raise
        vk.vkBindImageMemory(dev, self.handle, self.memory, 0)
        self.view = vk.vkCreateImageView(
            dev,
            vk.VkImageViewCreateInfo(
                image=self.handle,
                format=fmt,
                viewType=vk.VK_IMAGE_VIEW_TYPE_2D_ARRAY if array else vk.VK_IMAGE_VIEW_TYPE_2D,
                subresourceRange=self.range(),
            ),
            None,
        )
        self._alive = True
        ctx.defer_destroy(self.destroy)

    def range(self, base_mip=0, levels=None):
        return vk.VkImageSubresourceRange(
            aspectMask=self.aspect,
            baseMipLevel=base_mip,
            levelCount=self.mip_levels if levels is None else levels,
            baseArrayLayer=0,
            layerCount=self.layers,
        )

    def destroy(self):
        if self._alive:
            self._alive = False
            if self.ctx.hung:  # (as Buffer.destroy)
                return
            vk.vkDestroyImageView(self.ctx.device, self.view, None)
            vk.vkDestroyImage(self.ctx.device, self.handle, None)
            free(self.ctx, self.memory)


def image_barrier(cmd, image: Image, old, new, src_stage, dst_stage, src_access, dst_access, base_mip=0, levels=None):
    barrier = vk.VkImageMemoryBarrier(
        srcAccessMask=src_access,
        dstAccessMask=dst_access,
        oldLayout=old,
        newLayout=new,
        srcQueueFamilyIndex=vk.VK_QUEUE_FAMILY_IGNORED,
        dstQueueFamilyIndex=vk.VK_QUEUE_FAMILY_IGNORED,
        image=image.handle,
        subresourceRange=image.range(base_mip, levels),
    )
    vk.vkCmdPipelineBarrier(cmd, src_stage, dst_stage, 0, 0, None, 0, None, 1, [barrier])


def memory_barrier(cmd, src_stage, dst_stage, src_access, dst_access):
    barrier = vk.VkMemoryBarrier(srcAccessMask=src_access, dstAccessMask=dst_access)
    vk.vkCmdPipelineBarrier(cmd, src_stage, dst_stage, 0, 1, [barrier], 0, None, 0, None)


def _layers(layer: int, count: int, level: int = 0):
    return vk.VkImageSubresourceLayers(vk.VK_IMAGE_ASPECT_COLOR_BIT, level, layer, count)


def _layout(
    cmd,
    img: Image,
    old,
    new,
    src_access,
    dst_access,
    base_mip=0,
    levels=None,
    dst_stage=vk.VK_PIPELINE_STAGE_TRANSFER_BIT,
):
    image_barrier(
        cmd,
        img,
        old,
        new,
        vk.VK_PIPELINE_STAGE_TRANSFER_BIT if src_access else vk.VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT,
        dst_stage,
        src_access,
        dst_access,
        base_mip,
        levels,
    )


def upload_texture_array(
    ctx: Context, images: list, width: int, height: int, srgb: bool = True, name: str = "textures"
) -> Image:
    """A 2D array texture, one layer per (h, w, 4) uint8 image in `images` (in that order), each resized to
    width x height by a linear blit where its size differs (in linear light for sRGB), with a full mip chain made by
    blits (all layers at once), left SHADER_READ_ONLY. Consecutive images of one size share one temporary image and
    one blit, so callers order images by size."""
    n = len(images)
    levels = int(np.floor(np.log2(max(width, height)))) + 1
    fmt = vk.VK_FORMAT_R8G8B8A8_SRGB if srgb else vk.VK_FORMAT_R8G8B8A8_UNORM
    usage = vk.VK_IMAGE_USAGE_SAMPLED_BIT | vk.VK_IMAGE_USAGE_TRANSFER_DST_BIT | vk.VK_IMAGE_USAGE_TRANSFER_SRC_BIT
    img = Image(ctx, width, height, fmt, usage, mip_levels=levels, name=name, layers=n, array=True)
    offsets = np.cumsum([0] + [im.nbytes for im in images])
    staging = Buffer(ctx, int(offsets[-1]), TRANSFER_SRC, host=True)
    view = staging.view()
    for im, off in zip(images, offsets[:-1]):
        view[off : off + im.nbytes] = np.ascontiguousarray(im, dtype=np.uint8).reshape(-1)
    runs, start = [], 0  # (first layer, count, h, w): consecutive images of one size
    for i in range(1, n + 1):
        if i == n or images[i].shape[:2] != images[start].shape[:2]:
            runs.append((start, i - start, *images[start].shape[:2]))
            start = i
    TW, TR = vk.VK_ACCESS_TRANSFER_WRITE_BIT, vk.VK_ACCESS_TRANSFER_READ_BIT
    DST, SRC = vk.VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, vk.VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL
    READ_ONLY = vk.VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL
    temps = []
    try:
        with ctx.one_shot() as cmd:
            _layout(cmd, img, vk.VK_IMAGE_LAYOUT_UNDEFINED, DST, 0, TW)

            def copy(target, first, count, h, w, layer0):
                regions = [
                    vk.VkBufferImageCopy(
                        bufferOffset=int(offsets[first + k]),
                        bufferRowLength=0,
                        bufferImageHeight=0,
                        imageSubresource=_layers(layer0 + k, 1),
                        imageOffset=vk.VkOffset3D(0, 0, 0),
                        imageExtent=vk.VkExtent3D(w, h, 1),
                    )
                    for k in range(count)
                ]
                vk.vkCmdCopyBufferToImage(cmd, staging.handle, target.handle, DST, len(regions), regions)

            for first, count, h, w in runs:
                if (w, h) == (width, height):
                    copy(img, first, count, h, w, first)
                    continue
                tmp = Image(ctx, w, h, fmt, usage, name=f"{name} (resize)", layers=count, array=True)
                temps.append(tmp)
                _layout(cmd, tmp, vk.VK_IMAGE_LAYOUT_UNDEFINED, DST, 0, TW)
                copy(tmp, first, count, h, w, 0)
                _layout(cmd, tmp, DST, SRC, TW, TR)
                blit = vk.VkImageBlit(
                    srcSubresource=_layers(0, count),
                    srcOffsets=[vk.VkOffset3D(0, 0, 0), vk.VkOffset3D(w, h, 1)],
                    dstSubresource=_layers(first, count),
                    dstOffsets=[vk.VkOffset3D(0, 0, 0), vk.VkOffset3D(width, height, 1)],
                )
                vk.vkCmdBlitImage(cmd, tmp.handle, SRC, img.handle, DST, 1, [blit], vk.VK_FILTER_LINEAR)
            mw, mh = width, height
            for level in range(1, levels):  # each level from the one above, all layers in one blit
                _layout(cmd, img, DST, SRC, TW, TR, base_mip=level - 1, levels=1)
                nw, nh = max(mw // 2, 1), max(mh // 2, 1)
                blit = vk.VkImageBlit(
                    srcSubresource=_layers(0, n, level - 1),
                    srcOffsets=[vk.VkOffset3D(0, 0, 0), vk.VkOffset3D(mw, mh, 1)],
                    dstSubresource=_layers(0, n, level),
                    dstOffsets=[vk.VkOffset3D(0, 0, 0), vk.VkOffset3D(nw, nh, 1)],
                )
                vk.vkCmdBlitImage(cmd, img.handle, SRC, img.handle, DST, 1, [blit], vk.VK_FILTER_LINEAR)
                _layout(
                    cmd,
                    img,
                    SRC,
                    READ_ONLY,
                    TR,
                    vk.VK_ACCESS_SHADER_READ_BIT,
                    level - 1,
                    1,
                    vk.VK_PIPELINE_STAGE_ALL_COMMANDS_BIT,
                )
                mw, mh = nw, nh
            _layout(
                cmd,
                img,
                DST,
                READ_ONLY,
                TW,
                vk.VK_ACCESS_SHADER_READ_BIT,
                levels - 1,
                1,
                vk.VK_PIPELINE_STAGE_ALL_COMMANDS_BIT,
            )
    except BaseException:
        img.destroy()
        raise
    finally:
        for tmp in temps:
            tmp.destroy()
        staging.destroy()
    return img


class Sampler:
    """Linear (trilinear with mip levels) or nearest filtering; `anisotropy` > 1 enables anisotropic filtering up to
    that ratio where the device has samplerAnisotropy (`Context.max_anisotropy`; capped there)."""

    def __init__(self, ctx: Context, linear=True, repeat=True, max_lod=16.0, anisotropy: float = 1.0):
        self.ctx = ctx
        filt = vk.VK_FILTER_LINEAR if linear else vk.VK_FILTER_NEAREST
        mode = vk.VK_SAMPLER_ADDRESS_MODE_REPEAT if repeat else vk.VK_SAMPLER_ADDRESS_MODE_CLAMP_TO_EDGE
        aniso = self.anisotropy = float(max(1.0, min(anisotropy, ctx.max_anisotropy)))
        self.handle = vk.vkCreateSampler(
            ctx.device,
            vk.VkSamplerCreateInfo(
                magFilter=filt,
                minFilter=filt,
                mipmapMode=vk.VK_SAMPLER_MIPMAP_MODE_LINEAR,
                addressModeU=mode,
                addressModeV=mode,
                addressModeW=mode,
                maxLod=max_lod,
                minLod=0.0,
                anisotropyEnable=vk.VK_TRUE if aniso > 1.0 else vk.VK_FALSE,
                maxAnisotropy=aniso,
                borderColor=vk.VK_BORDER_COLOR_FLOAT_OPAQUE_WHITE,
            ),
            None,
        )
        ctx.defer_destroy(vk.vkDestroySampler, ctx.device, self.handle, None)
