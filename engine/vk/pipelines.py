"""Descriptor sets, shader modules, compute and graphics pipelines, timestamp queries.

Pipelines can be rebuilt in place from new SPIR-V (hot reload): the new pipeline is made first and
only swapped in when that succeeded, so a bad shader leaves the last good pipeline running.
"""

from __future__ import annotations

import hashlib
import struct
import threading

import numpy as np
import vulkan as vk

from ..errors import ShaderError, VulkanError
from .context import Context
from .reflect import Binding

_vkGetQueryPoolResults = vk.lib.vkGetQueryPoolResults

SB = vk.VK_DESCRIPTOR_TYPE_STORAGE_BUFFER
UB = vk.VK_DESCRIPTOR_TYPE_UNIFORM_BUFFER
SI = vk.VK_DESCRIPTOR_TYPE_STORAGE_IMAGE
CIS = vk.VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER
UTB = vk.VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER
STB = vk.VK_DESCRIPTOR_TYPE_STORAGE_TEXEL_BUFFER
ALL = vk.VK_SHADER_STAGE_ALL
# GraphicsPipeline's `cull`
CULL_NONE, CULL_BACK, CULL_FRONT = vk.VK_CULL_MODE_NONE, vk.VK_CULL_MODE_BACK_BIT, vk.VK_CULL_MODE_FRONT_BIT
WHOLE_SIZE = 0xFFFFFFFFFFFFFFFF  # VK_WHOLE_SIZE (the binding exposes it as -1)


