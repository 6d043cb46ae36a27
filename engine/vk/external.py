"""Buffers whose memory another API on the same GPU can map (CUDA): allocated exportable as an opaque POSIX file
descriptor (VK_KHR_external_memory_fd) and handed out with vkGetMemoryFdKHR.

    reason = external_memory_unsupported(ctx)     # None where it works, else why not
    buf = ExternalBuffer(ctx, size, STORAGE)      # an engine.vk.Buffer in device-local, exportable memory
    fd = buf.export_fd()                          # a new descriptor; the importer (cudaImportExternalMemory) owns it
    uuid = device_uuid(ctx)                       # 16 bytes: which CUDA device is this Vulkan device
"""

from __future__ import annotations

import vulkan as vk

from ..errors import VulkanError
from .context import Context
from .resources import DEVICE, Buffer, allocate

OPAQUE_FD = vk.VK_EXTERNAL_MEMORY_HANDLE_TYPE_OPAQUE_FD_BIT
EXTENSION = vk.VK_KHR_EXTERNAL_MEMORY_FD_EXTENSION_NAME


def external_memory_unsupported(ctx: Context) -> str | None:
    """Why this device cannot export buffer memory as an opaque fd (None: it can)."""
    if not getattr(ctx, "external_memory_fd", False):
        return f"the Vulkan device {ctx.device_info['name']!r} lacks {EXTENSION}"
    return None


def device_uuid(ctx: Context) -> bytes:
    """The device's UUID (VkPhysicalDeviceIDProperties.deviceUUID), which CUDA reports for the same GPU."""
    ids = vk.VkPhysicalDeviceIDProperties()
    vk.vkGetPhysicalDeviceProperties2(ctx.physical, vk.VkPhysicalDeviceProperties2(pNext=ids))
    return bytes(vk.ffi.buffer(ids.deviceUUID, vk.VK_UUID_SIZE))


def _dedicated_only(ctx: Context, usage: int) -> bool:
    """Whether the driver exports such buffers' memory only from dedicated allocations."""
    props = vk.VkExternalBufferProperties()  # (given, so that its sType is set)
    vk.vkGetPhysicalDeviceExternalBufferProperties(
        ctx.physical, vk.VkPhysicalDeviceExternalBufferInfo(usage=usage, handleType=OPAQUE_FD), props
    )
    feats = props.externalMemoryProperties.externalMemoryFeatures
    if not feats & vk.VK_EXTERNAL_MEMORY_FEATURE_EXPORTABLE_BIT:
        raise VulkanError(f"{ctx.device_info['name']!r} cannot export buffer memory as an opaque fd")
    return bool(feats & vk.VK_EXTERNAL_MEMORY_FEATURE_DEDICATED_ONLY_BIT)


class ExternalBuffer(Buffer):
    """A device-local Buffer whose memory can be exported (`export_fd`) and mapped by CUDA. `allocation_size` is the
    size of the whole allocation (what an importer maps), `dedicated` whether it is a dedicated allocation (CUDA's
    cudaExternalMemoryDedicated flag must then be set). Destroyed like any Buffer, after the importer let go."""

    def __init__(self, ctx: Context, size: int, usage: int, name: str = ""):
        reason = external_memory_unsupported(ctx)
        if reason:
            raise VulkanError(f"buffer {name!r}: {reason}")
        self.ctx, self.size, self.host, self.name = ctx, max(int(size), 4), False, name
        self._mapped = None
        dev = ctx.device
        self.dedicated = _dedicated_only(ctx, usage)
        self.handle = vk.vkCreateBuffer(
            dev,
            vk.VkBufferCreateInfo(
                pNext=vk.VkExternalMemoryBufferCreateInfo(handleTypes=OPAQUE_FD),
                size=self.size,
                usage=usage,
                sharingMode=vk.VK_SHARING_MODE_EXCLUSIVE,
            ),
            None,
        )
        req = vk.vkGetBufferMemoryRequirements(dev, self.handle)
        mtype = ctx.memory_type(req.memoryTypeBits, DEVICE)
        chain = vk.VkMemoryDedicatedAllocateInfo(buffer=self.handle) if self.dedicated else None
        export = vk.VkExportMemoryAllocateInfo(pNext=chain, handleTypes=OPAQUE_FD)
        try:
            self.memory = allocate(ctx, req, mtype, f"buffer {name!r}" if name else "a buffer", pnext=export)
        except VulkanError:
            vk.vkDestroyBuffer(dev, self.handle, None)
            raise
        self.allocation_size = int(req.size)
        vk.vkBindBufferMemory(dev, self.handle, self.memory, 0)
        self._alive = True
        ctx.defer_destroy(self.destroy)

    def export_fd(self) -> int:
        """A new file descriptor for this buffer's memory; whoever receives it closes it (CUDA does on import)."""
        get_fd = vk.vkGetDeviceProcAddr(self.ctx.device, "vkGetMemoryFdKHR")
        return int(get_fd(self.ctx.device, vk.VkMemoryGetFdInfoKHR(memory=self.memory, handleType=OPAQUE_FD)))
