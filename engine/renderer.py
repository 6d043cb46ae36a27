"""The Renderer: owns the Vulkan context, the render targets and the passes, and orders them into a frame.

    G-buffer raster -> shadow rays -> AO rays -> temporal accumulation -> a-trous denoise
        -> lighting + tonemap -> debug view -> readback

A frame's command buffer is recorded once per (scene, settings) and re-submitted; only the per-frame
uniform block (camera, previous camera, frame index, history reset flag) is rewritten before each submit.

The light masks and AO each go through a `Signal`'s buffers: the ray pass writes `raw`; accumulation blends
it with the reprojected `hist` into `cur` (then copied to `hist` for the next frame); the denoiser ping-pongs
`cur`/`val_b` and writes `final`, which the lighting pass reads. A signal that is not filtered this frame
(hard / seed-delta / reference shadows, AO off) has `raw` copied to `final`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import vulkan as vk

from .bvh import build_bvh
from .errors import ConfigError, EngineError, VulkanError
from .passes import frame_data as fd
from .passes.frame_data import FRAME_BYTES, MAX_LIGHTS, pack_frame, pack_light
from .passes.gbuffer import (ALBEDO_FORMAT, DEPTH_FORMAT, NORMAL_FORMAT, POSITION_FORMAT, VISIBILITY_FORMAT,
                             GBufferPass, SceneGeometry)
from .passes.accumulate import ALPHA_MIN, FILTER_AO, FILTER_MASKS, FILTER_TEMPORAL, AccumulatePass
from .passes.ao import AOPass
from .passes.debug_view import DebugViewPass
from .passes.denoise import DenoisePass
from .passes.lighting import LightingPass
from .passes.shadows import ShadowPass
from .rt.tracer import SceneBVH, bvh_descriptor_set
from .rt.tracer import bvh_layout as resolve_layout
from .scene import Scene
from .scene.camera import Camera
from .settings import DEFAULT_SETTINGS, check_png_path, check_settings, check_size
from .shaders import ShaderLibrary
from .vk import Buffer, BufferView, Context, Image, Timestamps, image_barrier, memory_barrier
from .vk.resources import STORAGE, STORAGE_TEXEL, TRANSFER_DST, TRANSFER_SRC, UNIFORM

ONE_F32 = 0x3F800000  # bit pattern of 1.0f, for vkCmdFillBuffer
WHOLE_SIZE = 0xFFFFFFFFFFFFFFFF

@dataclass
class Frame:
    """One rendered frame: `color` (H, W, 4) uint8 sRGB, `aov` float32 arrays, `timings` GPU ms per pass."""

    color: np.ndarray
    aov: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    settings: dict = field(default_factory=dict)

    def save(self, path, aov: str | None = None):
        """Write the colour (or an AOV, normalized for viewing) as PNG (`path` ends in .png)."""
        from PIL import Image as PILImage
        check_png_path(path)
        img = self.color if aov is None else aov_to_rgba(self, aov)
        try:
            PILImage.fromarray(img, "RGBA").save(str(path))
        except (OSError, ValueError) as exc:
            raise EngineError(f"{path}: cannot write image: {exc}") from None


def aov_to_rgba(frame: Frame, name: str) -> np.ndarray:
    """A viewable 8-bit image of an AOV: normals mapped to [0, 1], depth and position normalized."""
    if name == "color":
        return frame.color
    if name not in frame.aov:
        raise ConfigError(f"aov {name!r}: not in this frame (have: {', '.join(sorted(frame.aov))})")
    a = np.asarray(frame.aov[name], np.float32)
    cover = frame.aov["depth"] < np.inf
    if name == "normal":
        rgb = np.where(cover[..., None], a * 0.5 + 0.5, 0.0)
    elif name == "depth":
        d = np.where(cover, a, np.nan)
        lo, hi = (np.nanmin(d), np.nanmax(d)) if cover.any() else (0.0, 1.0)
        rgb = np.repeat(np.where(cover, 1.0 - (a - lo) / max(hi - lo, 1e-12), 0.0)[..., None], 3, axis=2)
    elif name == "position":
        lo, hi = (a[cover].min(0), a[cover].max(0)) if cover.any() else (0.0, 1.0)
        rgb = np.where(cover[..., None], (a - lo) / np.maximum(hi - lo, 1e-12), 0.0)
    elif name == "albedo":
        rgb = np.clip(a, 0, 1) ** (1 / 2.2)
    elif name in ("shadow", "shadow_raw"):  # per-light masks: average over lights
        rgb = np.repeat(a.mean(axis=2, keepdims=True), 3, axis=2) if a.shape[2] else np.ones(a.shape[:2] + (3,))
    elif name == "history":  # frames of history: white from 32 on
        rgb = np.repeat(np.clip(a / 32.0, 0.0, 1.0)[..., None], 3, axis=2)
    elif a.ndim == 2:
        rgb = np.repeat(a[..., None], 3, axis=2)
    else:
        rgb = a
    rgb = np.clip(np.nan_to_num(rgb), 0.0, 1.0)
    out = np.empty(rgb.shape[:2] + (4,), np.uint8)
    out[..., :3] = np.round(rgb * 255)
    out[..., 3] = 255
    return out


class Signal:
    """The buffers one filtered per-pixel signal goes through in a frame: the light masks (`channels` = lights,
    light-major [channel][y][x] floats) or AO (1 channel). See the module docstring for the flow."""

    NAMES = ("raw", "cur", "hist", "var_a", "val_b", "var_b", "final")
    #: The parts the denoiser reads, also as R32F storage texel buffers (`views`; denoise.comp constant 0).
    READ = ("cur", "var_a", "val_b", "var_b")

    def __init__(self, ctx, name, n_pixels, channels):
        usage = STORAGE | STORAGE_TEXEL | TRANSFER_SRC | TRANSFER_DST
        for part in self.NAMES:
            setattr(self, part, Buffer(ctx, n_pixels * 4 * channels, usage, name=f"{name} {part}"))
        # (a GPU, which reads the storage buffers, may allow larger storage buffers than texel buffers: the views
        # are then of the buffers' first maxTexelBufferElements floats, never read there)
        size = min(n_pixels * 4 * channels, int(ctx.limits.maxTexelBufferElements) * 4)
        self.texel_ok = size == n_pixels * 4 * channels  # the views hold the whole signal (the denoiser may read them)
        self.views = {part: BufferView(getattr(self, part), vk.VK_FORMAT_R32_SFLOAT, 0, size) for part in self.READ}

    def buffers(self):
        """Everything to destroy, the views before their buffers."""
        return list(self.views.values()) + [getattr(self, part) for part in self.NAMES]


class Targets:
    """Every per-size image and buffer of a frame, plus the host buffer the frame is read back into."""

    def __init__(self, ctx, width, height, light_capacity):
        self.width, self.height, self.light_capacity = width, height, light_capacity
        n = width * height
        self.check_capacity(ctx, width, height, light_capacity)
        att = vk.VK_IMAGE_USAGE_STORAGE_BIT | vk.VK_IMAGE_USAGE_TRANSFER_SRC_BIT   # written by the G-buffer resolve
        self.visibility = Image(ctx, width, height, VISIBILITY_FORMAT, vk.VK_IMAGE_USAGE_COLOR_ATTACHMENT_BIT
                                | vk.VK_IMAGE_USAGE_STORAGE_BIT | vk.VK_IMAGE_USAGE_TRANSFER_DST_BIT, name="visibility")
        self.position = Image(ctx, width, height, POSITION_FORMAT, att, name="position")
        self.normal = Image(ctx, width, height, NORMAL_FORMAT, att, name="normal")
        self.albedo = Image(ctx, width, height, ALBEDO_FORMAT, att, name="albedo")
        self.gbuffer = [self.position, self.normal, self.albedo]
        # The normal in 4 bytes for the denoiser (written by the G-buffer resolve)
        self.normal8 = Image(ctx, width, height, vk.VK_FORMAT_R8G8B8A8_SNORM, vk.VK_IMAGE_USAGE_STORAGE_BIT,
                             name="normal (8-bit)")
        self.depth = Image(ctx, width, height, DEPTH_FORMAT, vk.VK_IMAGE_USAGE_DEPTH_STENCIL_ATTACHMENT_BIT)
        out_usage = (vk.VK_IMAGE_USAGE_STORAGE_BIT | vk.VK_IMAGE_USAGE_TRANSFER_SRC_BIT)
        self.color = Image(ctx, width, height, vk.VK_FORMAT_R8G8B8A8_UNORM, out_usage, name="color")
        self.hdr = Image(ctx, width, height, vk.VK_FORMAT_R16G16B16A16_SFLOAT, out_usage, name="hdr")
        # The previous frame's G-buffer position and normal (temporal reprojection / disocclusion tests).
        hist_usage = vk.VK_IMAGE_USAGE_STORAGE_BIT | vk.VK_IMAGE_USAGE_TRANSFER_DST_BIT
        self.hist_position = Image(ctx, width, height, POSITION_FORMAT, hist_usage, name="history position")
        self.hist_normal = Image(ctx, width, height, NORMAL_FORMAT, hist_usage, name="history normal")
        self.signals = {"masks": Signal(ctx, "masks", n, light_capacity), "ao": Signal(ctx, "ao", n, 1)}
        buf_usage = STORAGE | TRANSFER_SRC | TRANSFER_DST
        self.len_cur = Buffer(ctx, n * 4, buf_usage, name="history length")
        self.len_hist = Buffer(ctx, n * 4, buf_usage, name="previous history length")
        # What the lighting pass reads, and what the ray passes write.
        self.masks, self.ao = self.signals["masks"].final, self.signals["ao"].final
        self.masks_raw, self.ao_raw = self.signals["masks"].raw, self.signals["ao"].raw
        # Readback layout: colour, position, normal, albedo, masks, ao, raw masks, raw ao, history length.
        self.offsets = {}
        off = 0
        for name, size in (("color", n * 4), ("position", n * 16), ("normal", n * 16), ("albedo", n * 8),
                           ("masks", n * 4 * light_capacity), ("ao", n * 4), ("masks_raw", n * 4 * light_capacity),
                           ("ao_raw", n * 4), ("history", n * 4)):
            off = -(-off // 16) * 16  # a copy's buffer offset is a multiple of its texel size (16 B at most here)
            self.offsets[name] = off
            off += size
        self.readback = Buffer(ctx, off, TRANSFER_DST, host=True, name="readback")
        self._objects = [self.visibility, self.normal8, self.position, self.normal, self.albedo, self.depth,
                         self.color, self.hdr, self.hist_position, self.hist_normal, self.len_cur, self.len_hist,
                         self.readback]
        for sig in self.signals.values():
            self._objects += sig.buffers()
        with ctx.one_shot() as cmd:
            for img in (self.color, self.hdr, self.hist_position, self.hist_normal):
                image_barrier(cmd, img, vk.VK_IMAGE_LAYOUT_UNDEFINED, vk.VK_IMAGE_LAYOUT_GENERAL,
                              vk.VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, vk.VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                              0, vk.VK_ACCESS_SHADER_WRITE_BIT)
            # the visibility image starts as background; each frame's G-buffer resolve leaves it so again
            image_barrier(cmd, self.visibility, vk.VK_IMAGE_LAYOUT_UNDEFINED, vk.VK_IMAGE_LAYOUT_GENERAL,
                          vk.VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, vk.VK_PIPELINE_STAGE_TRANSFER_BIT,
                          0, vk.VK_ACCESS_TRANSFER_WRITE_BIT)
            vk.vkCmdClearColorImage(cmd, self.visibility.handle, vk.VK_IMAGE_LAYOUT_GENERAL,
                                    vk.VkClearColorValue(uint32=[0, 0, 0, 0]), 1, [self.visibility.range()])
            memory_barrier(cmd, vk.VK_PIPELINE_STAGE_TRANSFER_BIT, vk.VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT,
                           vk.VK_ACCESS_TRANSFER_WRITE_BIT,
                           vk.VK_ACCESS_COLOR_ATTACHMENT_READ_BIT | vk.VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT)
            for buf in (self.len_cur, self.len_hist):   # defined contents for the history-length AOV
                vk.vkCmdFillBuffer(cmd, buf.handle, 0, WHOLE_SIZE, 0)

    @staticmethod
    def check_capacity(ctx, width, height, lights):
        """The light masks are one storage buffer per stage, light-major: it must fit the device's
        maxStorageBufferRange (128 MiB on lavapipe: 16 lights at 1920x1080, 8 up to 2560x1600)."""
        need, limit = width * height * 4 * max(lights, 1), int(ctx.limits.maxStorageBufferRange)
        if need > limit:
            raise ConfigError(
                f"size {width}x{height} with {lights} lights: the light masks need {need / 2**20:.1f} MiB per "
                f"buffer, over this device's maxStorageBufferRange of {limit / 2**20:.0f} MiB; use fewer lights "
                f"or a smaller size")

    def record_readback(self, cmd):
        """Copy every target into the host buffer (after the lighting pass)."""
        w, h = self.width, self.height
        sub = vk.VkImageSubresourceLayers(vk.VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1)
        for name, img in (("color", self.color), ("position", self.position), ("normal", self.normal),
                          ("albedo", self.albedo)):
            region = vk.VkBufferImageCopy(bufferOffset=self.offsets[name], bufferRowLength=0, bufferImageHeight=0,
                                          imageSubresource=sub, imageOffset=vk.VkOffset3D(0, 0, 0),
                                          imageExtent=vk.VkExtent3D(w, h, 1))
            vk.vkCmdCopyImageToBuffer(cmd, img.handle, vk.VK_IMAGE_LAYOUT_GENERAL, self.readback.handle, 1, [region])
        for name, buf in (("masks", self.masks), ("ao", self.ao), ("masks_raw", self.masks_raw),
                          ("ao_raw", self.ao_raw), ("history", self.len_cur)):
            vk.vkCmdCopyBuffer(cmd, buf.handle, self.readback.handle, 1,
                               [vk.VkBufferCopy(0, self.offsets[name], buf.size)])
        memory_barrier(cmd, vk.VK_PIPELINE_STAGE_TRANSFER_BIT, vk.VK_PIPELINE_STAGE_HOST_BIT,
                       vk.VK_ACCESS_TRANSFER_WRITE_BIT, vk.VK_ACCESS_HOST_READ_BIT)

    def read(self, n_lights) -> tuple[np.ndarray, dict]:
        w, h = self.width, self.height
        n = w * h
        raw = self.readback.view(np.uint8)

        def part(name, dtype, count, shape):
            o = self.offsets[name]
            return np.frombuffer(raw[o:o + count * np.dtype(dtype).itemsize].tobytes(), dtype).reshape(shape)

        def masks(name):
            m = part(name, np.float32, n * max(n_lights, 1), (max(n_lights, 1), h, w))[:n_lights]
            return np.ascontiguousarray(np.moveaxis(m, 0, -1))

        color = part("color", np.uint8, n * 4, (h, w, 4)).copy()
        pos = part("position", np.float32, n * 4, (h, w, 4))
        nrm = part("normal", np.float32, n * 4, (h, w, 4))
        alb = part("albedo", np.float16, n * 4, (h, w, 4)).astype(np.float32)
        cover = nrm[..., 3] > 0
        depth = np.where(cover, pos[..., 3], np.inf).astype(np.float32)
        aov = {
            "position": np.ascontiguousarray(pos[..., :3]),
            "normal": np.ascontiguousarray(nrm[..., :3]),
            "albedo": np.ascontiguousarray(alb[..., :3]),
            "depth": depth,
            "shadow": masks("masks"),              # what the lighting used (accumulated + denoised for soft)
            "shadow_raw": masks("masks_raw"),      # this frame's rays alone
            "ao": part("ao", np.float32, n, (h, w)).copy(),
            "ao_raw": part("ao_raw", np.float32, n, (h, w)).copy(),
            "history": part("history", np.float32, n, (h, w)).copy(),   # frames accumulated (0: none)
        }
        return color, aov

    def destroy(self):
        for obj in self._objects:
            obj.destroy()


class Renderer:
    """Headless hybrid renderer. `with Renderer(640, 360) as r: frame = r.render(scene)`."""

    def __init__(self, width: int, height: int, *, device=None, validation: bool = False,
                 shader_dir=None, hot_reload: bool = False, context: Context | None = None,
                 bvh_layout: str | None = None):
        """`context`: render on an existing Context (the viewer's, which has a surface); it is not closed here.
        `bvh_layout`: "binary" or "wide" scene BVH for the shadow and AO passes (default: $HYBRID_BVH_LAYOUT, else
        "binary"; engine.rt.tracer.bvh_layout)."""
        self.bvh_layout = resolve_layout(bvh_layout)  # a bad one fails here, before any Vulkan object exists
        check_size(width, height)
        self.width, self.height = int(width), int(height)
        self.library = ShaderLibrary(shader_dir, hot_reload=hot_reload)
        self.ctx = None
        self._validation_errors: list[str] = []
        self._owns_ctx = context is None
        self._commands: dict = {}          # set before anything can fail, so close() always works
        self._steady = None                # _Steady: the last frame's inputs, for re-submitting it cheaply
        self._geometry = self._scene_bvh = self.targets = None
        try:
            if context is not None:
                if not isinstance(context, Context):
                    raise ConfigError(f"Renderer: context must be an engine.vk.Context, got {type(context).__name__}")
                context.check_open("Renderer")   # a destroyed device would abort the process in the first call
            self.ctx = context if context is not None else Context(device=device, validation=validation or None)
            self._validation_errors = self.ctx.validation_errors  # the same list: still readable after close()
            self._init_gpu()
        except BaseException:
            self.close()
            raise

    def _init_gpu(self):
        ctx = self.ctx
        if not ctx.geometry_shader:
            raise VulkanError(f"device {ctx.device_info['name']!r} lacks the geometryShader feature, which the "
                              "G-buffer's visibility pass needs (gl_PrimitiveID in a fragment shader); the Tracer "
                              "works without it")
        self.frame_ubo = Buffer(ctx, FRAME_BYTES, UNIFORM, host=True, name="frame")
        self._ubo_f32 = self.frame_ubo.view(np.float32)   # the mapped frame block (FRAME_BLOCK), written in place
        self._ubo_u32 = self.frame_ubo.view(np.uint32)
        self.timestamps = Timestamps(ctx)
        self.targets = Targets(ctx, self.width, self.height, light_capacity=1)
        self.bvh_set = bvh_descriptor_set(ctx)
        self.gbuffer = GBufferPass(ctx, self.library, self.frame_ubo, self.targets)
        self.shadows = ShadowPass(ctx, self.library, self.frame_ubo, self.bvh_set, self.targets, self.bvh_layout)
        self.ao = AOPass(ctx, self.library, self.frame_ubo, self.bvh_set, self.targets, self.bvh_layout)
        self.accumulate = AccumulatePass(ctx, self.library, self.frame_ubo, self.targets)
        self.denoise = DenoisePass(ctx, self.library, self.frame_ubo, self.targets)
        self.lighting = LightingPass(ctx, self.library, self.frame_ubo, self.targets)
        self.debug_view = DebugViewPass(ctx, self.library, self.frame_ubo, self.targets)
        self.passes = [self.gbuffer, self.shadows, self.ao, self.accumulate, self.denoise, self.lighting,
                       self.debug_view]
        self._scene = None
        self._geometry = None
        self._scene_bvh = None
        self.bvh_stats = {}
        self._commands: dict = {}
        self._frame_index = 0
        self._prev_view_proj = None
        self._history_key = None   # what the temporal history was accumulated under (None: no valid history)
        self._steady = None
        self.uploads = 0  # scene uploads so far (a test reads it: the same scene is uploaded once)

    # ---- public ---------------------------------------------------------------------------
    @property
    def validation_errors(self) -> list[str]:
        """Error-severity validation messages so far (leaks found at close() included)."""
        return self._validation_errors

    @property
    def shader_errors(self) -> dict[str, str]:
        return dict(self.library.errors)

    @property
    def device_name(self) -> str:
        return self.ctx.device_info["name"]

    def render(self, scene, camera=None, **settings) -> Frame:
        """Render one frame and read everything back: colour, AOVs and GPU timings."""
        cmd, marks, cfg, n_lights = self._prepare(scene, camera, settings, readback=True)
        self.ctx.submit(cmd)
        color, aov = self.targets.read(n_lights)
        return Frame(color=color, aov=aov, timings=self.timestamps.read(marks), settings=cfg)

    def submit(self, scene, camera=None, *, wait=True, signal_semaphores=(), fence=None, **settings):
        """Render one frame into `self.targets.color` without reading it back (the viewer's path).

        With wait=False the caller synchronizes through `signal_semaphores` / `fence`, and reads
        `last_timings()` once that frame has finished."""
        cmd, marks, cfg, _ = self._prepare(scene, camera, settings, readback=False)
        self._last_marks = marks
        self.ctx.submit(cmd, wait=wait, signal_semaphores=signal_semaphores, fence=fence)
        return cfg

    def last_timings(self) -> dict[str, float]:
        """GPU ms per pass of the last submitted frame (blocks until its queries are available)."""
        return self.timestamps.read(self._last_marks) if getattr(self, "_last_marks", None) else {}

    def resize(self, width: int, height: int):
        """New render size: targets are recreated and recorded command buffers dropped."""
        check_size(width, height)
        if (width, height) != (self.width, self.height):
            Targets.check_capacity(self.ctx, width, height, self.targets.light_capacity)
            self.width, self.height = int(width), int(height)
            self._resize_targets(self.targets.light_capacity)

    def _prepare(self, scene, camera, settings, readback):
        if self.ctx is None:
            raise EngineError("render() on a closed Renderer")
        self.ctx.check_open("Renderer.render()")   # a shared context its owner closed: no Vulkan call may follow
        polled = False
        if self._steady is not None:
            self._poll_shaders()   # a reload drops the recorded commands, and with them self._steady
            polled = True
            steady = self._steady
            if steady is not None:
                cam = camera if camera is not None else scene.camera
                if steady.same(scene, settings, readback):
                    if cam is steady.camera:
                        return self._prepare_steady(steady)
                    if isinstance(cam, Camera):
                        return self._prepare_moved(steady, cam)
        self._steady = None
        if not isinstance(scene, Scene):
            raise ConfigError(f"render(): scene must be an engine.Scene (Scene.load(path)), got {type(scene).__name__}")
        if camera is not None and not isinstance(camera, Camera):
            raise ConfigError(f"render(): camera must be an engine.Camera or None, got {type(camera).__name__}")
        own = getattr(scene, "settings", None) or {}
        try:
            cfg = check_settings({**own, **settings})
        except ConfigError as exc:   # where the bad setting came from: the scene's [settings] (not overridden)?
            try:
                check_settings({k: v for k, v in own.items() if k not in settings})
            except ConfigError as own_exc:
                raise ConfigError(f"{scene.name}: [settings]: {own_exc}") from None
            raise exc from None
        camera = camera if camera is not None else scene.camera
        if not polled:
            self._poll_shaders()
        self._use_scene(scene)
        lights = list(scene.lights)
        if len(lights) > MAX_LIGHTS:
            raise ConfigError(f"{scene.name}: {len(lights)} lights, at most {MAX_LIGHTS} are supported")
        if len(lights) > self.targets.light_capacity:
            self._resize_targets(light_capacity=len(lights))

        aspect = self.width / self.height
        view_proj = camera.projection_matrix(aspect) @ camera.view_matrix()
        diag = float(np.linalg.norm(scene.bounds[1] - scene.bounds[0])) or 1.0
        # The temporal history holds the light masks and AO as traced under these: when any of them changes
        # (another scene, light, shadow mode or sample count, size), the next frame starts over.
        packed_lights = [pack_light(l) for l in lights]
        history_key = (scene.uid if hasattr(scene, "uid") else id(scene), self.width, self.height,
                       b"".join(p.tobytes() for p in packed_lights),
                       tuple(cfg[k] for k in ("shadows", "shadow_samples", "ao", "ao_samples", "ao_radius",
                                              "accumulate")))
        reset = history_key != self._history_key
        shadow_samples = cfg["reference_samples"] if cfg["shadows"] == "reference" else cfg["shadow_samples"]
        ao_samples = cfg["reference_samples"] if cfg["shadows"] == "reference" else cfg["ao_samples"]
        pack_frame(
            view_proj=view_proj,
            prev_view_proj=self._prev_view_proj if self._prev_view_proj is not None and not reset else view_proj,
            eye=camera.eye, forward=camera.forward, near=camera.near, width=self.width, height=self.height,
            frame_index=self._frame_index, lights=lights,
            ao_radius=cfg["ao_radius"] or 0.1 * diag, ao_samples=ao_samples, shadow_samples=shadow_samples,
            exposure=cfg["exposure"], ambient=cfg["ambient"], scene_scale=diag, accum_alpha=ALPHA_MIN,
            pixel_footprint=2.0 * math.tan(math.radians(camera.fov_y) / 2.0) / self.height,
            history_reset=reset, bounds=scene.bounds, out=self._ubo_f32, packed_lights=packed_lights)
        key = (cfg["shadows"], cfg["ao"], cfg["accumulate"], cfg["denoise"], cfg["view"], len(lights), readback)
        if cfg["shadows"] == "reference":
            key += (cfg["reference_samples"],)
        if key not in self._commands:
            cmd = self._record(cfg, len(lights), readback)
            self._commands[key] = (cmd, list(self.timestamps.names))
        cmd, marks = self._commands[key]
        self._frame_index += 1
        self._prev_view_proj = view_proj
        self._history_key = history_key
        self._steady = _Steady.capture(scene, camera, settings, readback, lights, view_proj,
                                       (cmd, marks, cfg, len(lights)))
        return cmd, marks, dict(cfg), len(lights)

    def _prepare_steady(self, steady):
        """The same scene, lights, camera and settings as the last frame: its command buffer, and a frame block
        that differs from the last one only in the frame index (plus, on the first such frame, the previous
        camera, now this one, and the history-reset flag, now off). What the full path would write, bit for bit."""
        if not steady.settled:
            self._ubo_f32[fd.PREV_VIEW_PROJ] = steady.view_proj_cols   # prev_view_proj = this camera's
            self._ubo_f32[fd.HISTORY_RESET] = 0.0                      # the history key is unchanged
            steady.settled = True
        self._ubo_u32[fd.FRAME_INDEX] = self._frame_index
        self._frame_index += 1
        cmd, marks, cfg, n_lights = steady.result
        return cmd, marks, dict(cfg), n_lights

    def _prepare_moved(self, steady, camera):
        """As the last frame but for the camera (the viewer while flying): the camera's fields of the frame block
        are rewritten, the rest (lights, settings, scene) stays; the temporal history is kept, as the full path
        keeps it (the camera is not part of the history key)."""
        view_proj = camera.projection_matrix(self.width / self.height) @ camera.view_matrix()
        f32 = self._ubo_f32
        f32[fd.VIEW_PROJ] = view_proj.T.reshape(-1)
        f32[fd.PREV_VIEW_PROJ] = steady.view_proj_cols   # the last frame's camera
        f32[fd.EYE], f32[fd.NEAR] = camera.eye, camera.near
        f32[fd.FORWARD] = camera.forward
        f32[fd.PIXEL_FOOTPRINT] = 2.0 * math.tan(math.radians(camera.fov_y) / 2.0) / self.height
        f32[fd.HISTORY_RESET] = 0.0                      # the history key is unchanged
        self._ubo_u32[fd.FRAME_INDEX] = self._frame_index
        self._frame_index += 1
        self._prev_view_proj = view_proj
        steady.camera, steady.settled = camera, False
        steady.view_proj_cols = np.asarray(view_proj, np.float32).T.reshape(-1)
        cmd, marks, cfg, n_lights = steady.result
        return cmd, marks, dict(cfg), n_lights

    def close(self):
        if self.ctx is not None:
            if self._owns_ctx:
                self.ctx.close()
            elif self.ctx.closed:  # its owner closed it first: the device, and all made on it, is gone already
                pass
            else:  # a shared context: free what this renderer made, leave the rest to its owner
                self.ctx.wait_idle()
                self._invalidate_commands()
                self._release_owned()
            self.ctx = None
        if getattr(self, "library", None) is not None:
            self.library.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # ---- internals ------------------------------------------------------------------------
    def _poll_shaders(self):
        updated = self.library.poll()
        if not updated:
            return
        for p in self.passes:
            if updated & set(p.shaders):
                try:
                    p.reload(self.library)
                except EngineError as exc:
                    self.library.errors[str(self.library.glsl_dir / p.shaders[-1])] = str(exc)
        self._invalidate_commands()

    def _release_owned(self):
        """Destroy this renderer's objects on a shared context (its defer list would hold them until the end)."""
        for obj in (self._geometry, self._scene_bvh):
            if obj is not None:
                obj.destroy()
        self._geometry = self._scene_bvh = None
        if self.targets is not None:
            self.targets.destroy()

    def _invalidate_commands(self):
        self._steady = None
        if self._commands:
            self.ctx.wait_idle()
            for cmd, _ in self._commands.values():
                self.ctx.free_command_buffer(cmd)
            self._commands.clear()

    def _use_scene(self, scene):
        if scene is self._scene:
            return
        self._steady = None
        self._invalidate_commands()
        self.ctx.wait_idle()
        for old in (self._geometry, self._scene_bvh):
            if old is not None:
                old.destroy()
        self._geometry = self._scene_bvh = None
        self._geometry = SceneGeometry(self.ctx, scene, self.gbuffer.white, self.gbuffer.sampler)
        self.gbuffer.bind_scene(self._geometry)
        self._scene_bvh = SceneBVH.upload(self.ctx, build_bvh(scene.positions, scene.indices), self.bvh_set,
                                          self.bvh_layout)
        self.bvh_stats = dict(self._scene_bvh.bvh.stats, layout=self.bvh_layout)
        for p in (self.shadows, self.ao):   # the traversal specialized to this BVH (its depth, its node layout)
            p.specialize(self.library, self._scene_bvh.spec(self.ctx, postpone=p.postpone_leaves))
        self._scene = scene
        self._prev_view_proj = None
        self.uploads += 1

    def _resize_targets(self, light_capacity):
        Targets.check_capacity(self.ctx, self.width, self.height, light_capacity)
        self._invalidate_commands()
        self.ctx.wait_idle()
        self.targets.destroy()
        self.targets = Targets(self.ctx, self.width, self.height, light_capacity)
        for p in (self.gbuffer, self.shadows, self.ao, self.accumulate, self.denoise, self.lighting, self.debug_view):
            p.bind_targets(self.targets)
        self._history_key = None
        self._steady = None

    def _record(self, cfg, n_lights, readback=True):
        ctx, t = self.ctx, self.targets
        cmd = ctx.allocate_command_buffer()
        vk.vkBeginCommandBuffer(cmd, vk.VkCommandBufferBeginInfo())
        ts = self.timestamps
        ts.begin(cmd)
        self.gbuffer.record(cmd, t, self._geometry)
        ts.mark(cmd, "gbuffer")
        mode = cfg["shadows"]
        reference = cfg["reference_samples"] if mode == "reference" else None
        if mode == "off" or n_lights == 0:
            vk.vkCmdFillBuffer(cmd, t.masks_raw.handle, 0, WHOLE_SIZE, ONE_F32)
        else:
            self.shadows.record(cmd, t, mode, n_lights=n_lights, reference_samples=reference)
        ts.mark(cmd, "shadows")
        if cfg["ao"]:
            self.ao.record(cmd, t, reference_samples=reference)
        else:
            vk.vkCmdFillBuffer(cmd, t.ao_raw.handle, 0, WHOLE_SIZE, ONE_F32)
        ts.mark(cmd, "ao")
        _barrier(cmd)

        # Which signals are filtered: soft light masks and (outside the reference mode) AO.
        filtered = []
        if mode == "soft" and n_lights and (cfg["accumulate"] or cfg["denoise"]):
            filtered.append("masks")
        if cfg["ao"] and mode != "reference" and (cfg["accumulate"] or cfg["denoise"]):
            filtered.append("ao")
        flags = (FILTER_MASKS if "masks" in filtered else 0) | (FILTER_AO if "ao" in filtered else 0)
        if filtered:
            self.accumulate.record(cmd, t, flags | (FILTER_TEMPORAL if cfg["accumulate"] else 0), n_lights)
            _barrier(cmd)
            if cfg["accumulate"]:
                self.accumulate.record_history_copy(cmd, t, filtered)
                _barrier(cmd)
            ts.mark(cmd, "accumulate")
            if cfg["denoise"]:
                self.denoise.record(cmd, t, flags, n_lights)
                ts.mark(cmd, "denoise")
                _barrier(cmd)
            else:
                for name in filtered:
                    _copy(cmd, t.signals[name].cur, t.signals[name].final)
        else:
            vk.vkCmdFillBuffer(cmd, t.len_cur.handle, 0, WHOLE_SIZE, 0)
        for name in ("masks", "ao"):
            if name not in filtered:
                _copy(cmd, t.signals[name].raw, t.signals[name].final)
        _barrier(cmd)
        self.lighting.record(cmd, t)
        ts.mark(cmd, "lighting")
        if cfg["view"] != "color":
            _barrier(cmd)
            self.debug_view.record(cmd, t, cfg["view"])
            ts.mark(cmd, "view")
        memory_barrier(cmd, vk.VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, vk.VK_PIPELINE_STAGE_TRANSFER_BIT,
                       vk.VK_ACCESS_SHADER_WRITE_BIT, vk.VK_ACCESS_TRANSFER_READ_BIT)
        if readback:
            t.record_readback(cmd)
            ts.mark(cmd, "readback")
        vk.vkEndCommandBuffer(cmd)
        return cmd


_MISSING = object()
_PLAIN = (str, bool, int, float, type(None), np.generic)


def _snapshot(settings) -> dict | None:
    """A copy of a settings dict that later calls are compared with (`_same_settings`), or None when a value is
    not a plain scalar or a list / tuple of them (such calls always take the full path)."""
    out = {}
    for key, value in settings.items():
        if isinstance(value, (list, tuple)):
            if not all(isinstance(x, _PLAIN) for x in value):
                return None
            out[key] = (type(value), tuple(value))
        elif isinstance(value, _PLAIN):
            out[key] = (type(value), value)
        else:
            return None
    return out


def _same_value(value, snap) -> bool:
    kind, held = snap
    if type(value) is not kind:
        return False
    if kind is list or kind is tuple:
        return len(value) == len(held) and all(
            type(a) is type(b) and bool(a == b) for a, b in zip(value, held))
    return value is held or bool(value == held)


def _same_settings(settings, snap) -> bool:
    if len(settings) != len(snap):
        return False
    for key, value in settings.items():
        held = snap.get(key, _MISSING)
        if held is _MISSING or not _same_value(value, held):
            return False
    return True


class _Steady:
    """What the last frame was prepared from, to tell whether the next one is the same frame again: the same
    scene, camera and lights (by identity: cameras are immutable, and a light's attributes are compared by
    identity too, so an assigned attribute counts as a change) and equal settings (same values and types)."""

    __slots__ = ("scene", "camera", "readback", "bounds", "lights", "settings", "scene_settings", "view_proj_cols",
                 "settled", "result")

    @classmethod
    def capture(cls, scene, camera, settings, readback, lights, view_proj, result):
        """The state after a full `_prepare`, or None when it cannot be compared cheaply (then every frame takes
        the full path)."""
        snap = _snapshot(settings)
        scene_snap = _snapshot(getattr(scene, "settings", None) or {})
        if snap is None or scene_snap is None or not hasattr(scene.lights, "__len__"):
            return None
        held = []
        for light in lights:
            attrs = getattr(light, "__dict__", None)
            if attrs is None or any(getattr(c, "__slots__", ()) for c in type(light).__mro__):
                return None
            held.append((light, tuple(attrs.values())))
        self = cls()
        self.scene, self.camera, self.readback, self.bounds = scene, camera, readback, scene.bounds
        self.lights, self.settings, self.scene_settings = held, snap, scene_snap
        self.view_proj_cols = np.asarray(view_proj, np.float32).T.reshape(-1)   # as pack_frame writes it
        self.settled = False   # the block's prev_view_proj / history_reset still are the full path's
        self.result = result
        return self

    def same(self, scene, settings, readback) -> bool:
        """The same frame but perhaps for the camera (compared by the caller)."""
        if scene is not self.scene or readback != self.readback:
            return False
        if scene.bounds is not self.bounds or not _same_settings(settings, self.settings):
            return False
        scene_settings = getattr(scene, "settings", None) or {}
        if not _same_settings(scene_settings, self.scene_settings):
            return False
        lights = scene.lights
        if len(lights) != len(self.lights):
            return False
        for light, (held, values) in zip(lights, self.lights):
            if light is not held:
                return False
            attrs = light.__dict__
            if len(attrs) != len(values):
                return False
            for a, b in zip(attrs.values(), values):
                if a is not b:
                    return False
        return True


_ALL_STAGES = vk.VK_PIPELINE_STAGE_TRANSFER_BIT | vk.VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT
_ALL_ACCESS = (vk.VK_ACCESS_TRANSFER_WRITE_BIT | vk.VK_ACCESS_TRANSFER_READ_BIT | vk.VK_ACCESS_SHADER_WRITE_BIT
               | vk.VK_ACCESS_SHADER_READ_BIT)


def _barrier(cmd):
    """Compute and transfer work before it is done (and visible) before compute and transfer work after it."""
    memory_barrier(cmd, _ALL_STAGES, _ALL_STAGES, _ALL_ACCESS, _ALL_ACCESS)


def _copy(cmd, src, dst):
    vk.vkCmdCopyBuffer(cmd, src.handle, dst.handle, 1, [vk.VkBufferCopy(0, 0, min(src.size, dst.size))])
