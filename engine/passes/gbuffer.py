"""G-buffer pass: a visibility raster (the id of the visible triangle per pixel) and a compute resolve into world
position + linear depth, normal, albedo and the material's roughness, metallic, occlusion and emission.

The raster writes 4 bytes per pixel (R32_UINT: triangle + 1, 0 = background) plus depth; `gbuffer_resolve.comp`
then computes what the rasterizer would have interpolated at each pixel centre from the triangle's vertices
(perspective-correct barycentrics from homogeneous edge functions) and samples the albedo texture with the UV
derivatives of the neighbouring pixels (trilinear, anisotropic where the device can; textures are layers of a few
array images, engine/gpu/textures.py). Writing the whole G-buffer from fragments was several times slower on a GPU
with few raster units; the same bytes from compute cost a small fraction of that.

The scene's geometry, materials, textures and instances are engine/gpu/scene.py's `SceneGeometry`: every mesh once
with its levels of detail, a mesh's instances drawn together, one draw per material range. With culling
(engine/passes/cull.py) a compute pass first drops the instances outside the frustum and picks each one's level, and
the draws are indirect, one per run, level and range; without, direct draws of the full meshes. With culling, small
instances may go to a compute raster instead, merged into the visibility image by depth before the resolve
(engine/passes/soft_raster.py). Alpha-tested materials are drawn after the opaque ones by their own pipeline
(gbuffer_mask.vert / .frag, which discards).
Single-sided materials (glTF doubleSided false) are drawn by variants of the same pipelines that cull back faces
(counter-clockwise front faces, as glTF), or front faces for mirrored instances (a negative determinant turns the
winding over; an instance that changes sign makes the geometry again, as a new material override does); double-sided
ones by variants that cull nothing (the resolve turns the normal to the viewer). The ray passes see every triangle
from both sides (shadows and AO of single-sided geometry too).
"""

from __future__ import annotations

import numpy as np

from ..errors import ShaderError
from ..gpu.materials import white_texture
from ..gpu.scene import SceneGeometry
from ..gpu.textures import bind_textures
from ..vk import DescriptorSet, GraphicsPipeline, Sampler, device, reflect
from ..vk.formats import RG32F, RGB32F
from ..vk.pipelines import CULL_BACK, CULL_FRONT, CULL_NONE
from .base import ComputePass, read, update, write
from .cull import CullPass
from .raster_options import RasterOptions
from .soft_raster import SoftMergePass, SoftRasterPass
from .interface import MAX_TEXTURE_ARRAYS
from .targets import DEPTH_FORMAT, VISIBILITY_FORMAT


#: INSTANCES_TEXEL (the raster and the resolve read the instance records through texel views): None = on CPU devices.
INSTANCES_TEXEL = None
#: The texel views of the instances and draw slots that the visibility raster's vertex shaders also declare.
RASTER_TEXEL_BINDINGS = {"instance_texels", "instance_words", "visible_texels"}


