"""G-buffer pass: a visibility raster (the id of the visible triangle per pixel) and a compute resolve into world
position + linear depth, normal and albedo.

The raster writes 4 bytes per pixel (R32_UINT: triangle + 1, 0 = background) plus depth; `gbuffer_resolve.comp`
then computes what the rasterizer would have interpolated at each pixel centre from the triangle's vertices
(perspective-correct barycentrics from homogeneous edge functions) and samples the albedo texture with the UV
derivatives of the neighbouring pixels. Writing the whole G-buffer from fragments was several times slower on a GPU
with few raster units; the same bytes from compute cost a small fraction of that.

Vertices are interleaved (position, normal, uv: 32 bytes), in object space, every mesh once in one vertex and one
index buffer; each mesh is one instanced draw (vkCmdDrawIndexed with its instances' count and first slot). The
instances are a storage buffer in draw order (grouped by mesh): transforms (this frame's and the previous one's,
with their normal matrices), rewritten in place per frame, and each instance's first visibility id (the triangles
of the instances before it), so the visibility id is that + gl_PrimitiveID + 1 and the resolve finds the instance
by a binary search.
"""
from __future__ import annotations

import logging

import numpy as np

from ..errors import SceneError, ShaderError
from ..scene.material import texture_key
from ..vk import Buffer, BufferView, DescriptorSet, GraphicsPipeline, Sampler, reflect, upload_buffer, upload_texture
from ..vk.formats import R32UI, RGB32F, RGBA32F, RGBA32UI
from ..vk.resources import INDEX, STORAGE, UNIFORM_TEXEL, VERTEX
from .base import ComputePass, read, update, write
from .interface import MAX_TEXTURES
from .targets import DEPTH_FORMAT, VISIBILITY_FORMAT

log = logging.getLogger("engine.gbuffer")


INSTANCE_FLOATS = 64   # std430 `Instance` (shaders/glsl/include/instances.glsl): 256 bytes
NO_MATERIAL = 0xFFFFFFFF


def instance_materials(scene) -> np.ndarray:
    """(N,) int64 material override of each instance, -1 where none."""
    return np.asarray(scene.instance_material, np.int64)