class DescriptorSet:
    """One set layout + its own pool + one set. `bindings`: reflected `Binding`s (engine.vk.reflect), bound by name
    with `bind`, or (binding, type[, count]) tuples, bound by number with `buffer` / `image` / `texel_buffer`."""

    def __init__(self, ctx: Context, bindings, stages=ALL):
        self.ctx = ctx
        self.types = {}
        self.numbers: dict[str, int] = {}  # name -> binding number (reflected bindings)
        self.kinds: dict[str, str] = {}
        entries, signature = [], []
        sizes: dict[int, int] = {}
        for b in bindings:
            if isinstance(b, Binding):
                binding, dtype, count = b.binding, b.descriptor_type, max(b.count, 1)
                self.numbers[b.name], self.kinds[b.name] = b.binding, b.kind
            else:
                binding, dtype, count = (b + (1,))[:3]
            self.types[binding] = dtype
            signature.append((binding, dtype, count, stages))
            entries.append(
                vk.VkDescriptorSetLayoutBinding(
                    binding=binding, descriptorType=dtype, descriptorCount=count, stageFlags=stages
                )
            )
            sizes[dtype] = sizes.get(dtype, 0) + count
        self.signature = tuple(sorted(signature))  # what makes two set layouts "identically defined"
        dev = ctx.device
        self.layout = vk.vkCreateDescriptorSetLayout(
            dev, vk.VkDescriptorSetLayoutCreateInfo(bindingCount=len(entries), pBindings=entries), None
        )
        pool_sizes = [vk.VkDescriptorPoolSize(type=t, descriptorCount=n) for t, n in sizes.items()]
        self.pool = vk.vkCreateDescriptorPool(
            dev, vk.VkDescriptorPoolCreateInfo(maxSets=1, poolSizeCount=len(pool_sizes), pPoolSizes=pool_sizes), None
        )
        self.handle = vk.vkAllocateDescriptorSets(
            dev,
            vk.VkDescriptorSetAllocateInfo(descriptorPool=self.pool, descriptorSetCount=1, pSetLayouts=[self.layout]),
        )[0]
        ctx.defer_destroy(vk.vkDestroyDescriptorSetLayout, dev, self.layout, None)
        ctx.defer_destroy(vk.vkDestroyDescriptorPool, dev, self.pool, None)

    def bind(self, name: str, obj, sampler=None, element: int = 0):
        """Bind a Buffer, BufferView or Image to the binding the shader calls `name`, as the shader declares it."""
        binding = self.numbers.get(name)
        if binding is None:
            raise ShaderError(f"no binding named {name!r} in this set (it has: {', '.join(self.numbers)})")
        kind = self.kinds[name]
        if kind in ("uniform", "buffer"):
            return self.buffer(binding, obj)
        if kind in ("uniform_texel", "storage_texel"):
            return self.texel_buffer(binding, obj)
        layout = vk.VK_IMAGE_LAYOUT_GENERAL if kind == "image" else vk.VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL
        return self.image(binding, obj, layout=layout, sampler=sampler, element=element)

    def buffer(self, binding, buf, offset=0, size=None):
        info = vk.VkDescriptorBufferInfo(buffer=buf.handle, offset=offset, range=WHOLE_SIZE if size is None else size)
        vk.vkUpdateDescriptorSets(
            self.ctx.device,
            1,
            [
                vk.VkWriteDescriptorSet(
                    dstSet=self.handle,
                    dstBinding=binding,
                    descriptorCount=1,
                    descriptorType=self.types[binding],
                    pBufferInfo=[info],
                )
            ],
            0,
            None,
        )
        return self

    def texel_buffer(self, binding, view):
        """Bind a BufferView as the binding's type: a uniform texel buffer (`usamplerBuffer` / `samplerBuffer` in GLSL)
        or a storage texel buffer (`uimageBuffer` / `imageBuffer`)."""
        vk.vkUpdateDescriptorSets(
            self.ctx.device,
            1,
            [
                vk.VkWriteDescriptorSet(
                    dstSet=self.handle,
                    dstBinding=binding,
                    descriptorCount=1,
                    descriptorType=self.types[binding],
                    pTexelBufferView=[view.handle],
                )
            ],
            0,
            None,
        )
        return self

    def image(self, binding, image, layout=vk.VK_IMAGE_LAYOUT_GENERAL, sampler=None, element=0):
        info = vk.VkDescriptorImageInfo(
            sampler=sampler.handle if sampler else vk.VK_NULL_HANDLE, imageView=image.view, imageLayout=layout
        )
        vk.vkUpdateDescriptorSets(
            self.ctx.device,
            1,
            [
                vk.VkWriteDescriptorSet(
                    dstSet=self.handle,
                    dstBinding=binding,
                    dstArrayElement=element,
                    descriptorCount=1,
                    descriptorType=self.types[binding],
                    pImageInfo=[info],
                )
            ],
            0,
            None,
        )
        return self


def _shader_module(ctx, spirv: bytes, name: str):
    if len(spirv) % 4 or spirv[:4] != b"\x03\x02\x23\x07":
        raise ShaderError(f"{name}: not a SPIR-V binary")
    try:
        return vk.vkCreateShaderModule(ctx.device, vk.VkShaderModuleCreateInfo(codeSize=len(spirv), pCode=spirv), None)
    except vk.VkError as exc:
        raise ShaderError(f"{name}: vkCreateShaderModule failed ({type(exc).__name__})") from None


def _spec_words(spec: dict | None) -> list:
    """[(constant_id, its 4 bytes)] from {constant_id: int|float|bool}, as the shader receives them."""
    return [
        (cid, struct.pack("<f", value) if isinstance(value, float) else struct.pack("<I", int(value) & 0xFFFFFFFF))
        for cid, value in sorted((spec or {}).items())
    ]


def _specialization(spec: dict | None):
    """VkSpecializationInfo from {constant_id: int|float|bool}; returns (info, keepalive)."""
    if not spec:
        return None, None
    words = _spec_words(spec)
    entries = [vk.VkSpecializationMapEntry(constantID=cid, offset=4 * i, size=4) for i, (cid, _) in enumerate(words)]
    data = b"".join(raw for _, raw in words)
    buf = vk.ffi.new("char[]", data)
    info = vk.VkSpecializationInfo(mapEntryCount=len(entries), pMapEntries=entries, dataSize=len(data), pData=buf)
    return info, (entries, buf)


