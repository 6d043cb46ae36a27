"""Deliberate device loss and hangs, to test that a lost GPU gives clear errors and that a new device recovers.

`HYBRID_FAULT_INJECTION=KIND[:N]` makes the first (N-th) command buffer submitted on each new Context run after
`fault.comp` (the device then enables bufferDeviceAddress, which the shader declares):
- `device-lost`: a write through a pointer to unmapped GPU memory. A driver answers VK_ERROR_DEVICE_LOST, or its
  queue stalls (the H100 here), which the GPU timeout turns into a loss. Refused on a CPU device (lavapipe): there
  the shader runs in this process and the write would crash it.
- `hang`: an endless loop, on any device: the GPU timeout's case (on lavapipe, a thread spins until the process
  exits).
"""

from __future__ import annotations

import os

import vulkan as vk

from ..data import SHADERS_DIR
from ..errors import ConfigError

ENV = "HYBRID_FAULT_INJECTION"
KINDS = {"device-lost": 0, "hang": 1}  # the shader's mode
SHADER = "fault.comp"
UNMAPPED = 0xDEAD_0000_0000  # far above what a driver maps for a process
GROUPS = 65535  # 64 invocations each, every one faulting (or looping), the most one dispatch of x groups has
NEVER = 0  # with mode 1 the loop's store is guarded by mode == 2 too, so any value will do


def requested() -> tuple[str, int] | None:
    """(kind, the 1-based ordinal of the submission to fault) from $HYBRID_FAULT_INJECTION; None when unset."""
    text = os.environ.get(ENV, "").strip()
    if not text:
        return None
    kind, _, count = text.partition(":")
    if kind not in KINDS or (count and not (count.isdigit() and int(count) >= 1)):
        raise ConfigError(
            f"{ENV}={text!r}: expected one of {', '.join(KINDS)}, optionally ':N' with N >= 1 (the N-th submission)"
        )
    return kind, int(count) if count else 1


def check_device(kind: str, device_info: dict, buffer_device_address: bool) -> None:
    """Refuse a device on which the fault would not be a clean device loss."""
    if kind == "device-lost" and device_info["type"] == "CPU":
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

    def __init__(self, ctx, kind: str, ordinal: int):
        self.remaining = ordinal
        dev = ctx.device
        code = (SHADERS_DIR / "spv" / f"{SHADER}.spv").read_bytes()
        module = vk.vkCreateShaderModule(dev, vk.VkShaderModuleCreateInfo(codeSize=len(code), pCode=code), None)
        push = vk.VkPushConstantRange(stageFlags=vk.VK_SHADER_STAGE_COMPUTE_BIT, offset=0, size=16)
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
        words = UNMAPPED.to_bytes(8, "little") + KINDS[kind].to_bytes(4, "little") + NEVER.to_bytes(4, "little")
        vk.vkCmdPushConstants(self.cmd, layout, vk.VK_SHADER_STAGE_COMPUTE_BIT, 0, 16, vk.ffi.new("char[]", words))
        vk.vkCmdDispatch(self.cmd, GROUPS, 1, 1)
        vk.vkEndCommandBuffer(self.cmd)

    def due(self) -> bool:
        """Counts a submission (Context.submit, under its lock): is this the one to put the fault ahead of?"""
        self.remaining -= 1
        return self.remaining == 0