def inverse3(a: np.ndarray) -> np.ndarray:
    """(N, 3, 3) inverses of invertible (N, 3, 3) matrices: the adjugate over the determinant, component by
    component (far cheaper than np.linalg.inv or np.cross for many small matrices)."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = (
        (a[:, i, 0], a[:, i, 1], a[:, i, 2]) for i in range(3))
    adj = np.empty_like(a)
    adj[:, 0, 0], adj[:, 0, 1], adj[:, 0, 2] = a11 * a22 - a12 * a21, a02 * a21 - a01 * a22, a01 * a12 - a02 * a11
    adj[:, 1, 0], adj[:, 1, 1], adj[:, 1, 2] = a12 * a20 - a10 * a22, a00 * a22 - a02 * a20, a02 * a10 - a00 * a12
    adj[:, 2, 0], adj[:, 2, 1], adj[:, 2, 2] = a10 * a21 - a11 * a20, a01 * a20 - a00 * a21, a00 * a11 - a01 * a10
    det = a00 * adj[:, 0, 0] + a01 * adj[:, 1, 0] + a02 * adj[:, 2, 0]
    return adj / det[:, None, None]


class SceneGeometry:
    """The scene's raster data on the GPU: one vertex and one index buffer holding every mesh once (object space),
    per mesh triangle its material and object, the materials, textures, one instanced draw per mesh, and the
    instances (transforms this frame and the previous one, in a host-visible buffer rewritten per frame, so the
    recorded command buffer stays valid while instances move). Vertices, indices and triangle data are also texel
    buffers: the resolve reads the visible triangle's."""

    def __init__(self, ctx, scene, white_texture, sampler):
        self.ctx = ctx
        meshes, mesh_of, overrides = list(scene.meshes), np.asarray(scene.instance_mesh, np.int64), \
            instance_materials(scene)
        n_vert = sum(len(m.positions) for m in meshes)
        verts = np.zeros((n_vert, 8), np.float32)
        indices, info, first_tri = [], [], []
        v0 = t0 = 0
        for m in meshes:
            nv, nt = len(m.positions), len(m.indices)
            verts[v0:v0 + nv, 0:3] = m.positions
            verts[v0:v0 + nv, 3:6] = m.normals
            verts[v0:v0 + nv, 6:8] = m.uvs
            indices.append(np.asarray(m.indices, np.int64) + v0)
            tri = np.zeros((nt, 4), np.uint32)   # material, triangle within the mesh, object within the mesh
            tri[:, 0] = m.vertex_material[m.indices[:, 0]]
            tri[:, 1] = np.arange(nt)
            for k, sub in enumerate(m.submeshes):
                tri[sub.first_triangle:sub.first_triangle + sub.triangle_count, 2] = k
            info.append(tri)
            first_tri.append(t0)
            v0, t0 = v0 + nv, t0 + nt
        self.mesh_triangles = np.array([len(m.indices) for m in meshes], np.int64)
        self.mesh_first_triangle = np.array(first_tri, np.int64)
        self.vertex_buffer = upload_buffer(ctx, verts, VERTEX | UNIFORM_TEXEL, "vertices")
        self.index_buffer = upload_buffer(ctx, np.ascontiguousarray(np.concatenate(indices), np.uint32),
                                          INDEX | UNIFORM_TEXEL, "indices")
        self.tri_info_buffer = upload_buffer(ctx, np.concatenate(info + [np.zeros((1, 4), np.uint32)]),
                                             UNIFORM_TEXEL, "triangle info")
        self._instances(meshes, mesh_of, overrides)

        self.textures = []
        mat_data = np.zeros((max(len(scene.materials), 1), 8), np.float32)
        mat_slots = mat_data.view(np.int32)
        slots = {}   # texture content -> slot: one image shared by many materials takes one slot
        keys = [texture_key(m.texture) for m in scene.materials]
        for i, (m, key) in enumerate(zip(scene.materials, keys)):
            mat_data[i, 0:4] = m.base_color
            if key is not None and key not in slots and len(self.textures) < MAX_TEXTURES:
                slots[key] = len(self.textures)
                self.textures.append(upload_texture(ctx, m.texture))
            mat_slots[i, 4] = slots.get(key, -1)
        distinct = len(set(keys) - {None})
        if distinct > MAX_TEXTURES:
            log.warning("%s: %d distinct textures; the first %d are kept, materials with the other %d show their base "
                        "colour", scene.name, distinct, MAX_TEXTURES, distinct - MAX_TEXTURES)
        self.material_buffer = upload_buffer(ctx, mat_data, UNIFORM_TEXEL, "materials")
        self.views = [BufferView(self.vertex_buffer, RGBA32F), BufferView(self.index_buffer, R32UI),
                      BufferView(self.tri_info_buffer, RGBA32UI), BufferView(self.material_buffer, RGBA32F)]
        self.white = white_texture
        self.sampler = sampler

    def _instances(self, meshes, mesh_of, overrides):
        """The draw order (instances grouped by mesh), the draws and the instance buffer's constant fields."""
        n = len(mesh_of)
        self.instance_count = n
        self.order = np.argsort(mesh_of, kind="stable")   # draw slot -> instance
        tris = self.mesh_triangles[mesh_of[self.order]]
        total = int(tris.sum())
        if total >= 2 ** 32 - 1:
            raise SceneError(f"{total:,} instanced triangles: the visibility buffer's 32-bit ids hold at most "
                             f"{2 ** 32 - 2:,}")
        prefix = np.concatenate([[0], np.cumsum(tris)[:-1]]).astype(np.int64)
        # the flat arrays' order (scene.indices, scene.submeshes): instances in scene order, their triangles in a row
        flat_tri = np.concatenate([[0], np.cumsum(self.mesh_triangles[mesh_of])[:-1]])
        subs = np.array([len(m.submeshes) for m in meshes], np.int64)
        flat_obj = np.concatenate([[0], np.cumsum(subs[mesh_of])[:-1]])
        # one draw per mesh with instances: (first index, index count, instance count, first instance)
        used, first, count = np.unique(mesh_of[self.order], return_index=True, return_counts=True)
        self.draws = [(int(self.mesh_first_triangle[k]) * 3, int(self.mesh_triangles[k]) * 3, int(c), int(f))
                      for k, f, c in zip(used, first, count) if self.mesh_triangles[k]]
        self.instance_buffer = Buffer(self.ctx, max(n, 1) * INSTANCE_FLOATS * 4, STORAGE, host=True,
                                      name="instances")
        block = self.instance_buffer.view(np.float32)[:n * INSTANCE_FLOATS].reshape(n, INSTANCE_FLOATS)
        block[:] = 0
        ids = block.view(np.uint32)
        o = self.order
        ids[:, 56] = prefix
        ids[:, 57] = self.mesh_first_triangle[mesh_of[o]]
        ids[:, 58] = o
        ids[:, 59] = np.where(overrides[o] < 0, NO_MATERIAL, overrides[o])
        ids[:, 60] = flat_tri[o]
        ids[:, 61] = flat_obj[o]
        self._block = block
        self._overrides = overrides.copy()
        self._written = None   # (transforms, previous transforms) last written

    def write_materials(self, scene) -> None:
        """The instances' material overrides, where they changed since the buffer was written."""
        over = instance_materials(scene)
        if not np.array_equal(over, self._overrides):
            o = self.order
            self._block.view(np.uint32)[:, 59] = np.where(over[o] < 0, NO_MATERIAL, over[o])
            self._overrides = over.copy()

    def write_transforms(self, transforms: np.ndarray, previous: np.ndarray) -> bool:
        """Write this frame's and the previous frame's (N, 4, 4) object-to-world transforms (scene order) into the
        instance buffer (the frame that reads it must have finished). Returns False when they are what the buffer
        holds already (nothing written)."""
        w = self._written
        if w is not None and np.array_equal(w[0], transforms) and np.array_equal(w[1], previous):
            return False
        block, o = self._block, self.order
        todo = [(0, transforms), (16, previous)]
        if w is not None and np.array_equal(w[0], previous):   # last frame's current: moved over, not recomputed
            block[:, 16:32], block[:, 44:56] = block[:, 0:16], block[:, 32:44]
            todo = todo[:1]
        for at, m in todo:
            m = m[o]
            block[:, at:at + 16] = m.transpose(0, 2, 1).reshape(-1, 16)   # GLSL mat4: column-major
            inv = inverse3(m[:, :3, :3])   # rows of inv(A): the columns of its inverse transpose
            base = 32 + at * 3 // 4
            for r in range(3):
                block[:, base + 4 * r:base + 4 * r + 3] = inv[:, r]
        self._written = (transforms.copy(), previous.copy())
        return True

    def destroy(self):
        for obj in [*self.views, self.vertex_buffer, self.index_buffer, self.tri_info_buffer,
                    self.material_buffer, self.instance_buffer, *self.textures]:
            obj.destroy()