def _cache(ctx):
    """The device's VkPipelineCache (engine/vk/pipeline_cache.py), or none."""
    cache = getattr(ctx.root, "pipeline_cache", None)
    return cache.handle if cache is not None else vk.VK_NULL_HANDLE


def _digest(*blobs) -> str:
    return hashlib.sha256(b"".join(hashlib.sha256(b).digest() for b in blobs)).hexdigest()


def _memoized(ctx, key, make):
    """(pipeline, shared): the device's pipeline for `key`, made by `make()` the first time (kept until the device
    closes), so Renderers and Tracers on one device compile each shader and specialization once; `key` None: a
    pipeline of the caller's own."""
    if key is None:
        return make(), False
    root = ctx.root
    with root.memo_lock:
        hit = root.memo.get(key)
    if hit is not None:
        return hit, True
    new = make()
    with root.memo_lock:
        hit = root.memo.get(key)
        if hit is None:
            root.memo[key] = new
            root.defer_destroy(vk.vkDestroyPipeline, root.device, new, None)
    if hit is not None:  # another thread made it meanwhile
        vk.vkDestroyPipeline(root.device, new, None)
        return hit, True
    return new, True


class _Pipeline:
    """Shared bits: a pipeline layout, and a handle made on first use (so a pass specialized after it was made
    compiles once) that `rebuild` can swap.

    Made on first use, the pipeline is the device's for its shaders, constants and layout definition (pipelines
    bound with identically defined layouts are compatible), shared with every other user of the device; made by
    `rebuild` (hot reload), it is this object's own."""

    bind_point = vk.VK_PIPELINE_BIND_POINT_COMPUTE

    def __init__(self, ctx: Context, set_layouts, push_size: int):
        self.ctx = ctx
        self.push_size = push_size
        ranges = [vk.VkPushConstantRange(stageFlags=ALL, offset=0, size=push_size)] if push_size else []
        self.layout = vk.vkCreatePipelineLayout(
            ctx.device,
            vk.VkPipelineLayoutCreateInfo(
                setLayoutCount=len(set_layouts),
                pSetLayouts=[s.layout if hasattr(s, "layout") else s for s in set_layouts],
                pushConstantRangeCount=len(ranges),
                pPushConstantRanges=ranges or None,
            ),
            None,
        )
        # the layout's definition, where every set is a DescriptorSet (a raw handle: no shared pipelines)
        signatures = [getattr(s, "signature", None) for s in set_layouts]
        self._layout_key = None if None in signatures else (tuple(signatures), push_size)
        self._handle = None
        self._shared = False
        self._source: tuple | None = None  # the shader(s) of the pipeline to make on first use
        self._make_lock = threading.Lock()  # one first use makes it (Tracers share pipelines across threads)
        ctx.defer_destroy(self.destroy)

    def _key(self, *source):
        """What identifies the pipeline `source` makes (None: not shareable)."""
        return None

    @property
    def handle(self):
        """The VkPipeline, made now if it was not yet."""
        if self._handle is None and self._source is not None:
            with self._make_lock:
                if self._handle is None:
                    source = self._source
                    self._handle, self._shared = _memoized(self.ctx, self._key(*source), lambda: self._create(*source))
        return self._handle

    def defer(self, *source):
        """Make the pipeline from `source` on first use (dropping the current one)."""
        self._drop()
        self._source = source

    def rebuild(self, *source):
        """Make a new pipeline now; swap it in only when that succeeded (raises ShaderError otherwise)."""
        new = self._create(*source)
        self._drop()
        self._handle, self._shared, self._source = new, False, source

    def _drop(self):
        if self._handle is not None:
            if not self._shared:  # (a shared one stays the device's)
                self.ctx.wait_idle()
                vk.vkDestroyPipeline(self.ctx.device, self._handle, None)
            self._handle = None

    def bind(self, cmd, sets=(), push: bytes | np.ndarray | None = None):
        vk.vkCmdBindPipeline(cmd, self.bind_point, self.handle)
        if sets:
            vk.vkCmdBindDescriptorSets(
                cmd, self.bind_point, self.layout, 0, len(sets), [s.handle for s in sets], 0, None
            )
        if push is not None:
            raw = push.tobytes() if isinstance(push, np.ndarray) else bytes(push)
            vk.vkCmdPushConstants(cmd, self.layout, ALL, 0, len(raw), vk.ffi.new("char[]", raw))

    def destroy(self):
        self._source = None
        if self._handle is not None and not self._shared:
            vk.vkDestroyPipeline(self.ctx.device, self._handle, None)
        self._handle = None
        if self.layout is not None:
            vk.vkDestroyPipelineLayout(self.ctx.device, self.layout, None)
            self.layout = None


