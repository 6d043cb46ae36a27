"""The G-buffer of cameras whose image no raster makes (OpenCV distortion, fisheye, orthographic, equirectangular;
engine/scene/camera.py ModelCamera): one dispatch of gbuffer_rays.comp generates each pixel's primary ray, traces it
through the ray passes' BVH and fills the same G-buffer images as the raster's resolve, with the resolve's own code
(include/gbuffer_fill.glsl), so shadows, AO, lighting and every AOV follow unchanged.

The rays' camera-space directions are computed on the host in float64 (the model's inverse: `camera_rays`) and kept
in a device buffer of one texel per pixel, rewritten only when the camera's model, intrinsics or the render's size
change; the pose and the previous frame's camera (motion vectors) are a small uniform block written per frame. The
recorded command buffer therefore stays valid while such a camera moves.
"""

from __future__ import annotations

import numpy as np

from ..vk import Buffer, BufferView, device
from ..vk.formats import R32UI, RGBA32F
from ..vk.resources import TRANSFER_DST, UNIFORM, UNIFORM_TEXEL, update_buffer, upload_buffer
from ..gpu.textures import bind_textures
from ..scene.lens import fisheye_limit
from .base import read
from .gbuffer import ResolvePass
from .raypass import RayPass

# shaders/glsl/include/camera_rays.glsl CAMERA_*
KINDS = {"pinhole": 0, "opencv": 1, "fisheye": 2, "orthographic": 3, "equirect": 4}
# std140 CameraModel: to_world (mat4), k, d0, d1 (vec4), kind (uvec4): 32 words; the block holds two
MODEL_WORDS = 32


def traced(camera) -> bool:
    """Does this camera's image come from traced primary rays (every model but the pinhole)?"""
    return getattr(camera, "model", "pinhole") != "pinhole"


def model_record(camera, width: int, height: int) -> np.ndarray:
    """A camera's CameraModel record (32 float32 words, the kind's as uint bits) for a `width` x `height` render."""
    rec = np.zeros(MODEL_WORDS, np.float32)
    rec[0:16] = camera.pose.T.ravel()  # column-major
    K = camera.intrinsics(width, height)
    rec[16:20] = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    model = camera.model
    d = tuple(getattr(camera, "distortion", ()))
    if model == "opencv":
        rec[20:24], rec[24] = d[:4], d[4]
    elif model == "fisheye":
        rec[20:24], rec[25] = d, fisheye_limit(d)
    rec[26] = 0.0 if model == "orthographic" else camera.near
    rec[28:].view(np.uint32)[0] = KINDS[model]
    return rec


