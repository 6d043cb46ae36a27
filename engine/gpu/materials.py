"""A scene's materials on the GPU: the materials texel buffer that the G-buffer resolve and the alpha-tested raster
read (`material_texels`, MATERIAL_TEXELS texels per material: the layout is in engine/passes/interface.py), and
what the rays' alpha test reads (shaders/glsl/include/alpha.glsl): per flattened triangle an alpha word, the alpha
records and the texture arrays they sample (engine/gpu/textures.py). The renderer (engine/gpu/scene.py
`SceneGeometry`) and the Tracer (`scene_alpha`, `untested_alpha`) make them alike.
"""

from __future__ import annotations

import numpy as np

from ..passes.interface import MATERIAL_FLAGS, MATERIAL_TEXELS
from ..scene.material import dielectric_f0, texture_key
from ..vk import BufferView, Sampler, upload_buffer, upload_texture_array
from ..vk.formats import RGBA32F
from ..vk.resources import UNIFORM_TEXEL
from .textures import TEXTURE_KINDS, TextureArrays, bind_textures, scene_textures

WHITE = np.full((1, 1, 4), 255, np.uint8)


def white_texture(ctx):
    """A 1x1 white texture array: what texture bindings without a scene texture hold."""
    return upload_texture_array(ctx, [WHITE], 1, 1, name="white texture")


def material_texels(materials, textures: TextureArrays) -> np.ndarray:
    """The materials texel buffer: MATERIAL_TEXELS RGBA32F texels per material (the layout is in interface.py)."""
    data = np.zeros((max(len(materials), 1), 4 * MATERIAL_TEXELS), np.float32)
    bits = data.view(np.uint32)

    def handle(m, field):
        image = getattr(m, field)
        return textures.handle(None if image is None else (texture_key(image), TEXTURE_KINDS[field]))

    for i, m in enumerate(materials):
        data[i, 0:4] = m.base_color
        bits[i, 4:8] = [
            handle(m, f) for f in ("texture", "metallic_roughness_texture", "normal_texture", "emissive_texture")
        ]
        data[i, 8:12] = m.metallic, m.roughness, m.occlusion_strength, m.normal_scale
        # the raster cuts BLEND out at 0.5, as the hybrid frame's rays do (the path tracer blends it: alpha.glsl)
        data[i, 12:15], data[i, 15] = m.emissive, {"OPAQUE": 0.0, "MASK": m.alpha_cutoff, "BLEND": 0.5}[m.alpha_mode]
        bits[i, 16] = handle(m, "occlusion_texture")
        bits[i, 17] = (
            (MATERIAL_FLAGS["alpha_tested"] if m.alpha_mode != "OPAQUE" else 0)
            | (MATERIAL_FLAGS["double_sided"] if m.double_sided else 0)
            | (MATERIAL_FLAGS["blend"] if m.alpha_mode == "BLEND" else 0)
            | (MATERIAL_FLAGS["transmissive"] if m.transmission > 0 and m.metallic < 1 else 0)
        )
        # (the ior's F0 folded into the specular colour: brdf.glsl's 0.04 colour is then the extensions' F0)
        data[i, 20:23], data[i, 23] = m.specular_color * (dielectric_f0(m.ior) / 0.04), m.specular
        data[i, 24:26] = m.transmission, m.ior
    return data


def alpha_records(scene, textures: TextureArrays) -> tuple[np.ndarray, np.ndarray]:
    """The rays' alpha test (shaders/glsl/include/alpha.glsl): per scene triangle, 0 (opaque) or 1 + its record;
    the records, 2 RGBA32F texels per alpha-tested triangle: (uv0, uv1), (uv2, base texture handle bits,
    threshold): a hit counts where texture alpha >= threshold = cutoff / base alpha; BLEND's threshold is
    -(1 + base alpha), which the kernels with a stochastic alpha test (the path tracer) read as the alpha, and the
    others as the cutoff 0.5 / base alpha (a cut-out). Without
    alpha-tested materials: an empty index (every triangle opaque), and the flat arrays are never made."""
    if all(m.alpha_mode == "OPAQUE" for m in scene.materials):
        return np.zeros(0, np.uint32), np.zeros((1, 8), np.float32)
    tri_mat = scene.vertex_material[scene.indices[:, 0]] if scene.triangle_count else np.zeros(0, np.int64)
    tested = np.array([m.alpha_mode != "OPAQUE" for m in scene.materials] or [False])[tri_mat]
    index = np.zeros(scene.triangle_count, np.uint32)
    prims = np.flatnonzero(tested)
    index[prims] = np.arange(1, len(prims) + 1, dtype=np.uint32)
    records = np.zeros((max(len(prims), 1), 8), np.float32)
    records[: len(prims), 0:6] = scene.uvs[scene.indices[prims]].reshape(-1, 6)
    bits = records.view(np.uint32)
    for k, m in enumerate(scene.materials):
        if m.alpha_mode == "OPAQUE":
            continue
        rows = tri_mat[prims] == k
        base = float(m.base_color[3])
        bits[: len(prims)][rows, 6] = textures.handle(None if m.texture is None else (texture_key(m.texture), True))
        if m.alpha_mode == "BLEND":
            records[: len(prims)][rows, 7] = -(1.0 + base)
        else:
            cutoff = m.alpha_cutoff
            records[: len(prims)][rows, 7] = 0.0 if cutoff == 0 else (cutoff / base if base > 0 else np.inf)
    return index, records


class RayAlpha:
    """What the rays' alpha test reads (the `alpha_tris` and `textures` bindings of alpha.glsl's includers): the
    alpha records' texel view, the texture arrays they sample, a white texture for the arrays' unused elements and
    the sampler. Owns none of them."""

    def __init__(self, records: BufferView, textures: TextureArrays, white, sampler):
        self.records, self.textures, self.white, self.sampler = records, textures, white, sampler

    def bind(self, dset) -> None:
        """The records and texture arrays into a set that declares them (a ray pass's, a trace kernel's set 0)."""
        dset.bind("alpha_tris", self.records)
        bind_textures(dset, self.textures.images, self.white, self.sampler)


def scene_alpha(ctx, scene) -> tuple[RayAlpha, np.ndarray]:
    """The alpha test of a scene with MASK / BLEND materials on its own (the Tracer's), made on `ctx`: its texture
    arrays and alpha records, a white texture and a plain sampler; and the alpha words per flattened triangle
    (`alpha_records`' index, for the BVH's triangle records)."""
    textures = TextureArrays(ctx, scene_textures(scene.materials))
    index, records = alpha_records(scene, textures)
    view = BufferView(upload_buffer(ctx, records, UNIFORM_TEXEL, "alpha records"), RGBA32F)
    return RayAlpha(view, textures, white_texture(ctx), Sampler(ctx)), index


def untested_alpha(ctx) -> RayAlpha:
    """The bindings of kernels without the alpha test (ALPHA_TEST off, so never read): no texture arrays, a 1-texel
    record and a white texture; made on the context itself, once, and shared by its users."""
    root = ctx.root
    with root.memo_lock:
        if "alpha.untested" not in root.memo:
            view = BufferView(
                upload_buffer(root, np.zeros((1, 8), np.float32), UNIFORM_TEXEL, "alpha records"), RGBA32F
            )
            root.memo["alpha.untested"] = RayAlpha(view, TextureArrays(root, {}), white_texture(root), Sampler(root))
        return root.memo["alpha.untested"]