class ComputePipeline(_Pipeline):
    def __init__(self, ctx: Context, spirv: bytes, set_layouts, push_size: int = 0, spec=None, name="compute"):
        super().__init__(ctx, set_layouts, push_size)
        self.name, self.spec = name, spec
        self.defer(spirv)

    def _key(self, spirv: bytes):
        if self._layout_key is None:
            return None
        return ("compute", self._layout_key, _digest(spirv), tuple(_spec_words(self.spec)))

    def _create(self, spirv: bytes):
        module = _shader_module(self.ctx, spirv, self.name)
        try:
            spec_info, keep = _specialization(self.spec)
            stage = vk.VkPipelineShaderStageCreateInfo(
                stage=vk.VK_SHADER_STAGE_COMPUTE_BIT, module=module, pName="main", pSpecializationInfo=spec_info
            )
            info = vk.VkComputePipelineCreateInfo(stage=stage, layout=self.layout)
            try:
                return vk.vkCreateComputePipelines(self.ctx.device, _cache(self.ctx), 1, [info], None)[0]
            except vk.VkError as exc:
                raise ShaderError(f"{self.name}: compute pipeline creation failed ({type(exc).__name__})") from None
        finally:
            vk.vkDestroyShaderModule(self.ctx.device, module, None)

    def specialize(self, spirv: bytes, spec: dict):
        """Re-create the pipeline from `spirv` with these specialization constants, where they differ from the
        current ones (on first use, if it was not made yet); if that fails the old pipeline and its constants stay
        (the next call tries again)."""
        if spec == self.spec:
            return
        old, self.spec = self.spec, dict(spec)
        if self._handle is None:
            self.defer(spirv)
            return
        try:
            self.rebuild(spirv)
        except BaseException:
            self.spec = old
            raise

    def dispatch(self, cmd, sets, gx, gy=1, gz=1, push=None):
        self.bind(cmd, sets, push)
        vk.vkCmdDispatch(cmd, gx, gy, gz)


