"""What the path tracer (shaders/glsl/path.comp) reads of a scene besides its BVH, materials and textures: every
mesh's vertices once (object space), per flattened triangle its three vertices, instance and material (the order
of the BVH's triangle ids: instances in scene order, each mesh's triangles in order), the instances' transforms and
the emissive triangles' power CDF, by which next-event estimation picks one.

The transforms and the CDF (whose powers are world areas) live in host-visible buffers that `update` rewrites in
place when instances move, so the path tracer's recorded command buffer stays valid.
"""

from __future__ import annotations

import numpy as np

from ..bvh.instanced import inverse3
from ..vk import Buffer, BufferView, upload_buffer
from ..vk.formats import RGBA32F, RGBA32UI
from ..vk.resources import UNIFORM_TEXEL

INSTANCE_TEXELS = 6  # model rows 0-2 (3x4), the normal matrix's rows 3-5 (inverse transpose)
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def flat_triangles(scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per flattened triangle: (T, 3) vertex indices into the meshes' concatenated vertices, (T,) instance and
    (T,) material (the instance's override, else the mesh's)."""
    meshes = scene.meshes
    vbase = np.concatenate([[0], np.cumsum([len(m.positions) for m in meshes])[:-1]]).astype(np.int64)
    mesh_tris = [np.asarray(m.indices, np.int64) + vbase[k] for k, m in enumerate(meshes)]
    mesh_mats = [np.asarray(m.vertex_material, np.int64)[np.asarray(m.indices, np.int64)[:, 0]] for m in meshes]
    inst_mesh, override = np.asarray(scene.instance_mesh, np.int64), np.asarray(scene.instance_material, np.int64)
    tris, inst, mats = [], [], []
    for i, k in enumerate(inst_mesh):
        n = len(mesh_tris[k])
        tris.append(mesh_tris[k])
        inst.append(np.full(n, i, np.int64))
        mats.append(mesh_mats[k] if override[i] < 0 else np.full(n, override[i], np.int64))
    if not tris:
        return np.zeros((0, 3), np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(tris), np.concatenate(inst), np.concatenate(mats)


class PathScene:
    """The path tracer's scene buffers (see the module's docstring) on `ctx`, for `scene` as it is now; `update`
    follows its instances' motion."""

    def __init__(self, ctx, scene):
        self.ctx = ctx
        meshes = scene.meshes
        n_vert = sum(len(m.positions) for m in meshes)
        verts = np.zeros((max(n_vert, 1), 8), np.float32)
        at = 0
        for m in meshes:
            n = len(m.positions)
            verts[at : at + n, 0:3], verts[at : at + n, 3:6], verts[at : at + n, 6:8] = m.positions, m.normals, m.uvs
            at += n
        tris, inst, mats = flat_triangles(scene)
        self.tri_vertices, self.tri_instance = tris, inst
        emissive = np.array([np.asarray(m.emissive, np.float64) @ LUMINANCE for m in scene.materials] or [0.0])
        self.radiance = emissive[mats] if len(mats) else np.zeros(0)
        self.emitters = np.flatnonzero(self.radiance > 0)  # flat triangles with an emissive material
        records = np.zeros((max(len(tris), 1), 8), np.uint32)
        records[: len(tris), 0:3], records[: len(tris), 3], records[: len(tris), 4] = tris, inst, mats
        records[self.emitters, 5] = np.arange(1, len(self.emitters) + 1)
        self.positions = verts[:, 0:3].astype(np.float64)
        self.vertex_buffer = upload_buffer(ctx, verts, UNIFORM_TEXEL, "path vertices")
        self.triangle_buffer = upload_buffer(ctx, records, UNIFORM_TEXEL, "path triangles")
        n_inst = max(len(scene.instance_mesh), 1)
        self.instance_buffer = Buffer(ctx, n_inst * INSTANCE_TEXELS * 16, UNIFORM_TEXEL, host=True, name="path xf")
        self.emitter_buffer = Buffer(ctx, max(len(self.emitters), 1) * 16, UNIFORM_TEXEL, host=True, name="emitters")
        self.views = {
            "vertices": BufferView(self.vertex_buffer, RGBA32F),
            "triangles": BufferView(self.triangle_buffer, RGBA32UI),
            "instances": BufferView(self.instance_buffer, RGBA32F),
            "emitters": BufferView(self.emitter_buffer, RGBA32F),
        }
        self.emitter_buffer.view(np.uint32)[:4] = 0  # no emitters: a count of 0 (emitters.glsl emitter_count)
        self._written = None  # the transforms last written
        self.update(scene)

    @property
    def emitter_count(self) -> int:
        return len(self.emitters)

    def update(self, scene) -> None:
        """The instances' transforms and the emitters' CDF, where the transforms changed since the last call (the
        GPU must not be reading them: the renderer waits for each path-tracing batch)."""
        transforms = np.asarray(scene.transforms, np.float64)
        if self._written is not None and np.array_equal(self._written, transforms):
            return
        block = self.instance_buffer.view(np.float32)[: len(transforms) * 4 * INSTANCE_TEXELS]
        block = block.reshape(len(transforms), INSTANCE_TEXELS, 4)
        block[:, 0:3, :] = transforms[:, :3, :4]
        block[:, 3:6, 0:3] = inverse3(transforms[:, :3, :3]).transpose(0, 2, 1)  # rows of inv(A)^T
        block[:, 3:6, 3] = 0.0
        if len(self.emitters):
            self._write_emitters(transforms)
        self._written = transforms.copy()

    def _write_emitters(self, transforms) -> None:
        """Per emissive triangle (flat id bits, CDF up to and with it, its probability; the first record's w the
        count's bits): power = luminance of the emitted radiance times the world area (the constant pi of Lambertian
        emission cancels)."""
        e = self.emitters
        xf = transforms[self.tri_instance[e]]
        p = self.positions[self.tri_vertices[e]]  # (E, 3, 3) object space
        world = np.einsum("eij,ekj->eki", xf[:, :3, :3], p) + xf[:, None, :3, 3]
        area = 0.5 * np.linalg.norm(np.cross(world[:, 1] - world[:, 0], world[:, 2] - world[:, 0]), axis=1)
        power = self.radiance[e] * area
        total = power.sum()
        prob = power / total if total > 0 else np.full(len(e), 1.0 / len(e))
        cdf = np.cumsum(prob)
        cdf[-1] = 2.0  # every draw in [0, 1) lands in some record, whatever the rounding
        rec = self.emitter_buffer.view(np.float32)[: 4 * len(e)].reshape(len(e), 4)
        rec.view(np.uint32)[:, 0] = e
        rec[:, 1], rec[:, 2], rec[:, 3] = cdf, prob, 0.0
        rec.view(np.uint32)[0, 3] = len(e)  # the count (emitters.glsl emitter_count)

    def bind(self, dset, names=None) -> None:
        """Its texel views into `dset` by binding name (`names`: only these; default: all)."""
        for name, view in self.views.items():
            if names is None or name in names:
                dset.bind(name, view)

    def destroy(self) -> None:
        for view in self.views.values():
            view.destroy()
        for buf in (self.vertex_buffer, self.triangle_buffer, self.instance_buffer, self.emitter_buffer):
            buf.destroy()
