"""G-buffer pass: a visibility raster (the id of the visible triangle per pixel) and a compute resolve into world
position + linear depth, normal, albedo and the material's roughness, metallic, occlusion and emission.

The raster writes 4 bytes per pixel (R32_UINT: triangle + 1, 0 = background) plus depth; `gbuffer_resolve.comp`
then computes what the rasterizer would have interpolated at each pixel centre from the triangle's vertices
(perspective-correct barycentrics from homogeneous edge functions) and samples the albedo texture with the UV
derivatives of the neighbouring pixels (trilinear, anisotropic where the device can; textures are layers of a few
array images, engine/passes/textures.py). Writing the whole G-buffer from fragments was several times slower on a GPU
with few raster units; the same bytes from compute cost a small fraction of that.

Vertices are interleaved (position, normal, uv: 32 bytes), in object space, every mesh once in one vertex and one
index buffer with its levels of detail after it (engine/scene/lod.py), each level's triangles sorted by material; a
mesh's instances are drawn together, one draw per material range of the mesh (or one for the whole mesh where the
instances override its material), the range's first triangle within the mesh's levels in a push constant. With
culling (engine/passes/cull.py) a compute pass first drops the instances outside the frustum and picks each one's
level, and the draws are indirect, one per run, level and range; without, direct draws of the full meshes. With
culling, small instances may go to a compute raster instead, merged into the visibility image by depth before the
resolve (engine/passes/soft_raster.py).
Alpha-tested materials are drawn after the opaque ones by their own pipeline (gbuffer_mask.vert / .frag, which
discards). The instances are a storage buffer in draw order (grouped by mesh, material override and mirroring):
transforms (this frame's and the previous one's, with their normal matrices), written per frame into a host
staging buffer that the frame's command buffer copies to the device-local one, and each instance's first
visibility id (the triangles of the levels of the instances before it), so the visibility id is that + the draw's
first triangle + gl_PrimitiveID + 1 and the resolve finds the instance by a binary search.
Single-sided materials (glTF doubleSided false) are drawn by variants of the same pipelines that cull back faces
(counter-clockwise front faces, as glTF), or front faces for mirrored instances (a negative determinant turns the
winding over; an instance that changes sign makes the geometry again, as a new material override does); double-sided
ones by variants that cull nothing (the resolve turns the normal to the viewer). The ray passes see every triangle
from both sides (shadows and AO of single-sided geometry too).
"""
from __future__ import annotations

import numpy as np

from ..bvh.instanced import inverse3
from ..errors import SceneError, ShaderError
from ..scene.instances import determinants
from ..scene.lod import lod_chain
from ..scene.material import texture_key
from ..vk import (Buffer, BufferView, DescriptorSet, GraphicsPipeline, Sampler, device, reflect, upload_buffer,
                  upload_texture_array)
from ..vk.formats import R32UI, RG32F, RGB32F, RGBA32F, RGBA32UI
from ..vk.pipelines import CULL_BACK, CULL_FRONT, CULL_NONE
from ..vk.resources import INDEX, STORAGE, TRANSFER_DST, TRANSFER_SRC, UNIFORM_TEXEL, VERTEX
from .base import ComputePass, read, update, write
from .cull import CullPass, DrawTables
from .soft_raster import SW_RASTER_PIXELS, SoftMergePass, SoftRasterPass, soft_facing
from .interface import INSTANCE_TEXELS, MATERIAL_FLAGS, MATERIAL_TEXELS, MAX_TEXTURE_ARRAYS
from .targets import DEPTH_FORMAT, VISIBILITY_FORMAT
from .textures import TextureArrays


