"""Recording a command buffer from declared accesses: the barriers between steps are derived, not placed by hand.

    rec = Recorder(ctx, timestamps)          # begins a command buffer and a timestamp sequence
    rec.dispatch(pipeline, sets, groups, reads=[a], writes=[b])
    rec.copy(b, c)                           # a transfer: reads b, writes c
    rec.mark("pass name")                    # a GPU timestamp
    cmd = rec.finish()

Every step names the resources (Buffer / Image objects) it reads and writes. `Hazards` remembers, per resource,
the last write and the reads since, and before a step emits one memory barrier covering every read-after-write,
write-after-write and write-after-read hazard the step has with earlier steps. Images used by compute and
transfer stay in the GENERAL layout, so memory barriers suffice; passes that change an image's layout (the
raster) do that themselves with `image_barrier` and declare the accesses around it.
"""

from __future__ import annotations

import vulkan as vk

from .resources import Buffer, Image, image_barrier, memory_barrier

COMPUTE = vk.VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT
TRANSFER = vk.VK_PIPELINE_STAGE_TRANSFER_BIT
HOST = vk.VK_PIPELINE_STAGE_HOST_BIT
GRAPHICS = vk.VK_PIPELINE_STAGE_VERTEX_SHADER_BIT | vk.VK_PIPELINE_STAGE_FRAGMENT_SHADER_BIT  # the raster's shaders
INDIRECT = vk.VK_PIPELINE_STAGE_DRAW_INDIRECT_BIT  # indirect draw commands
READ = {
    COMPUTE: vk.VK_ACCESS_SHADER_READ_BIT,
    TRANSFER: vk.VK_ACCESS_TRANSFER_READ_BIT,
    HOST: vk.VK_ACCESS_HOST_READ_BIT,
    GRAPHICS: vk.VK_ACCESS_SHADER_READ_BIT,
    INDIRECT: vk.VK_ACCESS_INDIRECT_COMMAND_READ_BIT,
}
WRITE = {
    COMPUTE: vk.VK_ACCESS_SHADER_WRITE_BIT,
    TRANSFER: vk.VK_ACCESS_TRANSFER_WRITE_BIT,
    HOST: vk.VK_ACCESS_HOST_WRITE_BIT,
}
WHOLE_SIZE = 0xFFFFFFFFFFFFFFFF
ONE_F32 = 0x3F800000  # the bit pattern of 1.0f, for fill()
DRAW_RECORD = 20  # bytes of a VkDrawIndexedIndirectCommand
_EVERYTHING = COMPUTE | TRANSFER
_ANY_ACCESS = (
    vk.VK_ACCESS_SHADER_READ_BIT
    | vk.VK_ACCESS_SHADER_WRITE_BIT
    | vk.VK_ACCESS_TRANSFER_READ_BIT
    | vk.VK_ACCESS_TRANSFER_WRITE_BIT
)


class _State:
    __slots__ = ("write_stage", "visible", "readers")

    def __init__(self):
        self.write_stage = 0  # stage of the last write (0: none since the recording began)
        self.visible = 0  # stages the last write has been made visible to
        self.readers = 0  # stages that read it since the last write


class Hazards:
    """Per-resource access history of one recording, and the barrier a new step needs."""

    def __init__(self):
        self.state: dict[int, _State] = {}
        self.barriers = 0  # how many were emitted (tests read it)

    def use(self, cmd, reads=(), writes=(), stage=COMPUTE):
        src_stage = src_access = dst_access = 0
        for res in reads:
            st = self.state.get(id(res))
            if st is not None and st.write_stage and not st.visible & stage:
                src_stage |= st.write_stage
                src_access |= WRITE[st.write_stage]
                dst_access |= READ[stage]
        for res in writes:
            st = self.state.get(id(res))
            if st is None:
                continue
            if st.write_stage and not st.visible & stage:
                src_stage |= st.write_stage
                src_access |= WRITE[st.write_stage]
                dst_access |= WRITE[stage]
            src_stage |= st.readers  # write after read: an execution dependency
        if src_stage:
            memory_barrier(cmd, src_stage, stage, src_access, dst_access)
            self.barriers += 1
        for res in reads:
            st = self.state.setdefault(id(res), _State())
            st.readers |= stage
            if st.write_stage:
                st.visible |= stage
        for res in writes:
            st = self.state.setdefault(id(res), _State())
            st.write_stage, st.visible, st.readers = stage, 0, 0


