"""Semaphores and fences, for work submitted without waiting (the viewer's frame slots)."""

from __future__ import annotations

import vulkan as vk

from .context import Context


def create_semaphore(ctx: Context):
    return vk.vkCreateSemaphore(ctx.device, vk.VkSemaphoreCreateInfo(), None)


def destroy_semaphore(ctx: Context, semaphore) -> None:
    vk.vkDestroySemaphore(ctx.device, semaphore, None)


def create_fence(ctx: Context):
    """An unsignalled fence."""
    return vk.vkCreateFence(ctx.device, vk.VkFenceCreateInfo(), None)


def destroy_fence(ctx: Context, fence) -> None:
    vk.vkDestroyFence(ctx.device, fence, None)


def wait_fences(ctx: Context, fences) -> None:
    """Block until every fence in `fences` is signalled (a lost or hung device: a VulkanError, Context.wait_fences)."""
    ctx.root.wait_fences(fences)


def reset_fences(ctx: Context, fences) -> None:
    fences = list(fences)
    vk.vkResetFences(ctx.device, len(fences), fences)