INSTANCE_FLOATS = 4 * INSTANCE_TEXELS   # std430 `Instance` (shaders/glsl/include/instances.glsl): 256 bytes
#: INSTANCES_TEXEL (the raster and the resolve read the instance records through texel views): None = on CPU devices.
INSTANCES_TEXEL = None
#: The texel views of the instances and draw slots that the visibility raster's vertex shaders also declare.
RASTER_TEXEL_BINDINGS = {"instance_texels", "instance_words", "visible_texels"}
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
        meshes, mesh_of, overrides = list(scene.meshes), np.asarray(scene.instance_mesh, np.int64), \
            instance_materials(scene)
        chains = [lod_chain(m) if levels else lod_chain(m, max_levels=1) for m in meshes]
        n_vert = sum(len(level.positions) for chain in chains for level in chain)
        verts = np.zeros((n_vert, 8), np.float32)
        indices, info, first_tri = [], [], []
        # per mesh, per level of detail: (material, first triangle within the mesh's levels, triangle count), the
        # same materials at every level (a count may be 0)
        self.mesh_ranges = []
        self.mesh_levels = []   # per mesh: (object-space box, the object-space error of each level)
        v0 = t0 = 0
        for m, chain in zip(meshes, chains):
            tri_mat = np.asarray(m.vertex_material[m.indices[:, 0]], np.int64)
            objects = np.zeros(len(m.indices), np.uint32)
            for k, sub in enumerate(m.submeshes):
                objects[sub.first_triangle:sub.first_triangle + sub.triangle_count] = k
            materials = np.unique(tri_mat)
            levels, at = [], 0
            for level in chain:   # each level's triangles grouped by material, the levels in a row
                nv, nt = len(level.positions), len(level.indices)
                verts[v0:v0 + nv, 0:3] = level.positions
                verts[v0:v0 + nv, 3:6] = level.normals
                verts[v0:v0 + nv, 6:8] = level.uvs
                mats = tri_mat[level.source]
                order = np.argsort(mats, kind="stable")
                indices.append(np.asarray(level.indices, np.int64)[order] + v0)
                tri = np.zeros((nt, 4), np.uint32)   # material, triangle of the mesh, object, the level's error
                src = level.source[order]
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
        self.mesh_level_triangles = np.array([sum(len(level.indices) for level in chain) for chain in chains],
                                             np.int64)
        self.mesh_first_triangle = np.array(first_tri, np.int64)
        self.vertex_buffer = upload_buffer(ctx, verts, VERTEX | UNIFORM_TEXEL, "vertices")
        self.index_buffer = upload_buffer(ctx, np.ascontiguousarray(np.concatenate(indices), np.uint32),
                                          INDEX | UNIFORM_TEXEL, "indices")
        self.tri_info_buffer = upload_buffer(ctx, np.concatenate(info + [np.zeros((1, 4), np.uint32)]),
                                             UNIFORM_TEXEL, "triangle info")
        self.alpha_tested = {i for i, m in enumerate(scene.materials) if m.alpha_mode != "OPAQUE"}
        self.single_sided = {i for i, m in enumerate(scene.materials) if not m.double_sided}
        self._mirrored = mirrored(scene.transforms) if self.single_sided else None
        self._instances(meshes, mesh_of, overrides)

        self.textures = TextureArrays(ctx, scene_textures(scene.materials))
        mat_data = material_texels(scene.materials, self.textures)
        self.material_buffer = upload_buffer(ctx, mat_data, UNIFORM_TEXEL, "materials")
        self.alpha_index, records = alpha_records(scene, self.textures)
        self.alpha_buffer = upload_buffer(ctx, records, UNIFORM_TEXEL, "alpha records")
        self.views = [BufferView(self.vertex_buffer, RGBA32F), BufferView(self.index_buffer, R32UI),
                      BufferView(self.tri_info_buffer, RGBA32UI), BufferView(self.material_buffer, RGBA32F),
                      BufferView(self.alpha_buffer, RGBA32F)]
        self.white = white_texture
        self.sampler = sampler

    def _instances(self, meshes, mesh_of, overrides):
        """The draw order (instances grouped by mesh, then material override), the draws and the instance buffer's
        constant fields."""
        n = len(mesh_of)
        self.instance_count = n
        flip = self._mirrored.astype(np.int64) if self._mirrored is not None else np.zeros(n, np.int64)
        self.order = np.lexsort((flip, overrides, mesh_of))   # draw slot -> instance (stable)
        self._in_order = bool(np.array_equal(self.order, np.arange(n)))   # (no gather of the transforms per frame)
        tris = self.mesh_level_triangles[mesh_of[self.order]]
        total = int(tris.sum())
        if total >= 2 ** 32 - 1:
            raise SceneError(f"{total:,} instanced triangles (levels of detail included): the visibility buffer's "
                             f"32-bit ids hold at most {2 ** 32 - 2:,}")
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
        keys = np.stack([mesh_of[self.order], overrides[self.order], flip[self.order]], axis=1) if n else \
            np.zeros((0, 3), np.int64)
        runs = np.flatnonzero(np.r_[True, np.any(keys[1:] != keys[:-1], axis=1)]) if n else np.zeros(0, np.int64)
        run_of = np.zeros(n, np.int64)
        for r, (f, e) in enumerate(zip(runs, np.r_[runs[1:], n])):
            run_of[f:e] = r
            k, over, mirror = int(keys[f, 0]), int(keys[f, 1]), bool(keys[f, 2])
            base = int(self.mesh_first_triangle[k])
            levels = self.mesh_ranges[k] if over < 0 else \
                [[(over, ranges[0][1], sum(c for _, _, c in ranges))] for ranges in self.mesh_ranges[k]]
            materials = {material for ranges in levels for material, _, _ in ranges}
            culls = {CULL_NONE if m not in self.single_sided else CULL_FRONT if mirror else CULL_BACK
                     for m in materials}
            groups.append((self.mesh_levels[k][0], self.mesh_levels[k][1], len(records), len(levels[0]), int(f),
                           len(levels), soft_facing(culls, bool(materials & self.alpha_tested))))
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
        self.instance_views = (BufferView(self.instance_buffer, RGBA32F, 0, view),
                               BufferView(self.instance_buffer, RGBA32UI, 0, view))
        block = self.instance_staging.view(np.float32)[:n * INSTANCE_FLOATS].reshape(n, INSTANCE_FLOATS)
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
        self._written = None   # (transforms, previous transforms) last written

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
        if w is not None and _same(w[0], previous):   # last frame's current: moved over, not recomputed
            block[:, 16:32], block[:, 44:56] = block[:, 0:16], block[:, 32:44]
            todo = todo[:1]
        for at, m in todo:
            m = m if self._in_order else m[o]
            # GLSL mat4: column-major (written through a strided view of the block: no transposed copy)
            np.copyto(block[:, at:at + 16].reshape(n, 4, 4), m.transpose(0, 2, 1), casting="same_kind")
            inv = inverse3(m[:, :3, :3])   # rows of inv(A): the columns of its inverse transpose
            base = 32 + at * 3 // 4
            for r in range(3):
                block[:, base + 4 * r:base + 4 * r + 3] = inv[:, r]
        self._written = (transforms, previous) if owned else (transforms.copy(), previous.copy())
        return True

    def destroy(self):
        for obj in [*self.views, *self.instance_views, self.vertex_buffer, self.index_buffer, self.tri_info_buffer,
                    self.material_buffer, self.alpha_buffer, self.instance_buffer, self.instance_staging,
                    self.tables, self.textures]:
            obj.destroy()