class GraphicsPipeline(_Pipeline):
    """A triangle-list pipeline for dynamic rendering (no render pass objects)."""

    bind_point = vk.VK_PIPELINE_BIND_POINT_GRAPHICS

    def __init__(
        self,
        ctx,
        vert: bytes,
        frag: bytes,
        set_layouts,
        *,
        color_formats,
        depth_format=None,
        vertex_stride=0,
        attributes=(),
        push_size=0,
        cull=vk.VK_CULL_MODE_NONE,
        depth_compare=vk.VK_COMPARE_OP_GREATER,
        spec=None,
        name="graphics",
    ):
        """`spec`: {constant id: value}, the specialization constants of both stages."""
        super().__init__(ctx, set_layouts, push_size)
        self.name, self.spec = name, spec
        self.cfg = dict(
            color_formats=list(color_formats),
            depth_format=depth_format,
            vertex_stride=vertex_stride,
            attributes=list(attributes),
            cull=cull,
            depth_compare=depth_compare,
        )
        self.defer(vert, frag)

    def _key(self, vert: bytes, frag: bytes):
        if self._layout_key is None:
            return None
        c = self.cfg
        cfg = (
            tuple(c["color_formats"]),
            c["depth_format"],
            c["vertex_stride"],
            tuple(map(tuple, c["attributes"])),
            c["cull"],
            c["depth_compare"],
        )
        return ("graphics", self._layout_key, _digest(vert, frag), tuple(_spec_words(self.spec)), cfg)

    def _create(self, vert: bytes, frag: bytes):
        c = self.cfg
        dev = self.ctx.device
        vmod = _shader_module(self.ctx, vert, self.name + ".vert")
        try:
            fmod = _shader_module(self.ctx, frag, self.name + ".frag")
        except ShaderError:
            vk.vkDestroyShaderModule(dev, vmod, None)
            raise
        try:
            spec_info, keep = _specialization(self.spec)
            stages = [
                vk.VkPipelineShaderStageCreateInfo(
                    stage=vk.VK_SHADER_STAGE_VERTEX_BIT, module=vmod, pName="main", pSpecializationInfo=spec_info
                ),
                vk.VkPipelineShaderStageCreateInfo(
                    stage=vk.VK_SHADER_STAGE_FRAGMENT_BIT, module=fmod, pName="main", pSpecializationInfo=spec_info
                ),
            ]
            vbind = [
                vk.VkVertexInputBindingDescription(
                    binding=0, stride=c["vertex_stride"], inputRate=vk.VK_VERTEX_INPUT_RATE_VERTEX
                )
            ]
            vattr = [
                vk.VkVertexInputAttributeDescription(location=loc, binding=0, format=fmt, offset=off)
                for loc, fmt, off in c["attributes"]
            ]
            vin = vk.VkPipelineVertexInputStateCreateInfo(
                vertexBindingDescriptionCount=1 if vattr else 0,
                pVertexBindingDescriptions=vbind if vattr else None,
                vertexAttributeDescriptionCount=len(vattr),
                pVertexAttributeDescriptions=vattr or None,
            )
            ia = vk.VkPipelineInputAssemblyStateCreateInfo(topology=vk.VK_PRIMITIVE_TOPOLOGY_TRIANGLE_LIST)
            vp = vk.VkPipelineViewportStateCreateInfo(viewportCount=1, scissorCount=1)
            rs = vk.VkPipelineRasterizationStateCreateInfo(
                polygonMode=vk.VK_POLYGON_MODE_FILL,
                cullMode=c["cull"],
                frontFace=vk.VK_FRONT_FACE_COUNTER_CLOCKWISE,
                lineWidth=1.0,
            )
            ms = vk.VkPipelineMultisampleStateCreateInfo(rasterizationSamples=vk.VK_SAMPLE_COUNT_1_BIT)
            ds = vk.VkPipelineDepthStencilStateCreateInfo(
                depthTestEnable=c["depth_format"] is not None,
                depthWriteEnable=c["depth_format"] is not None,
                depthCompareOp=c["depth_compare"],
            )
            mask = (
                vk.VK_COLOR_COMPONENT_R_BIT
                | vk.VK_COLOR_COMPONENT_G_BIT
                | vk.VK_COLOR_COMPONENT_B_BIT
                | vk.VK_COLOR_COMPONENT_A_BIT
            )
            blends = [
                vk.VkPipelineColorBlendAttachmentState(blendEnable=vk.VK_FALSE, colorWriteMask=mask)
                for _ in c["color_formats"]
            ]
            cb = vk.VkPipelineColorBlendStateCreateInfo(attachmentCount=len(blends), pAttachments=blends)
            dyn_states = [vk.VK_DYNAMIC_STATE_VIEWPORT, vk.VK_DYNAMIC_STATE_SCISSOR]
            dyn = vk.VkPipelineDynamicStateCreateInfo(dynamicStateCount=2, pDynamicStates=dyn_states)
            rendering = vk.VkPipelineRenderingCreateInfo(
                colorAttachmentCount=len(c["color_formats"]),
                pColorAttachmentFormats=c["color_formats"],
                depthAttachmentFormat=c["depth_format"] or vk.VK_FORMAT_UNDEFINED,
            )
            info = vk.VkGraphicsPipelineCreateInfo(
                pNext=rendering,
                stageCount=2,
                pStages=stages,
                pVertexInputState=vin,
                pInputAssemblyState=ia,
                pViewportState=vp,
                pRasterizationState=rs,
                pMultisampleState=ms,
                pDepthStencilState=ds,
                pColorBlendState=cb,
                pDynamicState=dyn,
                layout=self.layout,
            )
            try:
                return vk.vkCreateGraphicsPipelines(dev, _cache(self.ctx), 1, [info], None)[0]
            except vk.VkError as exc:
                raise ShaderError(f"{self.name}: graphics pipeline creation failed ({type(exc).__name__})") from None
        finally:
            vk.vkDestroyShaderModule(dev, vmod, None)
            vk.vkDestroyShaderModule(dev, fmod, None)


