"""G-buffer pass: a visibility raster (the id of the visible triangle per pixel) and a compute resolve into world
position + linear depth, normal and albedo.

The raster writes 4 bytes per pixel (R32_UINT: triangle + 1, 0 = background) plus depth; `gbuffer_resolve.comp`
then computes what the rasterizer would have interpolated at each pixel centre from the triangle's vertices
(perspective-correct barycentrics from homogeneous edge functions) and samples the albedo texture with the UV
derivatives of the neighbouring pixels. Writing 44 bytes per pixel from fragments took 3.4 ms of a 1920x1080 frame
on an H200, whose raster units are few; the same bytes from compute cost a small fraction of that.

Vertices are interleaved (position, normal, uv: 32 bytes); triangles are sorted by material and drawn with one
draw per material, the draw's first triangle in a push constant (the triangle id is that + gl_PrimitiveID).
"""
from __future__ import annotations

import logging

import numpy as np
import vulkan as vk

from ..vk import (CIS, SI, UB, UTB, BufferView, ComputePipeline, DescriptorSet, GraphicsPipeline, Sampler,
                  image_barrier, upload_buffer, upload_texture)
from ..vk.resources import INDEX, UNIFORM_TEXEL, VERTEX

MAX_TEXTURES = 16
POSITION_FORMAT = vk.VK_FORMAT_R32G32B32A32_SFLOAT
NORMAL_FORMAT = vk.VK_FORMAT_R32G32B32A32_SFLOAT
ALBEDO_FORMAT = vk.VK_FORMAT_R16G16B16A16_SFLOAT
VISIBILITY_FORMAT = vk.VK_FORMAT_R32_UINT
DEPTH_FORMAT = vk.VK_FORMAT_D32_SFLOAT
F3 = vk.VK_FORMAT_R32G32B32_SFLOAT

log = logging.getLogger("engine.gbuffer")


class SceneGeometry:
    """The scene's raster data on the GPU: vertex/index buffers, per-triangle materials, materials, textures, draw
    ranges. Vertices, indices and materials are also texel buffers: the resolve reads the visible triangle's."""

    def __init__(self, ctx, scene, white_texture, sampler):
        self.ctx = ctx
        verts = np.zeros((len(scene.positions), 8), np.float32)
        verts[:, 0:3] = scene.positions
        verts[:, 3:6] = scene.normals
        verts[:, 6:8] = scene.uvs
        tri_mat = scene.vertex_material[scene.indices[:, 0]]
        order = np.argsort(tri_mat, kind="stable")
        indices = np.ascontiguousarray(scene.indices[order], dtype=np.uint32)
        mats_sorted = tri_mat[order]
        self.draws = []  # (material, first index, index count); the draw's first triangle is first index / 3
        if len(mats_sorted):
            starts = np.flatnonzero(np.r_[True, mats_sorted[1:] != mats_sorted[:-1]])
            ends = np.r_[starts[1:], len(mats_sorted)]
            self.draws = [(int(mats_sorted[s]), int(s) * 3, int(e - s) * 3) for s, e in zip(starts, ends)]
        self.vertex_buffer = upload_buffer(ctx, verts, VERTEX | UNIFORM_TEXEL, "vertices")
        self.index_buffer = upload_buffer(ctx, indices, INDEX | UNIFORM_TEXEL, "indices")
        self.tri_material_buffer = upload_buffer(ctx, np.r_[mats_sorted, 0].astype(np.uint32), UNIFORM_TEXEL,
                                                 "triangle materials")

        self.textures = []
        mat_data = np.zeros((max(len(scene.materials), 1), 8), np.float32)
        mat_slots = mat_data.view(np.int32)
        for i, m in enumerate(scene.materials):
            mat_data[i, 0:4] = m.base_color
            mat_slots[i, 4] = -1
            if m.texture is not None and len(self.textures) < MAX_TEXTURES:
                mat_slots[i, 4] = len(self.textures)
                self.textures.append(upload_texture(ctx, m.texture))
        textured = sum(m.texture is not None for m in scene.materials)
        if textured > MAX_TEXTURES:
            log.warning("%s: %d textured materials; the first %d keep their textures, the other %d show their base "
                        "colour", scene.name, textured, MAX_TEXTURES, textured - MAX_TEXTURES)
        self.material_buffer = upload_buffer(ctx, mat_data, UNIFORM_TEXEL, "materials")
        F4, U1 = vk.VK_FORMAT_R32G32B32A32_SFLOAT, vk.VK_FORMAT_R32_UINT
        self.views = [BufferView(self.vertex_buffer, F4), BufferView(self.index_buffer, U1),
                      BufferView(self.tri_material_buffer, U1), BufferView(self.material_buffer, F4)]
        self.white = white_texture
        self.sampler = sampler

    def destroy(self):
        for obj in [*self.views, self.vertex_buffer, self.index_buffer, self.tri_material_buffer,
                    self.material_buffer, *self.textures]:
            obj.destroy()