#: Each texture field of a Material and whether it holds colour (an sRGB array) or data (a linear one).
TEXTURE_KINDS = {"texture": True, "metallic_roughness_texture": False, "normal_texture": False,
                 "emissive_texture": True, "occlusion_texture": False}


def scene_textures(materials) -> dict:
    """(texture content, srgb) -> (image, srgb) over every texture of every material: one image used by many
    materials is one layer; one used as colour and as data is one of each kind."""
    out = {}
    for m in materials:
        for field, srgb in TEXTURE_KINDS.items():
            image = getattr(m, field)
            if image is not None:
                out.setdefault((texture_key(image), srgb), (image, srgb))
    return out


def material_texels(materials, textures: TextureArrays) -> np.ndarray:
    """The materials texel buffer: MATERIAL_TEXELS RGBA32F texels per material (the layout is in interface.py)."""
    data = np.zeros((max(len(materials), 1), 4 * MATERIAL_TEXELS), np.float32)
    bits = data.view(np.uint32)

    def handle(m, field):
        image = getattr(m, field)
        return textures.handle(None if image is None else (texture_key(image), TEXTURE_KINDS[field]))

    for i, m in enumerate(materials):
        data[i, 0:4] = m.base_color
        bits[i, 4:8] = [handle(m, f) for f in ("texture", "metallic_roughness_texture", "normal_texture",
                                               "emissive_texture")]
        data[i, 8:12] = m.metallic, m.roughness, m.occlusion_strength, m.normal_scale
        # BLEND is cut out at 0.5 (no transparency): the raster and the rays see the same surface
        data[i, 12:15], data[i, 15] = m.emissive, {"OPAQUE": 0.0, "MASK": m.alpha_cutoff, "BLEND": 0.5}[m.alpha_mode]
        bits[i, 16] = handle(m, "occlusion_texture")
        bits[i, 17] = ((MATERIAL_FLAGS["alpha_tested"] if m.alpha_mode != "OPAQUE" else 0)
                       | (MATERIAL_FLAGS["double_sided"] if m.double_sided else 0))
    return data