class Recorder:
    """One command buffer being recorded, with derived barriers and named GPU timestamps."""

    def __init__(self, ctx, timestamps=None, after_earlier: bool = True):
        """`after_earlier=False`: no barrier against earlier submissions, for a recording whose resources no other
        submission in flight touches (a Tracer's stream slot, reused only after its fence), so that it may overlap
        them on the device."""
        self.ctx = ctx
        self.cmd = ctx.allocate_command_buffer()
        self.hazards = Hazards()
        self.timestamps = timestamps
        vk.vkBeginCommandBuffer(self.cmd, vk.VkCommandBufferBeginInfo())
        if timestamps is not None:
            timestamps.begin(self.cmd)
        # What earlier submissions on the queue did to the same resources comes before anything recorded here.
        if after_earlier:
            memory_barrier(
                self.cmd,
                _EVERYTHING | vk.VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT,
                _EVERYTHING,
                _ANY_ACCESS | vk.VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT,
                _ANY_ACCESS,
            )

    def use(self, reads=(), writes=(), stage=COMPUTE):
        """Declare a step's accesses (emitting the barrier it needs) without recording the step itself."""
        self.hazards.use(self.cmd, reads, writes, stage)

    def dispatch(self, pipeline, sets, groups, push=None, reads=(), writes=()):
        self.use(reads, writes)
        pipeline.dispatch(self.cmd, sets, *groups, push=push)

    def dispatch_indirect(self, pipeline, sets, args: Buffer, reads=(), writes=()):
        self.use(reads=[args], stage=INDIRECT)  # (args a shader wrote: visible to the indirect command read)
        self.use(list(reads) + [args], writes)
        pipeline.bind(self.cmd, sets)
        vk.vkCmdDispatchIndirect(self.cmd, args.handle, 0)

    def fill(self, buf: Buffer, word: int, size: int = WHOLE_SIZE):
        """Every 4-byte word of `buf` (or its first `size` bytes) set to `word` (ONE_F32 for 1.0)."""
        self.use(writes=[buf], stage=TRANSFER)
        vk.vkCmdFillBuffer(self.cmd, buf.handle, 0, size, word)

    def copy(self, src: Buffer, dst: Buffer, regions=None, declared: bool = False):
        """Buffer to buffer: `regions` of (src offset, dst offset, size), default the whole of the smaller one.
        `declared`: the caller already declared this copy's accesses (`use`), e.g. for copies into disjoint parts
        of one buffer that need no barrier between them."""
        if not declared:
            self.use(reads=[src], writes=[dst], stage=TRANSFER)
        regions = regions or [(0, 0, min(src.size, dst.size))]
        vk.vkCmdCopyBuffer(
            self.cmd, src.handle, dst.handle, len(regions), [vk.VkBufferCopy(s, d, n) for s, d, n in regions]
        )

    def copy_image(self, src: Image, dst: Image):
        """A whole GENERAL-layout image into another of the same size and format."""
        self.use(reads=[src], writes=[dst], stage=TRANSFER)
        sub = vk.VkImageSubresourceLayers(vk.VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1)
        region = vk.VkImageCopy(
            srcSubresource=sub,
            srcOffset=vk.VkOffset3D(0, 0, 0),
            dstSubresource=sub,
            dstOffset=vk.VkOffset3D(0, 0, 0),
            extent=vk.VkExtent3D(src.width, src.height, 1),
        )
        G = vk.VK_IMAGE_LAYOUT_GENERAL
        vk.vkCmdCopyImage(self.cmd, src.handle, G, dst.handle, G, 1, [region])

    def image_to_buffer(self, src: Image, dst: Buffer, offset: int, declared: bool = False):
        """A whole GENERAL-layout image into `dst` at `offset`, tightly packed (`declared`: as for `copy`)."""
        if not declared:
            self.use(reads=[src], writes=[dst], stage=TRANSFER)
        sub = vk.VkImageSubresourceLayers(vk.VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1)
        region = vk.VkBufferImageCopy(
            bufferOffset=offset,
            bufferRowLength=0,
            bufferImageHeight=0,
            imageSubresource=sub,
            imageOffset=vk.VkOffset3D(0, 0, 0),
            imageExtent=vk.VkExtent3D(src.width, src.height, 1),
        )
        vk.vkCmdCopyImageToBuffer(self.cmd, src.handle, vk.VK_IMAGE_LAYOUT_GENERAL, dst.handle, 1, [region])

    def raster(
        self,
        pipeline,
        sets,
        color: Image,
        depth: Image,
        vertices: Buffer,
        indices: Buffer,
        draws,
        reads=(),
        more=(),
        indirect: Buffer | None = None,
        keep_depth: bool = False,
    ):
        """Indexed draws into `color` (kept: loaded and stored; GENERAL before and after) with a cleared reversed-Z
        `depth`. `draws`: (first index, index count, instance count, first instance, push-constant bytes), instanced
        indexed draws (gl_InstanceIndex counts from the first instance; no push constants where the bytes are
        empty); with `indirect` (VkDrawIndexedIndirectCommand records), (record index, push-constant bytes) instead:
        each an indirect draw of that record. `more`: further (pipeline, sets, draws) drawn after them in the same
        rendering. `reads`: buffers the vertex and fragment shaders read. Afterwards `color` counts as written by a
        compute-stage step, visible to compute and transfer; with `keep_depth`, so does `depth` (stored, then in
        the SHADER_READ_ONLY_OPTIMAL layout for compute shaders to read; it needs SAMPLED usage)."""
        self.use(reads=reads, stage=GRAPHICS)
        if indirect is not None:
            self.use(reads=[indirect], stage=INDIRECT)
        cmd, w, h = self.cmd, color.width, color.height
        CA, GENERAL = vk.VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL, vk.VK_IMAGE_LAYOUT_GENERAL
        OUT = vk.VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT
        RW = vk.VK_ACCESS_COLOR_ATTACHMENT_READ_BIT | vk.VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT
        image_barrier(cmd, color, GENERAL, CA, _EVERYTHING, OUT, _ANY_ACCESS, RW)
        DEPTH = vk.VK_IMAGE_LAYOUT_DEPTH_ATTACHMENT_OPTIMAL
        LATE = vk.VK_PIPELINE_STAGE_LATE_FRAGMENT_TESTS_BIT
        # (after compute shaders of earlier frames that read a kept depth)
        image_barrier(
            cmd,
            depth,
            vk.VK_IMAGE_LAYOUT_UNDEFINED,
            DEPTH,
            LATE | COMPUTE,
            vk.VK_PIPELINE_STAGE_EARLY_FRAGMENT_TESTS_BIT,
            vk.VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT,
            vk.VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_READ_BIT | vk.VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT,
        )
        color_info = vk.VkRenderingAttachmentInfo(
            imageView=color.view,
            imageLayout=CA,
            loadOp=vk.VK_ATTACHMENT_LOAD_OP_LOAD,
            storeOp=vk.VK_ATTACHMENT_STORE_OP_STORE,
        )
        depth_info = vk.VkRenderingAttachmentInfo(
            imageView=depth.view,
            imageLayout=DEPTH,
            loadOp=vk.VK_ATTACHMENT_LOAD_OP_CLEAR,
            storeOp=vk.VK_ATTACHMENT_STORE_OP_STORE if keep_depth else vk.VK_ATTACHMENT_STORE_OP_DONT_CARE,
            clearValue=vk.VkClearValue(depthStencil=vk.VkClearDepthStencilValue(depth=0.0, stencil=0)),
        )
        area = vk.VkRect2D(offset=vk.VkOffset2D(0, 0), extent=vk.VkExtent2D(w, h))
        vk.vkCmdBeginRendering(
            cmd,
            vk.VkRenderingInfo(
                renderArea=area,
                layerCount=1,
                colorAttachmentCount=1,
                pColorAttachments=[color_info],
                pDepthAttachment=depth_info,
            ),
        )
        vk.vkCmdSetViewport(cmd, 0, 1, [vk.VkViewport(0, 0, w, h, 0.0, 1.0)])
        vk.vkCmdSetScissor(cmd, 0, 1, [area])
        vk.vkCmdBindVertexBuffers(cmd, 0, 1, [vertices.handle], [0])
        vk.vkCmdBindIndexBuffer(cmd, indices.handle, 0, vk.VK_INDEX_TYPE_UINT32)
        for pipe, pipe_sets, pipe_draws in ((pipeline, sets, draws), *more):
            if not pipe_draws:
                continue
            pipe.bind(cmd, pipe_sets)
            for *draw, push in pipe_draws:
                if push:
                    vk.vkCmdPushConstants(
                        cmd, pipe.layout, vk.VK_SHADER_STAGE_ALL, 0, len(push), vk.ffi.new("char[]", bytes(push))
                    )
                if indirect is not None:
                    vk.vkCmdDrawIndexedIndirect(cmd, indirect.handle, DRAW_RECORD * draw[0], 1, DRAW_RECORD)
                else:
                    first, count, instances, first_instance = draw
                    vk.vkCmdDrawIndexed(cmd, count, instances, first, 0, first_instance)
        vk.vkCmdEndRendering(cmd)
        image_barrier(cmd, color, CA, GENERAL, OUT, _EVERYTHING, vk.VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT, _ANY_ACCESS)
        st = self.hazards.state.setdefault(id(color), _State())
        st.write_stage, st.visible, st.readers = COMPUTE, COMPUTE | TRANSFER, 0
        if keep_depth:
            image_barrier(
                cmd,
                depth,
                DEPTH,
                vk.VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL,
                LATE,
                COMPUTE,
                vk.VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT,
                vk.VK_ACCESS_SHADER_READ_BIT,
            )
            st = self.hazards.state.setdefault(id(depth), _State())
            st.write_stage, st.visible, st.readers = COMPUTE, COMPUTE, 0

    def to_host(self, *resources):
        """Make what earlier steps wrote into `resources` visible to the host (after the fence)."""
        self.use(reads=resources, stage=HOST)

    def to_later(self, *resources):
        """Make what earlier steps wrote visible to every later submission on the queue, whatever stage reads it
        (a recording other command buffers depend on without barriers of their own): every write recorded so far,
        or only those into `resources` when some are named (no barrier when none of them was written)."""
        if not resources or any(self.hazards.state.get(id(r)) is not None for r in resources):
            memory_barrier(
                self.cmd,
                _EVERYTHING,
                vk.VK_PIPELINE_STAGE_ALL_COMMANDS_BIT,
                vk.VK_ACCESS_SHADER_WRITE_BIT | vk.VK_ACCESS_TRANSFER_WRITE_BIT,
                vk.VK_ACCESS_MEMORY_READ_BIT | vk.VK_ACCESS_SHADER_READ_BIT,
            )

    def mark(self, name: str):
        if self.timestamps is not None:
            self.timestamps.mark(self.cmd, name)

    def finish(self):
        vk.vkEndCommandBuffer(self.cmd)
        return self.cmd


def to_general(cmd, image: Image, clear: bool = False):
    """Set-up (a one-shot command buffer): a new colour image into the GENERAL layout, cleared to zero if `clear`
    (which needs the image's COPY_DST usage)."""
    image_barrier(
        cmd,
        image,
        vk.VK_IMAGE_LAYOUT_UNDEFINED,
        vk.VK_IMAGE_LAYOUT_GENERAL,
        vk.VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT,
        TRANSFER,
        0,
        vk.VK_ACCESS_TRANSFER_WRITE_BIT,
    )
    if clear:
        vk.vkCmdClearColorImage(
            cmd, image.handle, vk.VK_IMAGE_LAYOUT_GENERAL, vk.VkClearColorValue(uint32=[0, 0, 0, 0]), 1, [image.range()]
        )


def fill(cmd, buf: Buffer, word: int):
    """Set-up (a one-shot command buffer): every 4-byte word of `buf` set to `word`."""
    vk.vkCmdFillBuffer(cmd, buf.handle, 0, WHOLE_SIZE, word)
