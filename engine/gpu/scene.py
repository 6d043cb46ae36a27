"""The scene's raster geometry on the GPU (`SceneGeometry`), which the G-buffer passes draw and resolve and the ray
passes take their alpha test from, and what changed of it between frames (`SceneChanges`).

Vertices are interleaved (position, normal, uv: 32 bytes), in object space, every mesh once in one vertex and one
index buffer with its levels of detail after it (engine/scene/lod.py), each level's triangles sorted by material; a
mesh's instances are drawn together, one draw per material range of the mesh (or one for the whole mesh where the
instances override its material), the range's first triangle within the mesh's levels in a push constant; the
culled raster's indirect records are filled on the GPU (engine/gpu/draws.py, engine/passes/cull.py). The instances
are a storage buffer in draw order (grouped by mesh, material override and mirroring): transforms (this frame's and
the previous one's, with their normal matrices), written per frame into a host staging buffer that the frame's
command buffer copies to the device-local one, and each instance's first visibility id (the triangles of the levels
of the instances before it), so the visibility id is that + the draw's first triangle + gl_PrimitiveID + 1 and the
resolve finds the instance by a binary search. Materials, textures and the rays' alpha records:
engine/gpu/materials.py, engine/gpu/textures.py.
"""

from __future__ import annotations

import numpy as np

from ..bvh.instanced import inverse3
from ..errors import SceneError
from ..passes.interface import INSTANCE_TEXELS
from ..scene.instances import determinants
from ..scene.lod import lod_chain
from ..vk import Buffer, BufferView, upload_buffer
from ..vk.formats import R32UI, RGBA32F, RGBA32UI
from ..vk.pipelines import CULL_BACK, CULL_FRONT, CULL_NONE
from ..vk.resources import INDEX, STORAGE, TRANSFER_DST, TRANSFER_SRC, UNIFORM_TEXEL, VERTEX
from .draws import DrawTables, soft_facing
from .materials import RayAlpha, alpha_records, material_texels
from .textures import TextureArrays, scene_textures


INSTANCE_FLOATS = 4 * INSTANCE_TEXELS  # std430 `Instance` (shaders/glsl/include/instances.glsl): 256 bytes
NO_MATERIAL = 0xFFFFFFFF


def mirrored(transforms: np.ndarray) -> np.ndarray:
    """(N,) bool: which of the (N, 4, 4) transforms turn the winding over (a negative 3x3 determinant)."""
    return determinants(np.asarray(transforms, np.float64)) < 0


def instance_materials(scene) -> np.ndarray:
    """(N,) int64 material override of each instance, -1 where none."""
    return np.asarray(scene.instance_material, np.int64)