class Timestamps:
    """GPU timestamps around named passes: `begin(cmd)`, `mark(cmd, name)` after each pass, `read()`.

    Every timestamp is followed by a second one into a scratch query. lavapipe (llvmpipe) bins a timestamp into
    its current render scene and only writes it when that scene is flushed, which a later BOTTOM_OF_PIPE timestamp
    does; compute work, which llvmpipe runs at once, would otherwise land in the wrong pass. The scratch write
    makes that flush happen right after each real timestamp. On other devices it is one more (ignored) query.
    """

    def __init__(self, ctx: Context, capacity: int = 32):
        self.ctx = ctx
        self.capacity = capacity
        self.names: list[str] = []
        self._ticks = None
        self.enabled = ctx.timestamp_bits > 0 and ctx.timestamp_period_ns > 0
        self.pool = vk.vkCreateQueryPool(
            ctx.device, vk.VkQueryPoolCreateInfo(queryType=vk.VK_QUERY_TYPE_TIMESTAMP, queryCount=2 * capacity), None
        )
        ctx.defer_destroy(vk.vkDestroyQueryPool, ctx.device, self.pool, None)

    def _write(self, cmd, stage, slot):
        vk.vkCmdWriteTimestamp(cmd, stage, self.pool, slot)
        vk.vkCmdWriteTimestamp(cmd, vk.VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, self.pool, self.capacity + slot)

    def begin(self, cmd):
        self.names = []
        vk.vkCmdResetQueryPool(cmd, self.pool, 0, 2 * self.capacity)
        self._write(cmd, vk.VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, 0)

    def mark(self, cmd, name: str):
        self.names.append(name)
        self._write(cmd, vk.VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, len(self.names))

    def read(self, names=None) -> dict[str, float]:
        """GPU ms per pass of the last submitted recording whose marks were `names` (default: the latest)."""
        names = self.names if names is None else names
        n = len(names) + 1
        if not self.enabled or n < 2:
            return {}
        if self._ticks is None:
            self._ticks = vk.ffi.new("uint64_t[]", self.capacity)
        ticks = self._ticks  # (the loader's entry point, without the wrapper's conversions: a per-query cost)
        result = _vkGetQueryPoolResults(
            self.ctx.device, self.pool, 0, n, n * 8, ticks, 8, vk.VK_QUERY_RESULT_64_BIT | vk.VK_QUERY_RESULT_WAIT_BIT
        )
        if result != vk.VK_SUCCESS:
            raise VulkanError(f"vkGetQueryPoolResults failed ({result})")
        scale = self.ctx.timestamp_period_ns * 1e-6
        out: dict[str, float] = {}
        for i, name in enumerate(names):
            out[name] = out.get(name, 0.0) + (ticks[i + 1] - ticks[i]) * scale
        return out
