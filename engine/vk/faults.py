"""Deliberate device loss, to test that a lost GPU gives clear errors and that a new device recovers.

`HYBRID_FAULT_INJECTION=device-lost` (or `device-lost:N`) makes the first (N-th) command buffer submitted on each
new Context run after `fault.comp`, which writes through a pointer to unmapped GPU memory: the driver answers with
VK_ERROR_DEVICE_LOST, as for any real fault (or a hang it resets). The device then enables bufferDeviceAddress.
A CPU device (lavapipe) is refused: there the shader runs in this process and the write would crash it.
"""

from __future__ import annotations

import os

import vulkan as vk

from ..data import SHADERS_DIR
from ..errors import ConfigError

ENV = "HYBRID_FAULT_INJECTION"
KIND = "device-lost"
SHADER = "fault.comp"
UNMAPPED = 0xDEAD_0000_0000  # far above what a driver maps for a process
GROUPS = 1024  # 64 invocations each, every one faulting


def requested() -> int | None:
    """The ordinal (1-based) of the submission to fault, from $HYBRID_FAULT_INJECTION; None when unset."""
    text = os.environ.get(ENV, "").strip()
    if not text:
        return None
    kind, _, count = text.partition(":")
    if kind != KIND or (count and not (count.isdigit() and int(count) >= 1)):
        raise ConfigError(f"{ENV}={text!r}: expected {KIND!r} or '{KIND}:N' with N >= 1 (the N-th submission)")
    return int(count) if count else 1


def check_device(device_info: dict, buffer_device_address: bool) -> None:
    """Refuse a device on which the fault would not be a clean device loss."""
    if device_info["type"] == "CPU":
        raise ConfigError(
            f"{ENV}: {device_info['name']!r} is a CPU device, where the faulting shader would crash this process "
            "instead of losing the device; fault injection needs a GPU"
        )
    if not buffer_device_address:
        raise ConfigError(f"{ENV}: {device_info['name']!r} lacks bufferDeviceAddress, which the faulting shader needs")


def arm(ctx, after: int = 1) -> None:
    """Fault ahead of the `after`-th submission from now on `ctx` (a context made with $HYBRID_FAULT_INJECTION set:
    a test arms it once its set-up has run, as set-up submits a varying number of uploads)."""
    root = ctx.root
    if root._fault is None:
        raise ConfigError(f"fault injection is not enabled on this device (create it with {ENV} set)")
    root._fault.remaining = after


class FaultInjector:
    """The faulting dispatch, recorded once (its own pipeline: faults.py sits below engine.vk.pipelines), and the
    count of submissions until it goes ahead of one."""

    def __init__(self, ctx, ordinal: int):
        self.remaining = ordinal
        dev = ctx.device
        code = (SHADERS_DIR / "spv" / f"{SHADER}.spv").read_bytes()
        module = vk.vkCreateShaderModule(dev, vk.VkShaderModuleCreateInfo(codeSize=len(code), pCode=code), None)
        push = vk.VkPushConstantRange(stageFlags=vk.VK_SHADER_STAGE_COMPUTE_BIT, offset=0, size=8)
        layout = vk.vkCreatePipelineLayout(
            dev, vk.VkPipelineLayoutCreateInfo(pushConstantRangeCount=1, pPushConstantRanges=[push]), None
        )
        ctx.defer_destroy(vk.vkDestroyPipelineLayout, dev, layout, None)
        stage = vk.VkPipelineShaderStageCreateInfo(stage=vk.VK_SHADER_STAGE_COMPUTE_BIT, module=module, pName="main")
        info = vk.VkComputePipelineCreateInfo(stage=stage, layout=layout)
        pipeline = vk.vkCreateComputePipelines(dev, None, 1, [info], None)[0]
        vk.vkDestroyShaderModule(dev, module, None)
        ctx.defer_destroy(vk.vkDestroyPipeline, dev, pipeline, None)

        self.cmd = ctx.allocate_command_buffer()
        vk.vkBeginCommandBuffer(self.cmd, vk.VkCommandBufferBeginInfo())
        vk.vkCmdBindPipeline(self.cmd, vk.VK_PIPELINE_BIND_POINT_COMPUTE, pipeline)
        address = vk.ffi.new("char[]", UNMAPPED.to_bytes(8, "little"))  # uvec2: the low word first
        vk.vkCmdPushConstants(self.cmd, layout, vk.VK_SHADER_STAGE_COMPUTE_BIT, 0, 8, address)
        vk.vkCmdDispatch(self.cmd, GROUPS, 1, 1)
        vk.vkEndCommandBuffer(self.cmd)

    def due(self) -> bool:
        """Counts a submission (Context.submit, under its lock): is this the one to put the fault ahead of?"""
        self.remaining -= 1
        return self.remaining == 0