class SceneGeometry:
    """The scene's raster data on the GPU: one vertex and one index buffer holding every mesh once (object space)
    with its levels of detail, per triangle its material, mesh triangle, object and level error, the materials,
    textures, the ray passes' alpha records, the instanced draws (opaque and alpha-tested; direct, and the culled
    indirect ones with their `tables`), and the instances (transforms this frame and the previous one, rewritten
    per frame in a host staging buffer that each frame copies to a device-local one, so the recorded command buffer
    stays valid while instances move). Vertices, indices and triangle data are also texel buffers: the resolve
    reads the visible triangle's."""

    def __init__(self, ctx, scene, white_texture, sampler, levels: bool = True):
        """`levels`: make the meshes' levels of detail (else each mesh is its only level)."""
        self.ctx, self.has_levels = ctx, bool(levels)
        meshes, mesh_of, overrides = (
            list(scene.meshes),
            np.asarray(scene.instance_mesh, np.int64),
            instance_materials(scene),
        )
        chains = [lod_chain(m) if levels else lod_chain(m, max_levels=1) for m in meshes]
        n_vert = sum(len(level.positions) for chain in chains for level in chain)
        verts = np.zeros((n_vert, 8), np.float32)
        indices, info, first_tri = [], [], []
        # per mesh, per level of detail: (material, first triangle within the mesh's levels, triangle count), the
        # same materials at every level (a count may be 0)
        self.mesh_ranges = []
        self.mesh_first_level = []  # per mesh: its first level's mesh triangle at each place (traced cameras' ids)
        self.mesh_levels = []  # per mesh: (object-space box, the object-space error of each level)
        v0 = t0 = 0
        for m, chain in zip(meshes, chains):
            tri_mat = np.asarray(m.vertex_material[m.indices[:, 0]], np.int64)
            objects = np.zeros(len(m.indices), np.uint32)
            for k, sub in enumerate(m.submeshes):
                objects[sub.first_triangle : sub.first_triangle + sub.triangle_count] = k
            materials = np.unique(tri_mat)
            levels, at = [], 0
            for level in chain:  # each level's triangles grouped by material, the levels in a row
                nv, nt = len(level.positions), len(level.indices)
                verts[v0 : v0 + nv, 0:3] = level.positions
                verts[v0 : v0 + nv, 3:6] = level.normals
                verts[v0 : v0 + nv, 6:8] = level.uvs
                mats = tri_mat[level.source]
                order = np.argsort(mats, kind="stable")
                indices.append(np.asarray(level.indices, np.int64)[order] + v0)
                tri = np.zeros((nt, 4), np.uint32)  # material, triangle of the mesh, object, the level's error
                src = level.source[order]
                if not levels:
                    self.mesh_first_level.append(src)
                tri[:, 0], tri[:, 1], tri[:, 2] = mats[order], src, objects[src]
                tri[:, 3] = np.float32(level.error).view(np.uint32)
                info.append(tri)
                lo, hi = np.searchsorted(mats[order], materials), np.searchsorted(mats[order], materials, "right")
                levels.append([(int(mat), int(at + a), int(b - a)) for mat, a, b in zip(materials, lo, hi)])
                v0, at = v0 + nv, at + nt
            self.mesh_ranges.append(levels)
            self.mesh_levels.append((np.asarray(m.box, np.float32), [level.error for level in chain]))
            first_tri.append(t0)
            t0 += at
        self.mesh_triangles = np.array([len(m.indices) for m in meshes], np.int64)
        self.mesh_level_triangles = np.array([sum(len(level.indices) for level in chain) for chain in chains], np.int64)
        self.mesh_first_triangle = np.array(first_tri, np.int64)
        self.vertex_buffer = upload_buffer(ctx, verts, VERTEX | UNIFORM_TEXEL, "vertices")
        self.index_buffer = upload_buffer(
            ctx, np.ascontiguousarray(np.concatenate(indices), np.uint32), INDEX | UNIFORM_TEXEL, "indices"
        )
        self.tri_info_buffer = upload_buffer(
            ctx, np.concatenate(info + [np.zeros((1, 4), np.uint32)]), UNIFORM_TEXEL, "triangle info"
        )
        self.alpha_tested = {i for i, m in enumerate(scene.materials) if m.alpha_mode != "OPAQUE"}
        self.single_sided = {i for i, m in enumerate(scene.materials) if not m.double_sided}
        self._mirrored = mirrored(scene.transforms) if self.single_sided else None
        self._instances(meshes, mesh_of, overrides)

        self.textures = TextureArrays(ctx, scene_textures(scene.materials))
        mat_data = material_texels(scene.materials, self.textures)
        self.material_buffer = upload_buffer(ctx, mat_data, UNIFORM_TEXEL, "materials")
        self.alpha_index, records = alpha_records(scene, self.textures)
        self.alpha_buffer = upload_buffer(ctx, records, UNIFORM_TEXEL, "alpha records")
        self.views = [
            BufferView(self.vertex_buffer, RGBA32F),
            BufferView(self.index_buffer, R32UI),
            BufferView(self.tri_info_buffer, RGBA32UI),
            BufferView(self.material_buffer, RGBA32F),
            BufferView(self.alpha_buffer, RGBA32F),
        ]
        self.white = white_texture
        self.sampler = sampler
        self.alpha = RayAlpha(self.views[4], self.textures, white_texture, sampler)  # the ray passes' alpha test

    def _instances(self, meshes, mesh_of, overrides):
        """The draw order (instances grouped by mesh, then material override), the draws and the instance buffer's
        constant fields."""
        n = len(mesh_of)
        self.instance_count = n
        flip = self._mirrored.astype(np.int64) if self._mirrored is not None else np.zeros(n, np.int64)
        self.order = np.lexsort((flip, overrides, mesh_of))  # draw slot -> instance (stable)
        self._in_order = bool(np.array_equal(self.order, np.arange(n)))  # (no gather of the transforms per frame)
        tris = self.mesh_level_triangles[mesh_of[self.order]]
        total = int(tris.sum())
        if total >= 2**32 - 1:
            raise SceneError(
                f"{total:,} instanced triangles (levels of detail included): the visibility buffer's "
                f"32-bit ids hold at most {2**32 - 2:,}"
            )
        prefix = np.concatenate([[0], np.cumsum(tris)[:-1]]).astype(np.int64)
        # the flat arrays' order (scene.indices, scene.submeshes): instances in scene order, their triangles in a row
        flat_tri = np.concatenate([[0], np.cumsum(self.mesh_triangles[mesh_of])[:-1]])
        subs = np.array([len(m.submeshes) for m in meshes], np.int64)
        flat_obj = np.concatenate([[0], np.cumsum(subs[mesh_of])[:-1]])
        # per run of instances of one mesh and override, its draws: (first index, index count, instance count,
        # first instance, push constants: first triangle within the mesh's levels (and the material, for the alpha
        # test)), by pipeline (masked or not) and culling (CULL_NONE, CULL_BACK, CULL_FRONT); `draws` draw every
        # instance's full mesh, `indirect` the records the culling pass fills, one per run, level and range
        # (engine/passes/cull.py)
        self.draws = {(masked, cull): [] for masked in (False, True) for cull in (CULL_NONE, CULL_BACK, CULL_FRONT)}
        self.indirect = {key: [] for key in self.draws}
        records, groups = [], []
        keys = (
            np.stack([mesh_of[self.order], overrides[self.order], flip[self.order]], axis=1)
            if n
            else np.zeros((0, 3), np.int64)
        )
        runs = np.flatnonzero(np.r_[True, np.any(keys[1:] != keys[:-1], axis=1)]) if n else np.zeros(0, np.int64)
        run_of = np.zeros(n, np.int64)
        for r, (f, e) in enumerate(zip(runs, np.r_[runs[1:], n])):
            run_of[f:e] = r
            k, over, mirror = int(keys[f, 0]), int(keys[f, 1]), bool(keys[f, 2])
            base = int(self.mesh_first_triangle[k])
            levels = (
                self.mesh_ranges[k]
                if over < 0
                else [[(over, ranges[0][1], sum(c for _, _, c in ranges))] for ranges in self.mesh_ranges[k]]
            )
            materials = {material for ranges in levels for material, _, _ in ranges}
            culls = {
                CULL_NONE if m not in self.single_sided else CULL_FRONT if mirror else CULL_BACK for m in materials
            }
            groups.append(
                (
                    self.mesh_levels[k][0],
                    self.mesh_levels[k][1],
                    len(records),
                    len(levels[0]),
                    int(f),
                    len(levels),
                    soft_facing(culls, bool(materials & self.alpha_tested)),
                )
            )
            for level, ranges in enumerate(levels):
                for material, start, count in ranges:
                    cull = CULL_NONE if material not in self.single_sided else CULL_FRONT if mirror else CULL_BACK
                    masked = material in self.alpha_tested
                    push = np.array([start, material] if masked else [start], np.uint32).tobytes()
                    if count and level == 0:
                        self.draws[masked, cull].append((3 * (base + start), 3 * count, int(e - f), int(f), push))
                    if count:
                        self.indirect[masked, cull].append((len(records), push))
                    records.append((3 * count, 0, 3 * (base + start), 0, (1 + level) * n + int(f), level))
        self.tables = DrawTables(self.ctx, records, groups, n, max((len(c) for c in self.mesh_ranges), default=1))
        size = max(n, 1) * INSTANCE_FLOATS * 4
        # written by the host, read by the raster and the resolve from a device-local copy (the frame's command
        # buffer copies it first): on a discrete GPU, reads of host memory would cross the bus per vertex and pixel
        self.instance_staging = Buffer(self.ctx, size, TRANSFER_SRC, host=True, name="instances staging")
        self.instance_buffer = Buffer(self.ctx, size, STORAGE | TRANSFER_DST | UNIFORM_TEXEL, name="instances")
        # the resolve's texel views of it (read on CPU devices, where the records fit one view)
        texels = int(self.ctx.limits.maxTexelBufferElements)
        self.instance_texel_ok = size // 16 <= texels and self.tables.texel_ok
        view = min(size, 16 * texels)
        self.instance_views = (
            BufferView(self.instance_buffer, RGBA32F, 0, view),
            BufferView(self.instance_buffer, RGBA32UI, 0, view),
        )
        block = self.instance_staging.view(np.float32)[: n * INSTANCE_FLOATS].reshape(n, INSTANCE_FLOATS)
        block[:] = 0
        ids = block.view(np.uint32)
        o = self.order
        ids[:, 56] = prefix
        ids[:, 57] = self.mesh_first_triangle[mesh_of[o]]
        ids[:, 58] = o
        ids[:, 59] = np.where(overrides[o] < 0, NO_MATERIAL, overrides[o])
        ids[:, 60] = flat_tri[o]
        ids[:, 61] = flat_obj[o]
        ids[:, 62] = run_of
        self._block = block
        self._overrides = overrides.copy()
        self._written = None  # (transforms, previous transforms) last written

    def overrides_changed(self, scene) -> bool:
        """Do the instances' material overrides differ from those this geometry was made for? (The draws, their
        pipelines and the ray passes' alpha records follow the overrides: the geometry is made again.)"""
        return not np.array_equal(instance_materials(scene), self._overrides)

    def mirrors_changed(self, scene) -> bool:
        """Has an instance's determinant changed sign since this geometry was made (only where some material is
        single-sided: its draws cull the other face for mirrored instances)?"""
        return self._mirrored is not None and not np.array_equal(mirrored(scene.transforms), self._mirrored)

    def write_transforms(self, transforms: np.ndarray, previous: np.ndarray, owned: bool = False) -> bool:
        """Write this frame's and the previous frame's (N, 4, 4) object-to-world transforms (scene order) into the
        instance buffer (the frame that reads it must have finished). Returns False when they are what the buffer
        holds already (nothing written). `owned`: the arrays are the caller's own, never changed afterwards (kept,
        not copied; the next call knows them by identity)."""
        w = self._written
        if w is not None and _same(w[0], transforms) and _same(w[1], previous):
            return False
        block, o = self._block, self.order
        n = len(block)
        todo = [(0, transforms), (16, previous)]
        if w is not None and _same(w[0], previous):  # last frame's current: moved over, not recomputed
            block[:, 16:32], block[:, 44:56] = block[:, 0:16], block[:, 32:44]
            todo = todo[:1]
        for at, m in todo:
            m = m if self._in_order else m[o]
            # GLSL mat4: column-major (written through a strided view of the block: no transposed copy)
            np.copyto(block[:, at : at + 16].reshape(n, 4, 4), m.transpose(0, 2, 1), casting="same_kind")
            inv = inverse3(m[:, :3, :3])  # rows of inv(A): the columns of its inverse transpose
            base = 32 + at * 3 // 4
            for r in range(3):
                block[:, base + 4 * r : base + 4 * r + 3] = inv[:, r]
        self._written = (transforms, previous) if owned else (transforms.copy(), previous.copy())
        return True

    def destroy(self):
        for obj in [
            *self.views,
            *self.instance_views,
            self.vertex_buffer,
            self.index_buffer,
            self.tri_info_buffer,
            self.material_buffer,
            self.alpha_buffer,
            self.instance_buffer,
            self.instance_staging,
            self.tables,
            self.textures,
        ]:
            obj.destroy()


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """The same transforms: the same array, or equal ones."""
    return a is b or np.array_equal(a, b)


class SceneChanges:
    """What the last frame drew of a scene's instances (its `version`, the transforms), so that the next frame
    writes the instance buffer only when something moved, with the previous transforms its motion needs."""

    def __init__(self):
        self.version = None  # the scene's `version` the last frame drew (None: none drawn yet)
        self.last = None  # the transforms the last frame drew
        self.settled = False  # the instance buffer's previous transforms equal its current ones

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
        """This frame's transforms and the last frame's into `geom` (made for the scene's current material
        overrides: `SceneGeometry.overrides_changed`)."""
        transforms = scene.transforms.copy()  # (one copy: the instance buffer's record and the next `last`)
        last = self.last if self.last is not None and self.last.shape == transforms.shape else transforms
        geom.write_transforms(transforms, last, owned=True)
        self.settled = _same(transforms, last)
        self.last = transforms

    def still(self, geom: SceneGeometry) -> None:
        """No motion this frame (a frame without temporal history): the previous transforms are the current."""
        if self.last is not None:
            geom.write_transforms(self.last, self.last, owned=True)
            self.settled = True
