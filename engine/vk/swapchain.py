"""A VkSwapchainKHR on the Context's surface: create, recreate on resize, acquire and present.

The renderer's colour target already holds sRGB-encoded values, so a UNORM swapchain format is preferred
(B8G8R8A8_UNORM, then R8G8B8A8_UNORM): a blit then copies the values unchanged. With only an _SRGB format
on offer the blit would encode a second time; `Swapchain.srgb` says so, and the viewer warns.

Swapchain images are only ever written by transfers (blits), so the usage is TRANSFER_DST (+ COLOR_ATTACHMENT,
which every surface supports and some drivers expect).
"""

from __future__ import annotations

import logging

import vulkan as vk

from ..errors import VulkanError
from .context import Context

log = logging.getLogger("engine.vk")

PRESENT_MODES = {
    "fifo": vk.VK_PRESENT_MODE_FIFO_KHR,
    "mailbox": vk.VK_PRESENT_MODE_MAILBOX_KHR,
    "immediate": vk.VK_PRESENT_MODE_IMMEDIATE_KHR,
}
PREFERRED_FORMATS = (
    vk.VK_FORMAT_B8G8R8A8_UNORM,
    vk.VK_FORMAT_R8G8B8A8_UNORM,
    vk.VK_FORMAT_B8G8R8A8_SRGB,
    vk.VK_FORMAT_R8G8B8A8_SRGB,
)
_SRGB_FORMATS = {vk.VK_FORMAT_B8G8R8A8_SRGB, vk.VK_FORMAT_R8G8B8A8_SRGB}
# How long acquire waits for an image: a presentation engine that stalls (a hidden window on some systems) must not
# hang the caller, which can then handle its window's events (a close) and try again
ACQUIRE_TIMEOUT_NS = 1_000_000_000