class SceneChanges:
    """What the last frame drew of a scene's instances (its `version`, the transforms), so that the next frame
    writes the instance buffer only when something moved, with the previous transforms its motion needs."""

    def __init__(self):
        self.version = None      # the scene's `version` the last frame drew (None: none drawn yet)
        self.last = None         # the transforms the last frame drew
        self.settled = False     # the instance buffer's previous transforms equal its current ones

    def begin(self, scene):
        """None when nothing changed since the last frame (and it had no motion); else (whether a mesh deformed,
        whether anything changed)."""
        version = scene.version
        if version == self.version and self.settled:
            return None
        changed = self.version is None or version != self.version
        deformed = self.version is not None and changed and len(scene.deformed_meshes(self.version)) > 0
        self.version = version
        return deformed, changed

    def write(self, scene, geom: SceneGeometry) -> None:
        """This frame's transforms and material overrides, and the last frame's transforms, into `geom`."""
        transforms = scene.transforms
        last = self.last if self.last is not None and self.last.shape == transforms.shape else transforms
        geom.write_materials(scene)
        geom.write_transforms(transforms, last)
        self.settled = np.array_equal(transforms, last)
        self.last = transforms.copy()

    def still(self, geom: SceneGeometry) -> None:
        """No motion this frame (a frame without temporal history): the previous transforms are the current."""
        if self.last is not None:
            geom.write_transforms(self.last, self.last)
            self.settled = True


class ResolvePass(ComputePass):
    """Visibility -> G-buffer (gbuffer_resolve.comp); the scene's geometry is bound by `bind_scene`."""

    name = "gbuffer_resolve"
    shader = "gbuffer_resolve.comp"
    bindings = {
        "frame": read("uniform", "frame"), "visibility": update("image", "visibility"),
        "g_position": write("image", "position"), "g_normal": write("image", "normal"),
        "g_albedo": write("image", "albedo"), "g_normal8": write("image", "normal8"),
        "vertices": read("uniform_texel"), "indices": read("uniform_texel"), "tri_info": read("uniform_texel"),
        "materials": read("uniform_texel"), "textures": read("texture"),
        "g_depth": write("image", "view_depth"), "g_triangle": write("image", "triangle_id"),
        "g_object": write("image", "object_id"), "g_material": write("image", "material_id"),
        "g_motion": write("image", "motion"), "g_instance": write("image", "instance_id"),
        "g_prev_position": write("image", "prev_position"), "g_prev_normal": write("image", "prev_normal"),
        "instances": read("buffer"),
    }

    def constants(self, ctx) -> dict:
        return {"TEXTURE_SLOTS": MAX_TEXTURES}   # lowered to the slots a scene uses (its sampling blocks past them go)