def alpha_records(scene, textures: TextureArrays) -> tuple[np.ndarray, np.ndarray]:
    """The ray passes' alpha test (shaders/glsl/include/alpha.glsl): per scene triangle, 0 (opaque) or 1 + its
    record; the records, 2 RGBA32F texels per alpha-tested triangle: (uv0, uv1), (uv2, base texture handle bits,
    threshold): a hit counts where texture alpha >= threshold = cutoff / base alpha (BLEND: cutoff 0.5). Without
    alpha-tested materials: an empty index (every triangle opaque), and the flat arrays are never made."""
    if all(m.alpha_mode == "OPAQUE" for m in scene.materials):
        return np.zeros(0, np.uint32), np.zeros((1, 8), np.float32)
    tri_mat = scene.vertex_material[scene.indices[:, 0]] if scene.triangle_count else np.zeros(0, np.int64)
    tested = np.array([m.alpha_mode != "OPAQUE" for m in scene.materials] or [False])[tri_mat]
    index = np.zeros(scene.triangle_count, np.uint32)
    prims = np.flatnonzero(tested)
    index[prims] = np.arange(1, len(prims) + 1, dtype=np.uint32)
    records = np.zeros((max(len(prims), 1), 8), np.float32)
    records[:len(prims), 0:6] = scene.uvs[scene.indices[prims]].reshape(-1, 6)
    bits = records.view(np.uint32)
    for k, m in enumerate(scene.materials):
        if m.alpha_mode == "OPAQUE":
            continue
        rows = tri_mat[prims] == k
        cutoff = 0.5 if m.alpha_mode == "BLEND" else m.alpha_cutoff
        base = float(m.base_color[3])
        bits[:len(prims)][rows, 6] = textures.handle(None if m.texture is None else (texture_key(m.texture), True))
        records[:len(prims)][rows, 7] = 0.0 if cutoff == 0 else (cutoff / base if base > 0 else np.inf)
    return index, records


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """The same transforms: the same array, or equal ones."""
    return a is b or np.array_equal(a, b)


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
        """This frame's transforms and the last frame's into `geom` (made for the scene's current material
        overrides: `SceneGeometry.overrides_changed`)."""
        transforms = scene.transforms.copy()   # (one copy: the instance buffer's record and the next `last`)
        last = self.last if self.last is not None and self.last.shape == transforms.shape else transforms
        geom.write_transforms(transforms, last, owned=True)
        self.settled = _same(transforms, last)
        self.last = transforms

    def still(self, geom: SceneGeometry) -> None:
        """No motion this frame (a frame without temporal history): the previous transforms are the current."""
        if self.last is not None:
            geom.write_transforms(self.last, self.last, owned=True)
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
        "g_motion": write("image", "motion"), "g_pbr": write("image", "material"),
        "g_emissive": write("image", "emissive"), "g_instance": write("image", "instance_id"),
        "g_prev_position": write("image", "prev_position"), "g_prev_normal": write("image", "prev_normal"),
        "instances": read("buffer"), "instance_texels": read("uniform_texel"),
        "instance_words": read("uniform_texel"),
    }

    def constants(self, ctx) -> dict:
        # TEXTURE_ARRAYS: lowered to the arrays a scene has (blocks past them go); INSTANCES_TEXEL: set per scene
        return {"TEXTURE_ARRAYS": MAX_TEXTURE_ARRAYS, "INSTANCES_TEXEL": False}