class GBufferPass:
    name = "gbuffer"
    shaders = ("gbuffer.vert", "gbuffer.frag", "gbuffer_resolve.comp")

    def __init__(self, ctx, library, frame_ubo, targets):
        self.ctx = ctx
        self.frame_ubo = frame_ubo
        self.raster_set = DescriptorSet(ctx, [(0, UB)])
        self.raster_set.buffer(0, frame_ubo)
        self.set = DescriptorSet(ctx, [(0, UB), (1, SI), (2, SI), (3, SI), (4, SI), (5, UTB), (6, UTB), (7, UTB),
                                       (8, UTB), (9, CIS, MAX_TEXTURES), (10, SI)])
        self.set.buffer(0, frame_ubo)
        self.sampler = Sampler(ctx)
        self.white = upload_texture(ctx, np.full((1, 1, 4), 255, np.uint8))
        for slot in range(MAX_TEXTURES):
            self.set.image(9, self.white, vk.VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL, self.sampler, element=slot)
        self.pipeline = GraphicsPipeline(
            ctx, library.get("gbuffer.vert"), library.get("gbuffer.frag"), [self.raster_set],
            color_formats=[VISIBILITY_FORMAT], depth_format=DEPTH_FORMAT, vertex_stride=32,
            attributes=[(0, F3, 0)], push_size=4, name="gbuffer")
        # Specialization constant 0: the texture slots the scene uses (the resolve's sampling blocks past them go).
        self.resolve = ComputePipeline(ctx, library.get("gbuffer_resolve.comp"), [self.set], spec={0: MAX_TEXTURES},
                                       name="gbuffer_resolve")
        self.library = library
        self.bind_targets(targets)

    def reload(self, library):
        self.library = library
        self.pipeline.rebuild(library.get("gbuffer.vert"), library.get("gbuffer.frag"))
        self.resolve.rebuild(library.get("gbuffer_resolve.comp"))

    def bind_targets(self, t):
        self.set.image(1, t.visibility).image(2, t.position).image(3, t.normal).image(4, t.albedo)
        self.set.image(10, t.normal8)

    def bind_scene(self, geom: SceneGeometry):
        spec = {0: max(1, len(geom.textures))}
        if spec != self.resolve.spec:
            self.resolve.specialize(self.library.get("gbuffer_resolve.comp"), spec)
        for binding, view in enumerate(geom.views, start=5):
            self.set.texel_buffer(binding, view)
        for slot in range(MAX_TEXTURES):
            tex = geom.textures[slot] if slot < len(geom.textures) else self.white
            self.set.image(9, tex, vk.VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL, self.sampler, element=slot)

    def record(self, cmd, targets, geom: SceneGeometry):
        w, h = targets.width, targets.height
        CA, GENERAL = vk.VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL, vk.VK_IMAGE_LAYOUT_GENERAL
        CS = vk.VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT
        # The visibility image is all zeros here (cleared once when made, then by each frame's resolve after reading
        # it), so the raster loads it instead of clearing it: a clear costs the few raster units of an H200 0.1 ms.
        image_barrier(cmd, targets.visibility, GENERAL, CA, CS, vk.VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT,
                      vk.VK_ACCESS_SHADER_READ_BIT | vk.VK_ACCESS_SHADER_WRITE_BIT,
                      vk.VK_ACCESS_COLOR_ATTACHMENT_READ_BIT | vk.VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT)
        image_barrier(cmd, targets.depth, vk.VK_IMAGE_LAYOUT_UNDEFINED, vk.VK_IMAGE_LAYOUT_DEPTH_ATTACHMENT_OPTIMAL,
                      vk.VK_PIPELINE_STAGE_LATE_FRAGMENT_TESTS_BIT, vk.VK_PIPELINE_STAGE_EARLY_FRAGMENT_TESTS_BIT,
                      vk.VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT,
                      vk.VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_READ_BIT | vk.VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT)
        vis = vk.VkRenderingAttachmentInfo(
            imageView=targets.visibility.view, imageLayout=CA, loadOp=vk.VK_ATTACHMENT_LOAD_OP_LOAD,
            storeOp=vk.VK_ATTACHMENT_STORE_OP_STORE)
        depth = vk.VkRenderingAttachmentInfo(
            imageView=targets.depth.view, imageLayout=vk.VK_IMAGE_LAYOUT_DEPTH_ATTACHMENT_OPTIMAL,
            loadOp=vk.VK_ATTACHMENT_LOAD_OP_CLEAR, storeOp=vk.VK_ATTACHMENT_STORE_OP_DONT_CARE,
            clearValue=vk.VkClearValue(depthStencil=vk.VkClearDepthStencilValue(depth=0.0, stencil=0)))
        area = vk.VkRect2D(offset=vk.VkOffset2D(0, 0), extent=vk.VkExtent2D(w, h))
        info = vk.VkRenderingInfo(renderArea=area, layerCount=1, colorAttachmentCount=1, pColorAttachments=[vis],
                                  pDepthAttachment=depth)
        vk.vkCmdBeginRendering(cmd, info)
        vk.vkCmdSetViewport(cmd, 0, 1, [vk.VkViewport(0, 0, w, h, 0.0, 1.0)])
        vk.vkCmdSetScissor(cmd, 0, 1, [area])
        self.pipeline.bind(cmd, [self.raster_set])
        vk.vkCmdBindVertexBuffers(cmd, 0, 1, [geom.vertex_buffer.handle], [0])
        vk.vkCmdBindIndexBuffer(cmd, geom.index_buffer.handle, 0, vk.VK_INDEX_TYPE_UINT32)
        for _material, first, count in geom.draws:
            vk.vkCmdPushConstants(cmd, self.pipeline.layout, vk.VK_SHADER_STAGE_ALL, 0, 4,
                                  vk.ffi.new("uint32_t[]", [first // 3]))
            vk.vkCmdDrawIndexed(cmd, count, 1, first, 0, 0)
        vk.vkCmdEndRendering(cmd)
        image_barrier(cmd, targets.visibility, CA, GENERAL, vk.VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT, CS,
                      vk.VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT,
                      vk.VK_ACCESS_SHADER_READ_BIT | vk.VK_ACCESS_SHADER_WRITE_BIT)
        # The resolve overwrites every pixel: the last frame's contents (read by compute and copies) are discarded.
        for img in (*targets.gbuffer, targets.normal8):
            image_barrier(cmd, img, vk.VK_IMAGE_LAYOUT_UNDEFINED, GENERAL, CS | vk.VK_PIPELINE_STAGE_TRANSFER_BIT, CS,
                          vk.VK_ACCESS_SHADER_READ_BIT | vk.VK_ACCESS_TRANSFER_READ_BIT, vk.VK_ACCESS_SHADER_WRITE_BIT)
        self.resolve.dispatch(cmd, [self.set], (w + 7) // 8, (h + 7) // 8)
        for img in (*targets.gbuffer, targets.normal8):
            image_barrier(cmd, img, GENERAL, GENERAL, CS, CS | vk.VK_PIPELINE_STAGE_TRANSFER_BIT,
                          vk.VK_ACCESS_SHADER_WRITE_BIT, vk.VK_ACCESS_SHADER_READ_BIT | vk.VK_ACCESS_TRANSFER_READ_BIT)