class Swapchain:
    """`Swapchain(ctx, width, height, present_mode="fifo")`.

    `images` (VkImage handles), `extent` (w, h), `format`, `generation` (bumped on every recreate, so
    users can tell that what they recorded against the images is stale). `acquire(semaphore)` returns
    `(index, suboptimal)`, `(None, False)` when no image came within the timeout, or None when the swapchain is
    out of date; `present(index, wait)` returns False
    when it should be recreated. `recreate(w, h)` waits for the device and rebuilds on the old one.
    """

    def __init__(self, ctx: Context, width: int, height: int, present_mode: str = "fifo"):
        if ctx.surface is None:
            raise VulkanError("a swapchain needs a Context made with a surface_factory")
        if present_mode not in PRESENT_MODES:
            raise VulkanError(f"present mode {present_mode!r}: expected one of {', '.join(PRESENT_MODES)}")
        self.ctx = ctx
        self.want_mode = present_mode
        self.handle = None
        self.images: list = []
        self.extent = (0, 0)
        self.generation = 0
        inst, dev = ctx.instance, ctx.device
        self._caps_fn = vk.vkGetInstanceProcAddr(inst, "vkGetPhysicalDeviceSurfaceCapabilitiesKHR")
        self._formats_fn = vk.vkGetInstanceProcAddr(inst, "vkGetPhysicalDeviceSurfaceFormatsKHR")
        self._modes_fn = vk.vkGetInstanceProcAddr(inst, "vkGetPhysicalDeviceSurfacePresentModesKHR")
        self._create_fn = vk.vkGetDeviceProcAddr(dev, "vkCreateSwapchainKHR")
        self._destroy_fn = vk.vkGetDeviceProcAddr(dev, "vkDestroySwapchainKHR")
        self._images_fn = vk.vkGetDeviceProcAddr(dev, "vkGetSwapchainImagesKHR")
        self._acquire_fn = vk.vkGetDeviceProcAddr(dev, "vkAcquireNextImageKHR")
        self._present_fn = vk.vkGetDeviceProcAddr(dev, "vkQueuePresentKHR")
        self._index = vk.ffi.new("uint32_t*")
        self.format, self.color_space = self._choose_format()
        self.srgb = self.format in _SRGB_FORMATS
        self.present_mode = self._choose_mode(present_mode)
        ctx.defer_destroy(self.destroy)
        self.recreate(width, height)

    # ---- choices --------------------------------------------------------------------------
    def _choose_format(self):
        formats = list(self._formats_fn(self.ctx.physical, self.ctx.surface))
        if not formats:
            raise VulkanError("the surface offers no formats")
        by_format = {f.format: f for f in formats}
        for want in PREFERRED_FORMATS:
            if want in by_format and by_format[want].colorSpace == vk.VK_COLOR_SPACE_SRGB_NONLINEAR_KHR:
                return want, by_format[want].colorSpace
        if len(formats) == 1 and formats[0].format == vk.VK_FORMAT_UNDEFINED:  # "anything goes"
            return vk.VK_FORMAT_B8G8R8A8_UNORM, vk.VK_COLOR_SPACE_SRGB_NONLINEAR_KHR
        return formats[0].format, formats[0].colorSpace

    def _choose_mode(self, name):
        modes = set(self._modes_fn(self.ctx.physical, self.ctx.surface))
        want = PRESENT_MODES[name]
        if want in modes:
            return want
        log.info("present mode %s not supported by the surface; using fifo", name)
        return vk.VK_PRESENT_MODE_FIFO_KHR  # always supported

    def surface_extent(self, width, height):
        """The extent a swapchain would get for a framebuffer of width x height (0, 0 while minimized)."""
        caps = self._caps_fn(self.ctx.physical, self.ctx.surface)
        cur = caps.currentExtent
        if cur.width != 0xFFFFFFFF:
            return int(cur.width), int(cur.height)
        lo, hi = caps.minImageExtent, caps.maxImageExtent
        return (max(lo.width, min(hi.width, int(width))), max(lo.height, min(hi.height, int(height))))

    # ---- lifetime -------------------------------------------------------------------------
    def recreate(self, width: int, height: int) -> bool:
        """(Re)build for a framebuffer of width x height. Returns False (and keeps nothing) while it is 0x0."""
        ctx = self.ctx
        caps = self._caps_fn(ctx.physical, ctx.surface)
        w, h = self.surface_extent(width, height)
        ctx.wait_idle()
        if w == 0 or h == 0:
            return False
        count = caps.minImageCount + 1
        if caps.maxImageCount:
            count = min(count, caps.maxImageCount)
        usage = vk.VK_IMAGE_USAGE_TRANSFER_DST_BIT | vk.VK_IMAGE_USAGE_COLOR_ATTACHMENT_BIT
        if caps.supportedUsageFlags & usage != usage:
            raise VulkanError(
                f"the surface does not allow TRANSFER_DST swapchain images (usage {caps.supportedUsageFlags:#x})"
            )
        alpha = vk.VK_COMPOSITE_ALPHA_OPAQUE_BIT_KHR
        if not caps.supportedCompositeAlpha & alpha:
            alpha = next(
                b
                for b in (
                    vk.VK_COMPOSITE_ALPHA_INHERIT_BIT_KHR,
                    vk.VK_COMPOSITE_ALPHA_PRE_MULTIPLIED_BIT_KHR,
                    vk.VK_COMPOSITE_ALPHA_POST_MULTIPLIED_BIT_KHR,
                )
                if caps.supportedCompositeAlpha & b
            )
        old = self.handle
        info = vk.VkSwapchainCreateInfoKHR(
            surface=ctx.surface,
            minImageCount=count,
            imageFormat=self.format,
            imageColorSpace=self.color_space,
            imageExtent=vk.VkExtent2D(w, h),
            imageArrayLayers=1,
            imageUsage=usage,
            imageSharingMode=vk.VK_SHARING_MODE_EXCLUSIVE,
            preTransform=caps.currentTransform,
            compositeAlpha=alpha,
            presentMode=self.present_mode,
            clipped=vk.VK_TRUE,
            oldSwapchain=old if old is not None else vk.VK_NULL_HANDLE,
        )
        try:
            self.handle = self._create_fn(ctx.device, info, None)
        except vk.VkError as exc:
            self.handle, self.images = None, []
            raise VulkanError(f"could not create a {w}x{h} swapchain: {type(exc).__name__}") from None
        finally:
            if old is not None:
                self._destroy_fn(ctx.device, old, None)
        self.images = list(self._images_fn(ctx.device, self.handle))
        self.extent = (w, h)
        self.generation += 1
        log.debug(
            "swapchain %dx%d, %d images, format %d, present mode %d",
            w,
            h,
            len(self.images),
            self.format,
            self.present_mode,
        )
        return True

    def destroy(self):
        if self.handle is not None:
            self._destroy_fn(self.ctx.device, self.handle, None)
            self.handle = None
            self.images = []

    # ---- per frame ------------------------------------------------------------------------
    def acquire(self, semaphore, timeout=ACQUIRE_TIMEOUT_NS):
        """Next image index and whether the swapchain is suboptimal; (None, False) when no image came within
        `timeout` ns (the semaphore stays unsignalled); None when it is out of date."""
        try:
            self._acquire_fn(self.ctx.device, self.handle, timeout, semaphore, vk.VK_NULL_HANDLE, self._index)
        except vk.VkSuboptimalKhr:  # an image was acquired (the semaphore will be signalled): use it
            return int(self._index[0]), True
        except vk.VkErrorOutOfDateKhr:
            return None
        except (vk.VkTimeout, vk.VkNotReady):
            return None, False
        return int(self._index[0]), False

    def present(self, index: int, wait_semaphores=()) -> bool:
        """Queue image `index` for presentation; False when the swapchain should be recreated."""
        info = vk.VkPresentInfoKHR(
            waitSemaphoreCount=len(wait_semaphores),
            pWaitSemaphores=list(wait_semaphores) or None,
            swapchainCount=1,
            pSwapchains=[self.handle],
            pImageIndices=[index],
        )
        try:
            self._present_fn(self.ctx.queue, info)
        except (vk.VkSuboptimalKhr, vk.VkErrorOutOfDateKhr):
            return False
        return True