class _Raster:
    """One visibility pipeline: its vertex and fragment shaders, its set 0 (laid out from their reflection) and the
    bindings its shaders may have (hot reload refuses others, or a changed layout)."""

    def __init__(self, ctx, library, stem: str, bindings: set, attributes: list):
        self.stem, self.bindings = stem, bindings | RASTER_TEXEL_BINDINGS
        self.spirv = self._spirv(library)   # what the pipelines run (hot reload replaces it once they took the new)
        vert, frag = self.spirv
        interface = reflect(vert, f"{stem}.vert").merged(reflect(frag, f"{stem}.frag"))
        self._check(interface)
        self.interface = interface   # what the pipeline layout was made for; hot reload must keep it
        self.set = DescriptorSet(ctx, interface.set(0).values())
        self.values = {"INSTANCES_TEXEL": False}   # set per scene (GBufferPass.bind_scene)
        spec = interface.specialization(self.values, stem)
        # by culling: both sides (double-sided materials), front faces only (single-sided ones), back faces only
        # (single-sided ones of mirrored instances)
        self.pipelines = {cull: GraphicsPipeline(
            ctx, vert, frag, [self.set], color_formats=[VISIBILITY_FORMAT], depth_format=DEPTH_FORMAT,
            vertex_stride=32, attributes=attributes, push_size=interface.push_size, cull=cull, spec=spec,
            name=f"{stem} {label}") for cull, label in ((CULL_NONE, "two-sided"), (CULL_BACK, "one-sided"),
                                                        (CULL_FRONT, "one-sided mirrored"))}
        self.pipeline = self.pipelines[CULL_NONE]

    def _spirv(self, library):
        return library.get(f"{self.stem}.vert"), library.get(f"{self.stem}.frag")

    def specialize(self, **values):
        """Re-create the pipelines with these constants changed (by name), where they differ; on a failure the
        old pipelines and constants stay."""
        merged = {**self.values, **values}
        if merged != self.values:
            self._build(self.spirv, self.interface, merged)
            self.values = merged

    def _build(self, spirv, interface, values):
        """The three pipelines re-created from `spirv` with the constants `values`, or, where one fails, all as
        they were."""
        spec = interface.specialization(values, self.stem)
        done = []
        try:
            for pipeline in self.pipelines.values():
                old, pipeline.spec = pipeline.spec, spec
                try:
                    pipeline.rebuild(*spirv)
                except BaseException:
                    pipeline.spec = old
                    raise
                done.append((pipeline, old))
        except BaseException:
            for pipeline, old in done:
                pipeline.spec = old
                pipeline.rebuild(*self.spirv)
            raise

    def _check(self, interface):
        if {b.name for b in interface.bindings} != self.bindings:
            raise ShaderError(f"{self.stem}.vert/.frag: the raster reads {', '.join(sorted(self.bindings))} and "
                              f"nothing else; the shaders declare {', '.join(b.name for b in interface.bindings)}")

    def reload(self, library):
        vert, frag = self._spirv(library)
        interface = reflect(vert, f"{self.stem}.vert").merged(reflect(frag, f"{self.stem}.frag"))
        self._check(interface)
        old = self.interface
        if (interface.bindings, interface.push_size) != (old.bindings, old.push_size):
            was = ", ".join(f"{b.name} {b.kind} set {b.set} binding {b.binding}" for b in old.bindings)
            now = ", ".join(f"{b.name} {b.kind} set {b.set} binding {b.binding}" for b in interface.bindings)
            raise ShaderError(f"{self.stem}.vert/.frag: their layout changed ({was}, {old.push_size} bytes of push "
                              f"constants -> {now}, {interface.push_size} bytes); restart to use them")
        self._build((vert, frag), interface, self.values)   # (the constants' ids as the new shaders have them)
        self.spirv, self.interface = (vert, frag), interface


