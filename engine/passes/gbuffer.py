"""G-buffer pass: rasterize every mesh into world position + linear depth, normal and albedo.

Vertices are interleaved (position, normal, uv: 32 bytes); triangles are sorted by material and drawn
with one draw per material, the material index in a push constant.
"""
from __future__ import annotations

import numpy as np
import vulkan as vk

from ..vk import CIS, SB, UB, DescriptorSet, GraphicsPipeline, Sampler, image_barrier, upload_buffer, upload_texture
from ..vk.resources import INDEX, STORAGE, VERTEX

MAX_TEXTURES = 16
POSITION_FORMAT = vk.VK_FORMAT_R32G32B32A32_SFLOAT
NORMAL_FORMAT = vk.VK_FORMAT_R32G32B32A32_SFLOAT
ALBEDO_FORMAT = vk.VK_FORMAT_R16G16B16A16_SFLOAT
DEPTH_FORMAT = vk.VK_FORMAT_D32_SFLOAT
COLOR_FORMATS = [POSITION_FORMAT, NORMAL_FORMAT, ALBEDO_FORMAT]
F3 = vk.VK_FORMAT_R32G32B32_SFLOAT


class SceneGeometry:
    """The scene's raster data on the GPU: vertex/index buffers, materials, textures, draw ranges."""

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
        self.draws = []  # (material, first index, index count)
        if len(mats_sorted):
            starts = np.flatnonzero(np.r_[True, mats_sorted[1:] != mats_sorted[:-1]])
            ends = np.r_[starts[1:], len(mats_sorted)]
            self.draws = [(int(mats_sorted[s]), int(s) * 3, int(e - s) * 3) for s, e in zip(starts, ends)]
        self.vertex_buffer = upload_buffer(ctx, verts, VERTEX, "vertices")
        self.index_buffer = upload_buffer(ctx, indices, INDEX, "indices")

        self.textures = []
        mat_data = np.zeros((max(len(scene.materials), 1), 8), np.float32)
        mat_slots = mat_data.view(np.int32)
        for i, m in enumerate(scene.materials):
            mat_data[i, 0:4] = m.base_color
            mat_slots[i, 4] = -1
            if m.texture is not None and len(self.textures) < MAX_TEXTURES:
                mat_slots[i, 4] = len(self.textures)
                self.textures.append(upload_texture(ctx, m.texture))
        self.material_buffer = upload_buffer(ctx, mat_data, STORAGE, "materials")
        self.white = white_texture
        self.sampler = sampler

    def destroy(self):
        for obj in [self.vertex_buffer, self.index_buffer, self.material_buffer, *self.textures]:
            obj.destroy()