class ResolvePass(ComputePass):
    """Visibility -> G-buffer (gbuffer_resolve.comp); the scene's geometry is bound by `bind_scene`."""

    name = "gbuffer_resolve"
    shader = "gbuffer_resolve.comp"
    bindings = {
        "frame": read("uniform", "frame"),
        "visibility": update("image", "visibility"),
        "g_position": write("image", "position"),
        "g_normal": write("image", "normal"),
        "g_albedo": write("image", "albedo"),
        "g_normal8": write("image", "normal8"),
        "vertices": read("uniform_texel"),
        "indices": read("uniform_texel"),
        "tri_info": read("uniform_texel"),
        "materials": read("uniform_texel"),
        "textures": read("texture"),
        "g_depth": write("image", "view_depth"),
        "g_triangle": write("image", "triangle_id"),
        "g_object": write("image", "object_id"),
        "g_material": write("image", "material_id"),
        "g_motion": write("image", "motion"),
        "g_pbr": write("image", "material"),
        "g_emissive": write("image", "emissive"),
        "g_instance": write("image", "instance_id"),
        "g_prev_position": write("image", "prev_position"),
        "g_prev_normal": write("image", "prev_normal"),
        "g_terminator": write("image", "terminator"),
        "instances": read("buffer"),
        "instance_texels": read("uniform_texel"),
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
        self.spirv = self._spirv(library)  # what the pipelines run (hot reload replaces it once they took the new)
        vert, frag = self.spirv
        interface = reflect(vert, f"{stem}.vert").merged(reflect(frag, f"{stem}.frag"))
        self._check(interface)
        self.interface = interface  # what the pipeline layout was made for; hot reload must keep it
        self.set = DescriptorSet(ctx, interface.set(0).values())
        self.values = {"INSTANCES_TEXEL": False}  # set per scene (GBufferPass.bind_scene)
        spec = interface.specialization(self.values, stem)
        # by culling: both sides (double-sided materials), front faces only (single-sided ones), back faces only
        # (single-sided ones of mirrored instances)
        self.pipelines = {
            cull: GraphicsPipeline(
                ctx,
                vert,
                frag,
                [self.set],
                color_formats=[VISIBILITY_FORMAT],
                depth_format=DEPTH_FORMAT,
                vertex_stride=32,
                attributes=attributes,
                push_size=interface.push_size,
                cull=cull,
                spec=spec,
                name=f"{stem} {label}",
            )
            for cull, label in ((CULL_NONE, "two-sided"), (CULL_BACK, "one-sided"), (CULL_FRONT, "one-sided mirrored"))
        }
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
            raise ShaderError(
                f"{self.stem}.vert/.frag: the raster reads {', '.join(sorted(self.bindings))} and "
                f"nothing else; the shaders declare {', '.join(b.name for b in interface.bindings)}"
            )

    def reload(self, library):
        vert, frag = self._spirv(library)
        interface = reflect(vert, f"{self.stem}.vert").merged(reflect(frag, f"{self.stem}.frag"))
        self._check(interface)
        old = self.interface
        if (interface.bindings, interface.push_size) != (old.bindings, old.push_size):
            was = ", ".join(f"{b.name} {b.kind} set {b.set} binding {b.binding}" for b in old.bindings)
            now = ", ".join(f"{b.name} {b.kind} set {b.set} binding {b.binding}" for b in interface.bindings)
            raise ShaderError(
                f"{self.stem}.vert/.frag: their layout changed ({was}, {old.push_size} bytes of push "
                f"constants -> {now}, {interface.push_size} bytes); restart to use them"
            )
        self._build((vert, frag), interface, self.values)  # (the constants' ids as the new shaders have them)
        self.spirv, self.interface = (vert, frag), interface


class GBufferPass:
    """The visibility raster (gbuffer.vert / gbuffer.frag; alpha-tested materials: gbuffer_mask.vert / .frag), the
    software raster of small instances and its merge (engine/passes/soft_raster.py) and the resolve."""

    name = "gbuffer"
    shaders = (
        "gbuffer.vert",
        "gbuffer.frag",
        "gbuffer_mask.vert",
        "gbuffer_mask.frag",
        "gbuffer_resolve.comp",
        "cull.comp",
        "soft_raster.comp",
        "soft_merge.comp",
    )

    def __init__(self, ctx, library, resources):
        self.ctx, self.library = ctx, library
        self.raster = _Raster(ctx, library, "gbuffer", {"frame", "instances", "visible"}, [(0, RGB32F, 0)])
        self.raster.set.bind("frame", resources["frame"])
        # alpha-tested materials: UVs too, and the materials and textures for the alpha test
        self.masked = _Raster(
            ctx,
            library,
            "gbuffer_mask",
            {"frame", "materials", "textures", "instances", "visible"},
            [(0, RGB32F, 0), (1, RG32F, 24)],
        )
        self.masked.set.bind("frame", resources["frame"])
        self.resolve = ResolvePass(ctx, library, resources)
        self.cull = CullPass(ctx, library, resources)
        # the software raster and its merge, where the device has 64-bit buffer atomics (else none: hardware only)
        self.soft = (
            (SoftRasterPass(ctx, library, resources), SoftMergePass(ctx, library, resources))
            if ctx.int64_atomics
            else ()
        )
        self.sampler = Sampler(ctx, anisotropy=device.texture_anisotropy(ctx))
        self.white = white_texture(ctx)
        for s in (self.resolve.set, self.masked.set):  # (until a scene's arrays are bound)
            bind_textures(s, [], self.white, self.sampler)
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
        if not (
            self.soft
            and culling
            and self.ctx.draw_indirect_first_instance
            and self.resources.get("soft_visibility") is not None
        ):
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
        for s in (self.resolve.set, self.masked.set):
            bind_textures(s, geom.textures.images, self.white, self.sampler)

    def record(self, rec, targets, geom: SceneGeometry, options: RasterOptions):
        """The instances' copy to the device, the culling pass (`options.culling`; levels of detail where
        `lod_pixels` > 0; instances of at most `sw_raster_pixels` across to the software raster where `software`),
        the raster, the software raster and its merge, and the resolve."""
        rec.copy(geom.instance_staging, geom.instance_buffer)
        soft = self.software(options.culling, options.sw_raster)
        culling = options.culling and self.ctx.draw_indirect_first_instance
        if culling:
            self.cull.record(
                rec, geom.instance_buffer, geom.tables, options.lod_pixels, options.sw_raster_pixels if soft else 0.0
            )
        # The visibility image is all zeros here (cleared when made, then by each frame's resolve after reading it),
        # so the raster loads it instead of clearing it (a clear costs GPUs with few raster units).
        # Opaque materials first, keeping early depth tests; then the alpha-tested ones, whose shader discards.
        # Opaque then masked; each: double-sided materials (no culling), single-sided ones (back faces culled;
        # front faces for mirrored instances).
        draws = geom.indirect if culling else geom.draws
        passes = [(r, cull) for r in (self.raster, self.masked) for cull in (CULL_NONE, CULL_BACK, CULL_FRONT)]
        lists = [(r.pipelines[cull], [r.set], draws[r is self.masked, cull]) for r, cull in passes]
        rec.raster(
            lists[0][0],
            lists[0][1],
            targets.visibility,
            targets.depth,
            geom.vertex_buffer,
            geom.index_buffer,
            lists[0][2],
            more=lists[1:],
            reads=[self.resources["frame"], geom.instance_buffer, geom.tables.visible],
            indirect=geom.tables.commands if culling else None,
            keep_depth=soft,
        )
        if soft:  # (after the raster in the recording: the GPU may run it while the raster runs)
            self.soft[0].record(rec, geom)
            self.soft[1].record(rec, targets.width, targets.height)
        self.resolve.dispatch(
            rec,
            self.resolve.tiles(targets.width, targets.height),
            push=np.array([geom.instance_count], np.uint32),
            reads=self.resolve.reads + [geom.instance_buffer],
        )