class GBufferPass:
    """The visibility raster (gbuffer.vert / gbuffer.frag; alpha-tested materials: gbuffer_mask.vert / .frag), the
    software raster of small instances and its merge (engine/passes/soft_raster.py) and the resolve."""

    name = "gbuffer"
    shaders = ("gbuffer.vert", "gbuffer.frag", "gbuffer_mask.vert", "gbuffer_mask.frag", "gbuffer_resolve.comp",
               "cull.comp", "soft_raster.comp", "soft_merge.comp")

    def __init__(self, ctx, library, resources):
        self.ctx, self.library = ctx, library
        self.raster = _Raster(ctx, library, "gbuffer", {"frame", "instances", "visible"}, [(0, RGB32F, 0)])
        self.raster.set.bind("frame", resources["frame"])
        # alpha-tested materials: UVs too, and the materials and textures for the alpha test
        self.masked = _Raster(ctx, library, "gbuffer_mask", {"frame", "materials", "textures", "instances", "visible"},
                              [(0, RGB32F, 0), (1, RG32F, 24)])
        self.masked.set.bind("frame", resources["frame"])
        self.resolve = ResolvePass(ctx, library, resources)
        self.cull = CullPass(ctx, library, resources)
        # the software raster and its merge, where the device has 64-bit buffer atomics (else none: hardware only)
        self.soft = (SoftRasterPass(ctx, library, resources), SoftMergePass(ctx, library, resources)) \
            if ctx.int64_atomics else ()
        self.sampler = Sampler(ctx, anisotropy=device.texture_anisotropy(ctx))
        self.white = upload_texture_array(ctx, [np.full((1, 1, 4), 255, np.uint8)], 1, 1, name="white texture")
        for slot in range(MAX_TEXTURE_ARRAYS):
            for s in (self.resolve.set, self.masked.set):
                s.bind("textures", self.white, sampler=self.sampler, element=slot)
        self.resources = resources

    def reload(self, library):
        self.library = library
        self.raster.reload(library)
        self.masked.reload(library)
        self.resolve.reload(library)
        self.cull.reload(library)
        for p in self.soft:
            p.reload(library)

    def bind(self, resources, targets=None):
        self.resources = resources
        for p in (self.resolve, self.cull, *self.soft):
            p.bind(resources)

    def software(self, culling: bool, sw_raster: bool | None) -> bool:
        """Does the software raster draw the small instances? Only with culling, on devices with 64-bit buffer
        atomics, at sizes whose buffer fits (`Targets.soft_visibility`); `sw_raster` None: on GPUs, not on CPU
        devices."""
        if not (self.soft and culling and self.ctx.draw_indirect_first_instance
                and self.resources.get("soft_visibility") is not None):
            return False
        return not device.is_cpu(self.ctx) if sw_raster is None else sw_raster

    def instances_texel(self, geom: SceneGeometry) -> bool:
        """Do the raster and the resolve read the instance records (and draw slots) through their texel views?"""
        return geom.instance_texel_ok and (device.is_cpu(self.ctx) if INSTANCES_TEXEL is None else INSTANCES_TEXEL)

    def bind_scene(self, geom: SceneGeometry):
        texel = self.instances_texel(geom)
        self.resolve.specialize(TEXTURE_ARRAYS=max(1, len(geom.textures)), INSTANCES_TEXEL=texel)
        s = self.resolve.set
        s.bind("instance_texels", geom.instance_views[0]).bind("instance_words", geom.instance_views[1])
        for r in (self.raster, self.masked):
            r.specialize(INSTANCES_TEXEL=texel)
            r.set.bind("instance_texels", geom.instance_views[0]).bind("instance_words", geom.instance_views[1])
            r.set.bind("visible_texels", geom.tables.visible_view)
        for name, view in zip(("vertices", "indices", "tri_info", "materials"), geom.views):
            s.bind(name, view)
        self.masked.set.bind("materials", geom.views[3])
        for r in (self.raster, self.masked):
            r.set.bind("instances", geom.instance_buffer)
            r.set.bind("visible", geom.tables.visible)
        self.cull.bind_scene(geom.instance_buffer, geom.tables)
        if self.soft:
            self.soft[0].bind_scene(geom)
        s.bind("instances", geom.instance_buffer)
        for slot in range(MAX_TEXTURE_ARRAYS):
            tex = geom.textures.images[slot] if slot < len(geom.textures) else self.white
            for s in (self.resolve.set, self.masked.set):
                s.bind("textures", tex, sampler=self.sampler, element=slot)

    def record(self, rec, targets, geom: SceneGeometry, culling: bool = True, lod_pixels: float = 0.0,
               sw_raster: bool | None = None, sw_raster_pixels: float = SW_RASTER_PIXELS):
        """The instances' copy to the device, the culling pass (`culling`; levels of detail where `lod_pixels` >
        0; instances of at most `sw_raster_pixels` across to the software raster where `software`), the raster,
        the software raster and its merge, and the resolve."""
        rec.copy(geom.instance_staging, geom.instance_buffer)
        soft = self.software(culling, sw_raster)
        culling = culling and self.ctx.draw_indirect_first_instance
        if culling:
            self.cull.record(rec, geom.instance_buffer, geom.tables, lod_pixels,
                             sw_raster_pixels if soft else 0.0)
        # The visibility image is all zeros here (cleared when made, then by each frame's resolve after reading it),
        # so the raster loads it instead of clearing it (a clear costs GPUs with few raster units).
        # Opaque materials first, keeping early depth tests; then the alpha-tested ones, whose shader discards.
        # Opaque then masked; each: double-sided materials (no culling), single-sided ones (back faces culled;
        # front faces for mirrored instances).
        draws = geom.indirect if culling else geom.draws
        passes = [(r, cull) for r in (self.raster, self.masked) for cull in (CULL_NONE, CULL_BACK, CULL_FRONT)]
        lists = [(r.pipelines[cull], [r.set], draws[r is self.masked, cull]) for r, cull in passes]
        rec.raster(lists[0][0], lists[0][1], targets.visibility, targets.depth, geom.vertex_buffer,
                   geom.index_buffer, lists[0][2], more=lists[1:],
                   reads=[self.resources["frame"], geom.instance_buffer, geom.tables.visible],
                   indirect=geom.tables.commands if culling else None, keep_depth=soft)
        if soft:   # (after the raster in the recording: the GPU may run it while the raster runs)
            self.soft[0].record(rec, geom)
            self.soft[1].record(rec, targets.width, targets.height)
        self.resolve.dispatch(rec, self.resolve.tiles(targets.width, targets.height),
                              push=np.array([geom.instance_count], np.uint32),
                              reads=self.resolve.reads + [geom.instance_buffer])