class GBufferPass:
    name = "gbuffer"
    shaders = ("gbuffer.vert", "gbuffer.frag")

    def __init__(self, ctx, library, frame_ubo):
        self.ctx = ctx
        self.frame_ubo = frame_ubo
        self.set = DescriptorSet(ctx, [(0, UB), (1, SB), (2, CIS, MAX_TEXTURES)])
        self.set.buffer(0, frame_ubo)
        self.sampler = Sampler(ctx)
        self.white = upload_texture(ctx, np.full((1, 1, 4), 255, np.uint8))
        self.pipeline = GraphicsPipeline(
            ctx, library.get("gbuffer.vert"), library.get("gbuffer.frag"), [self.set],
            color_formats=COLOR_FORMATS, depth_format=DEPTH_FORMAT, vertex_stride=32,
            attributes=[(0, F3, 0), (1, F3, 12), (2, vk.VK_FORMAT_R32G32_SFLOAT, 24)], push_size=4, name="gbuffer")

    def reload(self, library):
        self.pipeline.rebuild(library.get("gbuffer.vert"), library.get("gbuffer.frag"))

    def bind_scene(self, geom: SceneGeometry):
        self.set.buffer(1, geom.material_buffer)
        for slot in range(MAX_TEXTURES):
            tex = geom.textures[slot] if slot < len(geom.textures) else self.white
            self.set.image(2, tex, vk.VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL, self.sampler, element=slot)

    def record(self, cmd, targets, geom: SceneGeometry):
        w, h = targets.width, targets.height
        CA = vk.VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL
        for img in targets.gbuffer:
            image_barrier(cmd, img, vk.VK_IMAGE_LAYOUT_UNDEFINED, CA,
                          vk.VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT | vk.VK_PIPELINE_STAGE_TRANSFER_BIT,
                          vk.VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT,
                          vk.VK_ACCESS_SHADER_READ_BIT | vk.VK_ACCESS_TRANSFER_READ_BIT,
                          vk.VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT)
        image_barrier(cmd, targets.depth, vk.VK_IMAGE_LAYOUT_UNDEFINED, vk.VK_IMAGE_LAYOUT_DEPTH_ATTACHMENT_OPTIMAL,
                      vk.VK_PIPELINE_STAGE_LATE_FRAGMENT_TESTS_BIT, vk.VK_PIPELINE_STAGE_EARLY_FRAGMENT_TESTS_BIT,
                      vk.VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT,
                      vk.VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_READ_BIT | vk.VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT)
        zero = vk.VkClearValue(color=vk.VkClearColorValue(float32=[0.0, 0.0, 0.0, 0.0]))
        colors = [vk.VkRenderingAttachmentInfo(
            imageView=img.view, imageLayout=CA, loadOp=vk.VK_ATTACHMENT_LOAD_OP_CLEAR,
            storeOp=vk.VK_ATTACHMENT_STORE_OP_STORE, clearValue=zero) for img in targets.gbuffer]
        depth = vk.VkRenderingAttachmentInfo(
            imageView=targets.depth.view, imageLayout=vk.VK_IMAGE_LAYOUT_DEPTH_ATTACHMENT_OPTIMAL,
            loadOp=vk.VK_ATTACHMENT_LOAD_OP_CLEAR, storeOp=vk.VK_ATTACHMENT_STORE_OP_DONT_CARE,
            clearValue=vk.VkClearValue(depthStencil=vk.VkClearDepthStencilValue(depth=0.0, stencil=0)))
        area = vk.VkRect2D(offset=vk.VkOffset2D(0, 0), extent=vk.VkExtent2D(w, h))
        info = vk.VkRenderingInfo(renderArea=area, layerCount=1, colorAttachmentCount=len(colors),
                                  pColorAttachments=colors, pDepthAttachment=depth)
        vk.vkCmdBeginRendering(cmd, info)
        vk.vkCmdSetViewport(cmd, 0, 1, [vk.VkViewport(0, 0, w, h, 0.0, 1.0)])
        vk.vkCmdSetScissor(cmd, 0, 1, [area])
        self.pipeline.bind(cmd, [self.set])
        vk.vkCmdBindVertexBuffers(cmd, 0, 1, [geom.vertex_buffer.handle], [0])
        vk.vkCmdBindIndexBuffer(cmd, geom.index_buffer.handle, 0, vk.VK_INDEX_TYPE_UINT32)
        for material, first, count in geom.draws:
            vk.vkCmdPushConstants(cmd, self.pipeline.layout, vk.VK_SHADER_STAGE_ALL, 0, 4,
                                  vk.ffi.new("uint32_t[]", [material]))
            vk.vkCmdDrawIndexed(cmd, count, 1, first, 0, 0)
        vk.vkCmdEndRendering(cmd)
        for img in targets.gbuffer:
            image_barrier(cmd, img, CA, vk.VK_IMAGE_LAYOUT_GENERAL,
                          vk.VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT,
                          vk.VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT | vk.VK_PIPELINE_STAGE_TRANSFER_BIT,
                          vk.VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT,
                          vk.VK_ACCESS_SHADER_READ_BIT | vk.VK_ACCESS_TRANSFER_READ_BIT)
