"""G-buffer pass: a visibility raster (the id of the visible triangle per pixel) and a compute resolve into world
position + linear depth, normal, albedo and the material's roughness, metallic, occlusion and emission.

The raster writes 4 bytes per pixel (R32_UINT: triangle + 1, 0 = background) plus depth; `gbuffer_resolve.comp`
then computes what the rasterizer would have interpolated at each pixel centre from the triangle's vertices
(perspective-correct barycentrics from homogeneous edge functions) and samples the albedo texture with the UV
derivatives of the neighbouring pixels (trilinear, anisotropic where the device can; textures are layers of a few
array images, engine/passes/textures.py). Writing the whole G-buffer from fragments was several times slower on a GPU
with few raster units; the same bytes from compute cost a small fraction of that.

Vertices are interleaved (position, normal, uv: 32 bytes); triangles are sorted by material and drawn with one
draw per material, the draw's first triangle in a push constant (the triangle id is that + gl_PrimitiveID).
Single-sided materials (glTF doubleSided false) are drawn by a variant of the same pipeline that culls back faces
(counter-clockwise front faces, as glTF); double-sided ones by one that culls nothing (the resolve turns the normal
to the viewer). The ray passes see every triangle from both sides (shadows and AO of single-sided geometry too).
"""
from __future__ import annotations

import numpy as np

from ..errors import ShaderError
from ..scene.material import texture_key
from ..vk import (BufferView, DescriptorSet, GraphicsPipeline, Sampler, device, reflect, upload_buffer,
                  upload_texture_array)
from ..vk.formats import R32UI, RG32F, RGB32F, RGBA32F, RGBA32UI
from ..vk.pipelines import CULL_BACK, CULL_NONE
from ..vk.resources import INDEX, UNIFORM_TEXEL, VERTEX
from .base import ComputePass, read, update, write
from .interface import MATERIAL_FLAGS, MATERIAL_TEXELS, MAX_TEXTURE_ARRAYS
from .targets import DEPTH_FORMAT, VISIBILITY_FORMAT
from .textures import TextureArrays


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
        # per drawn triangle: its material, its index in the scene and its object (the sub-mesh it came from)
        info = np.zeros((len(order) + 1, 4), np.uint32)
        info[:-1, 0], info[:-1, 1], info[:-1, 2] = mats_sorted, order, triangle_objects(scene)[order]
        self.tri_info_buffer = upload_buffer(ctx, info, UNIFORM_TEXEL, "triangle info")

        self.textures = TextureArrays(ctx, scene_textures(scene.materials))
        mat_data = material_texels(scene.materials, self.textures)
        self.alpha_tested = {i for i, m in enumerate(scene.materials) if m.alpha_mode != "OPAQUE"}
        self.single_sided = {i for i, m in enumerate(scene.materials) if not m.double_sided}
        self.material_buffer = upload_buffer(ctx, mat_data, UNIFORM_TEXEL, "materials")
        self.alpha_index, records = alpha_records(scene, self.textures)
        self.alpha_buffer = upload_buffer(ctx, records, UNIFORM_TEXEL, "alpha records")
        self.views = [BufferView(self.vertex_buffer, RGBA32F), BufferView(self.index_buffer, R32UI),
                      BufferView(self.tri_info_buffer, RGBA32UI), BufferView(self.material_buffer, RGBA32F),
                      BufferView(self.alpha_buffer, RGBA32F)]
        self.white = white_texture
        self.sampler = sampler

    def destroy(self):
        for obj in [*self.views, self.vertex_buffer, self.index_buffer, self.tri_info_buffer,
                    self.material_buffer, self.alpha_buffer, self.textures]:
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
    threshold): a hit counts where texture alpha >= threshold = cutoff / base alpha (BLEND: cutoff 0.5)."""
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


def flag_alpha_tested(tris: np.ndarray, alpha_index: np.ndarray):
    """Write each BVH triangle's alpha record + 1 (0: opaque) into its free word (engine/bvh/layout.py pad1)."""
    prim = tris["prim"].astype(np.int64)
    flags = np.zeros(len(tris), np.uint32)
    ok = (prim >= 0) & (prim < len(alpha_index))
    flags[ok] = alpha_index[prim[ok]]
    tris["pad1"] = flags


def triangle_objects(scene) -> np.ndarray:
    """(T,) uint32: the index in `scene.submeshes` of each triangle's sub-mesh (the object id)."""
    out = np.zeros(scene.triangle_count, np.uint32)
    for k, sub in enumerate(scene.submeshes):
        out[sub.first_triangle:sub.first_triangle + sub.triangle_count] = k
    return out


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
        "g_emissive": write("image", "emissive"),
    }

    def constants(self, ctx) -> dict:
        return {"TEXTURE_ARRAYS": MAX_TEXTURE_ARRAYS}   # lowered to the arrays a scene has (blocks past them go)


