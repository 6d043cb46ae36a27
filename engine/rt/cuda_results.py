"""Vulkan buffers mapped into CUDA (engine.rt.cuda_arrays), and the pool of occlusion-result buffers that the
queries on CUDA arrays hand out without a copy: the kernel writes one byte per ray into an exported buffer, and the
caller gets a bool array of its framework that views that memory. A buffer is lent to one result array at a time and
comes back to the pool when that array (and every view of it) is freed (a `weakref.finalize` on the object the
framework holds as the memory's owner), so a result stays valid however many queries follow.

    pool = ResultPool(rt, device, make)         # make(buffer) -> (descriptor set, command buffer) that write it
    entry = pool.take(n)                        # a buffer for n rays: free, or made (its set and recording with it)
    arr = pool.lend(fw, entry, n)               # the (n,) bool array over it; the entry returns when arr is freed

Work that reads a result on a stream other than the query's must be done before the array is dropped (the next
query makes only its own stream wait before Vulkan writes a returned buffer again).
"""

from __future__ import annotations

import os
import weakref

from ..errors import VulkanError
from ..vk.external import ExternalBuffer
from ..vk.resources import STORAGE, STORAGE_TEXEL

#: result buffers lent at once, at most; past that a query copies its results into a new array of its framework
POOL_MAX = 16
MIN_BYTES = 1 << 16  # the smallest result buffer (sizes are powers of two, so that buffers serve many sizes)


def ok(result, what: str):
    """The values a cuda-bindings call returned after its error code, or a VulkanError naming the call."""
    err, rest = result[0], result[1:]
    if int(err) != 0:
        raise VulkanError(f"CUDA {what} failed: {getattr(err, 'name', err)}")
    return rest[0] if len(rest) == 1 else rest


def map_memory(rt, device: int, buf: ExternalBuffer) -> tuple:
    """(external memory, device pointer): `buf`'s memory imported into CUDA on `device` (cudaImportExternalMemory) and
    mapped whole; `unmap_memory` lets go of it."""
    fd = buf.export_fd()
    prev = ok(rt.cudaGetDevice(), "cudaGetDevice")
    try:
        ok(rt.cudaSetDevice(device), "cudaSetDevice")
        desc = rt.cudaExternalMemoryHandleDesc()
        desc.type = rt.cudaExternalMemoryHandleType.cudaExternalMemoryHandleTypeOpaqueFd
        desc.handle.fd = fd
        desc.size = buf.allocation_size
        desc.flags = rt.cudaExternalMemoryDedicated if buf.dedicated else 0
        try:
            ext = ok(rt.cudaImportExternalMemory(desc), "cudaImportExternalMemory")
        except VulkanError:
            os.close(fd)  # (CUDA owns the descriptor only once imported)
            raise
        mapping = rt.cudaExternalMemoryBufferDesc()
        mapping.offset, mapping.size, mapping.flags = 0, buf.size, 0
        try:
            ptr = int(ok(rt.cudaExternalMemoryGetMappedBuffer(ext, mapping), "cudaExternalMemoryGetMappedBuffer"))
        except VulkanError:
            rt.cudaDestroyExternalMemory(ext)
            raise
        return ext, ptr
    finally:
        rt.cudaSetDevice(prev)


def unmap_memory(rt, ext, ptr: int):
    rt.cudaFree(ptr)
    rt.cudaDestroyExternalMemory(ext)


class Region:
    """A piece of CUDA memory as `__cuda_array_interface__`, for torch.as_tensor / cupy.asarray to wrap (the array
    keeps it as its memory's owner)."""

    def __init__(self, ptr: int, shape: tuple, typestr: str, device: int):
        self.device = device
        self.__cuda_array_interface__ = {
            "shape": shape,
            "typestr": typestr,
            "data": (ptr, False),
            "version": 3,
            "strides": None,
            "stream": None,
        }


class Lent:
    """One result buffer of `capacity` bytes, mapped into CUDA, with the descriptor set and recording that write it."""

    def __init__(self, pool: ResultPool, capacity: int):
        self.capacity = capacity
        self.buf = ExternalBuffer(pool.ctx, capacity, STORAGE | STORAGE_TEXEL, name="occlusion results (CUDA)")
        try:
            self.ext, self.ptr = map_memory(pool.rt, pool.device, self.buf)
        except BaseException:
            self.buf.destroy()
            raise
        self.io_set, self.command = pool.make(self.buf)
        self.mapped = True

    def unmap(self, rt):
        if self.mapped:
            self.mapped = False
            unmap_memory(rt, self.ext, self.ptr)

    def destroy_vulkan(self, ctx):
        """The Vulkan side (the device is idle: each query waits for its fence); CUDA's mapping keeps the memory for an
        array still viewing it."""
        if self.command is not None:
            ctx.free_command_buffer(self.command[0])
            self.command = None
        self.buf.destroy()


class ResultPool:
    """The result buffers of one set of shared ray buffers (see the module notes). Used under the Tracer's lock; the
    finalizer that gives a buffer back may run inside any method here (a garbage collection) and on any thread, so it
    takes no lock and makes only single list and set operations."""

    def __init__(self, ctx, rt, device: int, make):
        self.ctx, self.rt, self.device, self.make = ctx, rt, device, make
        self.free: list[Lent] = []
        self.lent: set[Lent] = set()
        self.closed = False

    def take(self, n: int) -> tuple[Lent, bool]:
        """(a buffer for n rays, whether it can be lent): the smallest free one that is large enough, else a new
        one; when POOL_MAX are lent, the caller copies out of it instead."""
        fits = [e for e in self.free if e.capacity >= n]
        if fits:
            entry = min(fits, key=lambda e: e.capacity)
            self.free.remove(entry)
        else:
            entry = Lent(self, max(MIN_BYTES, 1 << max(n - 1, 0).bit_length()))
        return entry, len(self.lent) < POOL_MAX

    def lend(self, fw, entry: Lent, n: int):
        """The (n,) bool array of framework `fw` over `entry`'s first n bytes; the entry returns when it is freed."""
        region = Region(entry.ptr, (n,), "|b1", self.device)
        self.lent.add(entry)
        weakref.finalize(region, self._back, entry)
        return fw.wrap(region)

    def put(self, entry: Lent):
        """An entry taken but not lent (its query failed) back into the pool."""
        self.free.append(entry)

    def _back(self, entry: Lent):
        self.lent.discard(entry)
        if self.closed:
            entry.unmap(self.rt)  # (its Vulkan side is gone with the pool)
        else:
            self.free.append(entry)

    def close(self):
        """Free the buffers; one still viewed by an array keeps its CUDA mapping until that array is freed."""
        self.closed = True
        free, self.free = self.free, []
        for entry in free:
            entry.unmap(self.rt)
        for entry in free + list(self.lent):
            entry.destroy_vulkan(self.ctx)