class CameraRaysPass(RayPass):
    """Primary rays -> G-buffer (gbuffer_rays.comp): the resolve's bindings but the visibility image, plus the
    camera block, the rays' directions, the BVH-to-resolve triangle table and the alpha test's records; set 1 the
    scene's BVH (shared with the shadow and AO passes)."""

    name = "camera_rays"
    shader = "gbuffer_rays.comp"
    bindings = {
        **{k: v for k, v in ResolvePass.bindings.items() if k != "visibility"},
        "camera": read("uniform"),
        "camera_dirs": read("uniform_texel"),
        "ray_ids": read("uniform_texel"),
        "alpha_tris": read("uniform_texel"),
    }

    def __init__(self, ctx, library, resources, bvh_set, bvh_layout="binary", pixels=1):
        """`pixels`: the render's width x height (the directions buffer's size; `bind` makes it again on a resize)."""
        super().__init__(ctx, library, resources, bvh_set, bvh_layout)
        self.block = Buffer(ctx, 2 * MODEL_WORDS * 4, UNIFORM, host=True, name="camera rays")
        self.set.bind("camera", self.block)
        self._dirs = self._dirs_view = self._ids = self._ids_view = None
        self._dirs_key = self._last = None
        self._make_dirs(pixels)

    def constants(self, ctx) -> dict:
        bvh = {k: v for k, v in super().constants(ctx).items() if k != "WORK_SHARES"}  # (pixels in tile order)
        return {**bvh, "TEXTURE_ARRAYS": 1, "INSTANCES_TEXEL": False}

    def _make_dirs(self, pixels: int):
        """A directions buffer of `pixels` texels, bound (a new size: the recordings were dropped already)."""
        for old in (self._dirs_view, self._dirs):
            if old is not None:
                old.destroy()
        self._dirs = Buffer(self.ctx, 16 * pixels, UNIFORM_TEXEL | TRANSFER_DST, name="camera ray directions")
        self._dirs_view = BufferView(self._dirs, RGBA32F)
        self.set.bind("camera_dirs", self._dirs_view)
        self._dirs_key = None

    def bind(self, resources, targets=None):
        super().bind(resources, targets)
        if targets is not None:
            self.ctx.wait_idle()
            self._make_dirs(targets.width * targets.height)

    def bind_scene(self, geom, scene):
        """The scene's geometry as the resolve reads it, its alpha test, and the BVH-to-resolve triangle table."""
        super().bind_scene(geom)
        self.specialize(INSTANCES_TEXEL=geom.instance_texel_ok and device.is_cpu(self.ctx))  # (as the resolve)
        s = self.set
        for name, view in zip(("vertices", "indices", "tri_info", "materials"), geom.views):
            s.bind(name, view)
        s.bind("instances", geom.instance_buffer)
        s.bind("instance_texels", geom.instance_views[0]).bind("instance_words", geom.instance_views[1])
        bind_textures(s, geom.textures.images, geom.white, geom.sampler)
        for old in (self._ids_view, self._ids):
            if old is not None:
                old.destroy()
        self._ids = upload_buffer(self.ctx, ray_ids(geom, scene), UNIFORM_TEXEL, "camera ray ids")
        self._ids_view = BufferView(self._ids, R32UI)
        s.bind("ray_ids", self._ids_view)

    def set_camera(self, camera, width: int, height: int, previous=None):
        """This frame's camera (and the previous frame's, for motion; None: the same) into the block; the rays'
        directions rewritten where the model, its intrinsics or the size changed."""
        now = model_record(camera, width, height)
        prev = now if previous is None else model_record(previous, width, height)
        block = self.block.view(np.float32)
        block[:MODEL_WORDS], block[MODEL_WORDS:] = now, prev
        key = (camera.model, camera.distortion, tuple(camera.intrinsics(width, height).ravel()), width, height)
        if key != self._dirs_key and camera.model != "orthographic":
            _, dirs = camera.camera_rays(width, height)
            texels = np.zeros((height * width, 4), np.float32)
            texels[:, :3] = dirs.reshape(-1, 3)
            texels[:, 3] = np.any(dirs != 0.0, axis=-1).reshape(-1)
            update_buffer(self.ctx, self._dirs, [(0, texels)])
            self._dirs_key = key

    def record(self, rec, targets, geom):
        """The instances' copy to the device, then the one dispatch."""
        rec.copy(geom.instance_staging, geom.instance_buffer)
        self.dispatch(
            rec,
            self.tiles(targets.width, targets.height),
            push=np.array([geom.instance_count], np.uint32),
            reads=self.reads + [geom.instance_buffer],
        )


def ray_ids(geom, scene) -> np.ndarray:
    """camera_rays.glsl's `ray_ids`: per scene instance its first triangle in the scene's flat order (the BVH's
    triangle ids), its draw slot and where its mesh's ranks start; then each mesh's ranks (the place of each mesh
    triangle in the mesh's first level, whose triangles are sorted by material)."""
    mesh_of = np.asarray(scene.instance_mesh, np.int64)
    n = len(mesh_of)
    flat = np.concatenate([[0], np.cumsum(geom.mesh_triangles[mesh_of])[:-1]]) if n else np.zeros(0, np.int64)
    slot = np.empty(n, np.int64)
    slot[geom.order] = np.arange(n)
    ranks = []
    for src in geom.mesh_first_level:
        rank = np.empty(len(src), np.int64)
        rank[src] = np.arange(len(src))
        ranks.append(rank)
    sizes = np.array([len(r) for r in ranks], np.int64)
    base = np.concatenate([[0], np.cumsum(sizes)[:-1]]) if len(sizes) else np.zeros(0, np.int64)
    table = np.concatenate([flat, slot, base[mesh_of] if n else np.zeros(0, np.int64), *ranks, [0]])
    return table.astype(np.uint32)