class _Raster:
    """One visibility pipeline: its vertex and fragment shaders, its set 0 (laid out from their reflection) and the
    bindings its shaders may have (hot reload refuses others, or a changed layout)."""

    def __init__(self, ctx, library, stem: str, bindings: set, attributes: list):
        self.stem, self.bindings = stem, bindings
        vert, frag = self._spirv(library)
        interface = reflect(vert, f"{stem}.vert").merged(reflect(frag, f"{stem}.frag"))
        self._check(interface)
        self.interface = interface   # what the pipeline layout was made for; hot reload must keep it
        self.set = DescriptorSet(ctx, interface.set(0).values())
        # `pipeline` draws both sides (double-sided materials), `culled` front faces only (single-sided ones)
        self.pipeline, self.culled = (GraphicsPipeline(
            ctx, vert, frag, [self.set], color_formats=[VISIBILITY_FORMAT], depth_format=DEPTH_FORMAT,
            vertex_stride=32, attributes=attributes, push_size=interface.push_size, cull=cull,
            name=f"{stem} {label}") for cull, label in ((CULL_NONE, "two-sided"), (CULL_BACK, "one-sided")))

    def _spirv(self, library):
        return library.get(f"{self.stem}.vert"), library.get(f"{self.stem}.frag")

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
        self.pipeline.rebuild(vert, frag)
        self.culled.rebuild(vert, frag)


class GBufferPass:
    """The visibility raster (gbuffer.vert / gbuffer.frag; alpha-tested materials: gbuffer_mask.vert / .frag) and
    its resolve."""

    name = "gbuffer"
    shaders = ("gbuffer.vert", "gbuffer.frag", "gbuffer_mask.vert", "gbuffer_mask.frag", "gbuffer_resolve.comp")

    def __init__(self, ctx, library, resources):
        self.ctx, self.library = ctx, library
        self.raster = _Raster(ctx, library, "gbuffer", {"frame"}, [(0, RGB32F, 0)])
        self.raster.set.bind("frame", resources["frame"])
        # alpha-tested materials: UVs too, and the materials and textures for the alpha test
        self.masked = _Raster(ctx, library, "gbuffer_mask", {"frame", "materials", "textures"},
                              [(0, RGB32F, 0), (1, RG32F, 24)])
        self.masked.set.bind("frame", resources["frame"])
        self.resolve = ResolvePass(ctx, library, resources)
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

    def bind(self, resources, targets=None):
        self.resources = resources
        self.resolve.bind(resources)

    def bind_scene(self, geom: SceneGeometry):
        self.resolve.specialize(TEXTURE_ARRAYS=max(1, len(geom.textures)))
        s = self.resolve.set
        for name, view in zip(("vertices", "indices", "tri_info", "materials"), geom.views):
            s.bind(name, view)
        self.masked.set.bind("materials", geom.views[3])
        for slot in range(MAX_TEXTURE_ARRAYS):
            tex = geom.textures.images[slot] if slot < len(geom.textures) else self.white
            for s in (self.resolve.set, self.masked.set):
                s.bind("textures", tex, sampler=self.sampler, element=slot)

    def record(self, rec, targets, geom: SceneGeometry):
        # The visibility image is all zeros here (cleared when made, then by each frame's resolve after reading it),
        # so the raster loads it instead of clearing it (a clear costs GPUs with few raster units).
        # Opaque materials first, keeping early depth tests; then the alpha-tested ones, whose shader discards.
        # Each kind: double-sided materials (no culling), then single-sided ones (back faces culled).
        def draws(masked: bool, single: bool):
            return [(first, count, (np.array([first // 3, material], np.uint32) if masked
                                    else np.uint32(first // 3)).tobytes())
                    for material, first, count in geom.draws
                    if (material in geom.alpha_tested) == masked and (material in geom.single_sided) == single]

        rec.raster(self.raster.pipeline, [self.raster.set], targets.visibility, targets.depth, geom.vertex_buffer,
                   geom.index_buffer, draws(False, False), reads=[self.resources["frame"]],
                   more=[(self.raster.culled, [self.raster.set], draws(False, True)),
                         (self.masked.pipeline, [self.masked.set], draws(True, False)),
                         (self.masked.culled, [self.masked.set], draws(True, True))])
        self.resolve.dispatch(rec, self.resolve.tiles(targets.width, targets.height))