class GBufferPass:
    """The visibility raster (gbuffer.vert / gbuffer.frag) and its resolve."""

    name = "gbuffer"
    shaders = ("gbuffer.vert", "gbuffer.frag", "gbuffer_resolve.comp")

    def __init__(self, ctx, library, resources):
        self.ctx, self.library = ctx, library
        vert, frag = library.get("gbuffer.vert"), library.get("gbuffer.frag")
        interface = reflect(vert, "gbuffer.vert").merged(reflect(frag, "gbuffer.frag"))
        self.interface = interface   # what the pipeline layout was made for; hot reload must keep it
        self.raster_set = DescriptorSet(ctx, interface.set(0).values())
        self.raster_set.bind("frame", resources["frame"])
        self.pipeline = GraphicsPipeline(
            ctx, vert, frag, [self.raster_set], color_formats=[VISIBILITY_FORMAT], depth_format=DEPTH_FORMAT,
            vertex_stride=32, attributes=[(0, RGB32F, 0)], push_size=interface.push_size, name="gbuffer")
        self.resolve = ResolvePass(ctx, library, resources)
        self.sampler = Sampler(ctx)
        self.white = upload_texture(ctx, np.full((1, 1, 4), 255, np.uint8))
        for slot in range(MAX_TEXTURES):
            self.resolve.set.bind("textures", self.white, sampler=self.sampler, element=slot)
        self.resources = resources

    def reload(self, library):
        self.library = library
        vert, frag = library.get("gbuffer.vert"), library.get("gbuffer.frag")
        interface = reflect(vert, "gbuffer.vert").merged(reflect(frag, "gbuffer.frag"))
        if {b.name for b in interface.bindings} != {"frame", "instances"}:
            raise ShaderError("gbuffer.vert/.frag: the raster reads the frame block (set 0, binding 0) and the "
                              "instances (set 0, binding 1) and nothing else; the shaders declare "
                              f"{', '.join(b.name for b in interface.bindings)}")
        old = self.interface
        if (interface.bindings, interface.push_size) != (old.bindings, old.push_size):
            was = ", ".join(f"{b.name} {b.kind} set {b.set} binding {b.binding}" for b in old.bindings)
            now = ", ".join(f"{b.name} {b.kind} set {b.set} binding {b.binding}" for b in interface.bindings)
            raise ShaderError(f"gbuffer.vert/.frag: their layout changed ({was}, {old.push_size} bytes of push "
                              f"constants -> {now}, {interface.push_size} bytes); restart to use them")
        self.pipeline.rebuild(vert, frag)
        self.resolve.reload(library)

    def bind(self, resources, targets=None):
        self.resources = resources
        self.resolve.bind(resources)

    def bind_scene(self, geom: SceneGeometry):
        self.resolve.specialize(TEXTURE_SLOTS=max(1, len(geom.textures)))
        s = self.resolve.set
        for name, view in zip(("vertices", "indices", "tri_info", "materials"), geom.views):
            s.bind(name, view)
        s.bind("instances", geom.instance_buffer)
        self.raster_set.bind("instances", geom.instance_buffer)
        for slot in range(MAX_TEXTURES):
            tex = geom.textures[slot] if slot < len(geom.textures) else self.white
            s.bind("textures", tex, sampler=self.sampler, element=slot)

    def record(self, rec, targets, geom: SceneGeometry):
        # The visibility image is all zeros here (cleared when made, then by each frame's resolve after reading it),
        # so the raster loads it instead of clearing it (a clear costs GPUs with few raster units).
        rec.raster(self.pipeline, [self.raster_set], targets.visibility, targets.depth, geom.vertex_buffer,
                   geom.index_buffer, geom.draws, reads=[self.resources["frame"]])
        self.resolve.dispatch(rec, self.resolve.tiles(targets.width, targets.height),
                              push=np.array([geom.instance_count], np.uint32))
