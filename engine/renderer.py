"""The Renderer: owns the Vulkan context, the frame's resources and its passes, and orders them into a frame.

    G-buffer raster -> shadow rays -> AO rays -> reflection rays, diffuse GI rays + their filters
        -> temporal accumulation -> a-trous denoise -> lighting + tonemap -> temporal anti-aliasing -> exposure
        -> debug view -> readback

A frame's command buffer is recorded once per (scene, settings) and re-submitted; only the per-frame
uniform block (camera, previous camera, frame index, history reset flag) is rewritten before each submit
(engine/steady.py tells when the last frame's recording can be re-submitted; engine/passes/frame_block.py writes
the block). The passes declare what they read and write (engine/passes/base.py); the recorder derives the barriers
between them. The raster options (culling, levels of detail, the software raster) are one named type,
engine/passes/raster_options.py; the scene on the GPU is engine/gpu's.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Iterable, Iterator, Sequence
from typing import Any

import numpy as np

from .lifetime import Closes
from .errors import ConfigError, EngineError, VulkanError
from .frame import Frame
from .gpu import bvh_descriptor_set, bvh_layout as resolve_layout
from .gpu.pathscene import PathScene
from .gpu.environment import GpuEnvironment
from .gpu.scene import SceneChanges, SceneGeometry
from .passes.accumulate import ALPHA_MIN, AccumulatePass
from .passes.ao import AOPass
from .passes.debug_view import DebugViewPass
from .passes.denoise import DenoisePass
from .passes.camera_rays import CameraRaysPass, traced
from .passes.gbuffer import GBufferPass
from .passes.frame_block import FrameBlock
from .passes.interface import FILTER_AO, FILTER_MASKS, FILTER_TEMPORAL, MAX_LIGHTS, Tonemap, pack_light
from .passes.exposure import ExposurePass
from .passes.lighting import LightingPass
from .passes.path import PathPass
from .passes.raster_options import RasterOptions
from .passes.raypass import follow_scene
from .passes.gi import GIFilterPass, GITemporalPass, GITracePass, GIUpsamplePass
from .passes.gi import set_resolution as set_gi_resolution
from .passes.reflections import ReflectionFilterPass, ReflectionTemporalPass, ReflectionTracePass
from .passes.transparency import TransparencyPass
from .passes.shadows import ShadowPass
from .passes.taa import TAAPass
from .passes.soft_raster import SW_RASTER_PIXELS
from .parallel import serialized
from .passes.targets import Targets
from .scene import Scene, environment
from .scene.camera import Camera
from .progress import bar as progress_bar
from .settings import DEFAULT_SETTINGS, DEFAULT_SPP, ShadowMode, ViewMode, check_settings, check_size, default
from .settings import ao_samples, given_settings, readback_aovs, resolve_aovs
from .shaders import ShaderLibrary
from .steady import Steady
from .vk import Context, Recorder, Timestamps, reflect
from .vk.shared import Device, Scope
from .vk.recorder import ONE_F32, TRANSFER
from .vk.sync import create_fence, destroy_fence, reset_fences, wait_fences

#: The effects whose rays are shaded at their hits, by setting: their (trace, temporal, filter, then any) pass classes.
SECONDARY_EFFECTS = {
    "reflections": (ReflectionTracePass, ReflectionTemporalPass, ReflectionFilterPass),
    "gi": (GITracePass, GITemporalPass, GIFilterPass, GIUpsamplePass),
}


class Renderer(Closes):
    """A headless hybrid renderer of a fixed size: `with Renderer(640, 360) as r: frame = r.render(scene)`.

    One renderer owns a Vulkan device context (or shares the one it is given), the frame's images and the passes;
    `render()` draws a `Scene` and reads the frame back as numpy arrays (`Frame`). It keeps the last scene on the
    GPU (rendering the same `Scene` object again uploads nothing; `uploads` counts uploads) and one recorded command
    buffer per combination of settings, so repeated frames cost little host time. Soft shadows and AO accumulate
    over successive frames of the same scene and lights (the camera may move). Close it (`close()` or a `with`
    block) to free the device; a closed renderer raises `ConfigError` / `EngineError` instead of crashing.

    Conventions: sizes in pixels; row 0 of every image is the top; world units are the scene's; colours are linear
    RGB until the final image, which is tonemapped (ACES) and sRGB-encoded 8-bit RGBA.
    """

    def __init__(
        self,
        width: int,
        height: int,
        *,
        device: Device | int | str | None = None,
        validation: bool = False,
        shader_dir: str | os.PathLike[str] | None = None,
        hot_reload: bool = False,
        context: Context | None = None,
        bvh_layout: str | None = None,
        culling: bool = True,
        lod_pixels: float = 0.0,
        sw_raster: bool | None = None,
        sw_raster_pixels: float = SW_RASTER_PIXELS,
    ):
        """A renderer of `width` x `height` pixels (1..16384 each).

        Args:
            width: image width in pixels.
            height: image height in pixels.
            device: an open `engine.Device` to share (with Tracers, other Renderers), or the Vulkan device to open
                one of its own on: its index in `hybrid info`'s list or part of its name (default: $HYBRID_DEVICE,
                else discrete GPU > integrated > CPU).
            validation: turn the Khronos validation layer on (errors collect in `validation_errors`); also
                $HYBRID_VALIDATION=1 (a shared `engine.Device` has its own setting).
            shader_dir: a folder of GLSL sources to use instead of the committed SPIR-V (with `hot_reload`).
            hot_reload: recompile changed GLSL before each frame; failures keep the last good pipeline and show in
                `shader_errors`.
            context: render on an existing `engine.vk.Context` (the viewer's, which has a surface); it is not
                closed here.
            bvh_layout: "binary" or "wide" scene BVH for the shadow and AO passes (default: $HYBRID_BVH_LAYOUT,
                else "binary"); a scene of several (or moved) instances traces the two-level BVH, binary.
            culling: cull instances outside the view on the GPU, draw the rest indirectly (the same pixels; off
                where the device lacks drawIndirectFirstInstance). Also an attribute.
            lod_pixels: with culling, draw each instance at its mesh's coarsest level of detail (engine/scene/lod.py)
                whose error projects below this many pixels (1.0 is good); 0 (default): full meshes, exact AOVs.
                Also an attribute.
            sw_raster: with culling, draw the instances that project to at most `sw_raster_pixels` pixels across
                with a compute (software) raster into the same visibility buffer (engine/passes/soft_raster.py):
                faster on GPUs with few raster units. None (default): on for GPUs, off on CPU devices (lavapipe);
                True / False: forced. Where the device lacks 64-bit buffer atomics (shaderInt64 and
                shaderBufferInt64Atomics) it stays off, without an error. Also an attribute.
            sw_raster_pixels: the software raster's largest instance extent, in pixels (0 < it <= 128; 64 by
                default). Also an attribute.

        Raises:
            ConfigError: a bad size, device selector, layout or raster option.
            VulkanError: no usable Vulkan device, or it lacks the `geometryShader` feature.
        """
        self.bvh_layout = resolve_layout(bvh_layout)  # a bad one fails here, before any Vulkan object exists
        self._raster = RasterOptions(culling, lod_pixels, sw_raster, sw_raster_pixels)  # checked here
        check_size(width, height)
        self.width, self.height = int(width), int(height)
        self.library = ShaderLibrary(shader_dir, hot_reload=hot_reload)
        self.ctx = None
        self._validation_errors: list[str] = []
        if isinstance(device, Device) and device.closed:
            raise ConfigError("Renderer: its engine.Device is closed (make a new engine.Device)")
        self._owns_ctx = context is None and not isinstance(device, Device)
        self._device = device if isinstance(device, Device) else None
        self._lock = threading.RLock()  # one call at a time (engine.parallel.serialized)
        self._commands: dict = {}  # set before anything can fail, so close() always works
        self._steady = None  # _Steady: the last frame's inputs, for re-submitting it cheaply
        self._flight = None  # _Flight: a render_many frame in flight, read back by any other call first (_drain)
        self._device_name = None
        self._geometry = self._scene_bvh = self.targets = None
        try:
            if context is not None:
                if not isinstance(context, Context):
                    raise ConfigError(f"Renderer: context must be an engine.vk.Context, got {type(context).__name__}")
                context.check_open("Renderer")  # a destroyed device would abort the process in the first call
            with self._lock:  # (a Device closed meanwhile waits for the set-up, then closes this Renderer)
                if self._device is not None:  # its own share of the device: command pool, objects to destroy
                    self.ctx = self._device._attach(self, "Renderer")
                elif context is not None:
                    self.ctx = Scope(context, "Renderer")
                else:
                    self.ctx = Context(device=device, validation=validation or None)
                self._validation_errors = self.ctx.validation_errors  # the same list: still readable after close()
                self._device_name = self.ctx.device_info["name"]  # (also after close())
                self._init_gpu()
        except BaseException:
            self.close()
            raise

    def _init_gpu(self):
        ctx = self.ctx
        if not ctx.geometry_shader:
            raise VulkanError(
                f"device {ctx.device_info['name']!r} lacks the geometryShader feature, which the "
                "G-buffer's visibility pass needs (gl_PrimitiveID in a fragment shader); the Tracer "
                "works without it"
            )
        self.frame_block = FrameBlock(ctx)  # the per-frame uniform block and its one writer
        self._timestamps = [Timestamps(ctx), Timestamps(ctx)]  # per readback slot (render_many has two in flight)
        self.timestamps = self._timestamps[0]
        self._fences = [create_fence(ctx), create_fence(ctx)]
        [ctx.defer_destroy(destroy_fence, ctx, fence) for fence in self._fences]
        self.targets = Targets(ctx, self.width, self.height, light_capacity=1, frame_ubo=self.frame_block.buffer)
        res, lib = self.targets.resources, self.library
        self.bvh_set = bvh_descriptor_set(ctx, reflect(lib.get(ShadowPass.shader), ShadowPass.shader))
        self.gbuffer, self.accumulate = GBufferPass(ctx, lib, res), AccumulatePass(ctx, lib, res)
        self.shadows = ShadowPass(ctx, lib, res, self.bvh_set, self.bvh_layout)
        self.ao = AOPass(ctx, lib, res, self.bvh_set, self.bvh_layout)
        self.camera_rays = None  # the G-buffer of camera models other than the pinhole: made when first used
        self.denoise = DenoisePass(ctx, lib, res, self.targets)
        self.lighting, self.debug_view = LightingPass(ctx, lib, res), DebugViewPass(ctx, lib, res)
        self.exposure, self.taa = ExposurePass(ctx, lib, res), TAAPass(ctx, lib, res)
        self.passes = [
            self.gbuffer,
            self.shadows,
            self.ao,
            self.accumulate,
            self.denoise,
            self.lighting,
            self.taa,
            self.exposure,
            self.debug_view,
        ]
        self._scene = self._geometry = self._scene_bvh = None
        self._environment = None  # GpuEnvironment: the last scene's (gpu/environment.py)
        self.bvh_stats, self._commands = {}, {}
        self._changes = SceneChanges()  # the scene's state the last frame drew (instance motion)
        self._history_key = self._steady = None  # _history_key: what the temporal history was accumulated under
        self.path = None  # PathPass, made by the first path-traced frame (its pipeline takes a while to build)
        self.reflections = None  # (trace, temporal, filter) passes, made by the first frame with reflections on
        self.gi = (
            None  # the diffuse GI's (trace, temporal, filter, upsample) passes, made by the first frame with gi on
        )
        self.transparency = None  # TransparencyPass, made by the first frame with transparency on
        self.path_samples = 0  # samples per pixel in the path tracer's image so far
        self.path_progress = None  # called as f(samples done, samples in all) after each path-tracing batch
        self._path_key = None  # what the path tracer's samples so far were traced under
        self._spp_index = None  # render(spp=)'s frame being rendered: its jitter sample
        self.uploads = 0  # scene uploads so far (a test reads it: the same scene is uploaded once)
        self.bvh_builds = 0  # ray-pass BVHs made so far (a scene's first, and a new kind or rebuild after changes)

    # ---- public ---------------------------------------------------------------------------
    @property
    def validation_errors(self) -> list[str]:
        """Error-severity validation messages so far (leaks found at close() included)."""
        return self._validation_errors

    @property
    def shader_errors(self) -> dict[str, str]:
        """Hot reload's failures: GLSL path -> compiler or interface error (empty when all shaders are good)."""
        return dict(self.library.errors)

    # ---- raster options: the constructor's, also attributes (engine/passes/raster_options.py) ----------------
    @property
    def culling(self) -> bool:
        """GPU culling of the instances before the raster (the constructor's `culling`)."""
        return self._raster.culling

    @culling.setter
    def culling(self, value: bool) -> None:
        self._set_raster(culling=value)

    @property
    def lod_pixels(self) -> float:
        """The largest projected error of a level of detail, in pixels (the constructor's `lod_pixels`)."""
        return self._raster.lod_pixels

    @lod_pixels.setter
    def lod_pixels(self, value: float) -> None:
        self._set_raster(lod_pixels=value)

    @property
    def sw_raster(self) -> bool | None:
        """The software raster of small instances: None (auto), True, False (the constructor's `sw_raster`)."""
        return self._raster.sw_raster

    @sw_raster.setter
    def sw_raster(self, value: bool | None) -> None:
        self._set_raster(sw_raster=value)

    @property
    def sw_raster_pixels(self) -> float:
        """The software raster's largest instance extent, in pixels (the constructor's `sw_raster_pixels`)."""
        return self._raster.sw_raster_pixels

    @sw_raster_pixels.setter
    def sw_raster_pixels(self, value: float) -> None:
        self._set_raster(sw_raster_pixels=value)

    def _set_raster(self, **changes):
        """New raster options (checked): the next frame takes (or records) their recording; where levels of detail
        are wanted and the scene was uploaded without them, it is uploaded again."""
        self._raster, self._steady = self._raster.replace(**changes), None
        if self._raster.lod_pixels > 0 and self._geometry is not None and not self._geometry.has_levels:
            self._scene = None

    @property
    def device_name(self) -> str:
        """The Vulkan device's name, e.g. "llvmpipe (LLVM 15.0.7, 256 bits)" (still readable after close())."""
        return self._device_name

    @serialized
    def render(
        self,
        scene: Scene,
        camera: Camera | None = None,
        *,
        aovs: str | Sequence[str] | None = None,
        shadows: ShadowMode = default("shadows"),
        shadow_samples: int = default("shadow_samples"),
        reference_samples: int = default("reference_samples"),
        shadow_terminator: bool = default("shadow_terminator"),
        accumulate: bool = default("accumulate"),
        denoise: bool = default("denoise"),
        ao: bool = default("ao"),
        ao_samples: int | None = default("ao_samples"),
        ao_radius: float | None = default("ao_radius"),
        reflections: bool = default("reflections"),
        gi: bool = default("gi"),
        gi_resolution: str = default("gi_resolution"),
        transparency: bool = default("transparency"),
        exposure: float = default("exposure"),
        auto_exposure: bool = default("auto_exposure"),
        tonemap: Tonemap = default("tonemap"),
        ambient: float | Sequence[float] | None = default("ambient"),
        view: ViewMode = default("view"),
        integrator: str = default("integrator"),
        spp: int | None = default("spp"),
        max_depth: int = default("max_depth"),
        pixel_filter: str = default("pixel_filter"),
        seed: int = default("seed"),
        taa: bool = default("taa"),
        **unknown: Any,
    ) -> Frame:
        """Render one frame of `scene` seen from `camera` and read it back: colour, AOVs and GPU timings.

        The options are keywords. One left out takes the scene's `[settings]` value (docs/scenes.md), else its
        entry of `engine.settings.DEFAULT_SETTINGS` (shown as `Default(value)` in the signature); one given wins
        over both. Any other keyword is a `ConfigError` ("unknown render setting ...").

        Args:
            aovs: what to read back: AOV names ("color", "depth", "normal", "position", "albedo", "shadow",
                "shadow_raw", "ao", "ao_raw", "history", "triangle_id", "object_id", "material_id", "instance_id",
                "motion", "roughness", "metallic", "emissive", "radiance"; see `Frame.aov`), "all", or None for
                `engine.settings.DEFAULT_AOVS`. Only these are copied from the GPU.
            scene: what to draw. The last scene stays on the GPU: rendering the same object again uploads nothing.
            camera: the viewpoint (None: `scene.camera`). The image's aspect ratio is the renderer's width /
                height; `camera.fov_y` is the vertical field of view.
            shadows: "hard" (one ray to each light's centre), "soft" (`shadow_samples` rays over each light's
                area or solid angle, new ones every frame, accumulated and denoised), "seed-delta" (the paper's
                occlusion-delta approximation, one ray), "reference" (`reference_samples` rays per pixel per light,
                nothing accumulated: ground truth, slow) or "off".
            shadow_samples: soft shadows: rays per pixel per light per frame, 1..256.
            reference_samples: the reference mode: rays per pixel per light, and AO rays per pixel, 1..65536.
            shadow_terminator: start shadow rays from a point moved off the flat triangle towards the smooth
                surface its vertex normals describe (Hanika 2021), so that low-poly smooth meshes do not drop
                whole triangles into shadow near the terminator (both integrators: the raster's shadow pass and the
                path tracer's next-event shadow rays).
            accumulate: blend the soft light masks and AO with the previous frames' (reprojected when the camera
                moves). The history starts over when the scene, a light, the size, `shadows`, `shadow_samples`,
                `ao`, `ao_samples`, `ao_radius` or `accumulate` changes.
            denoise: filter the soft light masks and AO (edge-aware a-trous, 4 iterations).
            ao: trace ambient occlusion (off: AO is 1 everywhere).
            ao_samples: AO rays per pixel per frame, 1..256 (None: 4, or 1 with `gi` on).
            ao_radius: the AO rays' length in world units (None: 10% of the scene's bounding-box diagonal).
            reflections: trace one GGX reflection ray per pixel from the G-buffer (surfaces up to roughness 0.6),
                shaded at its hit with the scene's lights (a shadow ray each) and environment, accumulated over
                frames by roughness and filtered; it replaces the split-sum environment in the specular lobe there.
            gi: diffuse global illumination: one cosine-weighted ray per 2x2 pixels (see `gi_resolution`) from the
                G-buffer, shaded at its hit with the scene's lights (a shadow ray each) and the irradiance found
                there the frame before (a bounce more each frame), the environment on a miss; accumulated over
                frames, filtered and upsampled edge-aware. Its irradiance replaces the environment's times AO in
                the diffuse lobe (non-metal pixels).
            gi_resolution: "half" (a GI ray per 2x2 pixels, the block's pixels in turn over 4 frames) or "full"
                (a ray per pixel: slower, a little closer to the path tracer).
            transparency: draw transmissive (glass) surfaces by rays: the Fresnel-weighted mirror ray and the
                refracted ray followed through the solid (up to 4 interfaces), and BLEND surfaces mixed by alpha
                with what lies behind them (a ray continued through them); off: both are shaded as opaque.
            exposure: in EV: the linear HDR colour is scaled by 2^exposure before the tone curve and sRGB
                encoding; in [-60, 60].
            auto_exposure: also scale by 0.18 / the frame's log-average luminance (computed on the GPU).
            tonemap: the tone curve: "neutral" (Khronos PBR Neutral), "agx" (AgX, base look) or "aces"
                (Narkowicz's ACES fit).
            ambient: None: the scene's environment lights the scene (its `environment`; default: a daylight
                sky); a linear RGB colour (one number: grey), each in [0, 1e6]: a constant environment of that
                radiance instead (0: no environment light), times AO, and the background's colour.
            view: "color" (the lit image) or an AOV drawn into the colour image instead, on the GPU (the names
                are `engine.settings.AOVS`; `Frame.aov` holds every AOV whatever the view).
            integrator: "raster" (the hybrid frame: raster G-buffer, traced shadows and AO, deferred lighting) or
                "path" (shaders/glsl/path.comp: a progressive path tracer on the same BVH and materials, `spp`
                samples per pixel, its linear radiance tonemapped into "color" and as "radiance"; the data AOVs,
                depth, ids, normals, motion, stay the raster's; shadows, AO and their filters are not run).
            spp: samples per pixel, 1..2^20; None: the integrator's default (`DEFAULT_SPP`: raster 1, path 64).
                path: paths per pixel (`path_progress`, if set, is called after each batch). raster: `spp - 1`
                more frames with the sample point moved within the pixel (Halton 2, 3; TAA off in them), "color" and
                "radiance" averaged over all `spp`; the other AOVs are the first frame's, unjittered and exact (each
                sample is a whole frame: its time grows linearly). `submit()` draws one.
            max_depth: path: the most segments of a path, 1..64 (1: emitters seen directly; 2: direct light).
            pixel_filter: path: "box" (samples uniform over the pixel) or "gaussian" (standard deviation 0.5
                pixel).
            seed: path: the seed of the random sequence, 0..2^32-1: the same seed and spp give the same image.
            taa: temporal anti-aliasing: the raster's sample point moves within the pixel every frame (Halton 2, 3)
                and the lit radiance is blended with its history, reprojected by the motion vectors and clamped to
                the neighbourhood's colours. A frame that reads back a data AOV (anything but "color" and
                "radiance") or shows another `view` is not jittered, so depth, ids, normals and motion stay exact.
            **unknown: none are accepted: a `ConfigError` names the first.

        Returns:
            The frame (`Frame`): `color`, `aov`, `timings` and the `settings` it was rendered with.

        Raises:
            ConfigError: a bad or unknown setting (naming it; a bad value from the scene's `[settings]` also names
                the scene), a scene or camera of the wrong type, more lights than fit, a closed renderer.
            VulkanError: the device failed.
        """
        settings = given_settings(locals(), unknown)
        names = resolve_aovs(aovs)
        self._check_open("render()")
        self._drain()
        spp = _spp(scene, settings)
        if spp > 1:
            return self._render_spp(scene, camera, settings, names, spp)
        cmd, marks, cfg, n_lights = self._prepare(scene, camera, settings, readback=(readback_aovs(names), 0))
        if cfg["integrator"] == "path":
            self._path_samples(scene, camera, cfg, n_lights)
        self.ctx.submit(cmd)
        return self._frame(scene, names, 0, marks, cfg, n_lights, camera)

    def _render_spp(self, scene, camera, settings, names, spp) -> Frame:
        """render() with `spp` samples per pixel: the frame of `names` at the pixel centres (jitter sample 0), then
        spp - 1 frames of the colour alone at jitter samples 1.. (TAA off), "color" and "radiance" averaged."""
        colour = tuple(n for n in ("color", "radiance") if n in names) or ("color",)
        sums = {}
        try:
            for i in range(spp):
                self._spp_index, self._steady = i, None  # (each frame's block written whole: its jitter sample)
                wanted = names if i == 0 else colour
                given = settings if i == 0 else {**settings, "taa": False}
                cmd, marks, cfg, n_lights = self._prepare(scene, camera, given, readback=(readback_aovs(wanted), 0))
                self.ctx.submit(cmd)
                frame = self._frame(scene, wanted, 0, marks, cfg, n_lights, camera)
                if i == 0:
                    first = frame
                for n in colour:
                    value = frame.color if n == "color" else frame.aov[n]
                    sums[n] = sums.get(n, 0.0) + value.astype(np.float64)
        finally:
            self._spp_index, self._steady = None, None
        if "color" in names:
            first.color = np.clip(np.rint(sums["color"] / spp), 0, 255).astype(np.uint8)
        if "radiance" in names:
            first.aov["radiance"] = (sums["radiance"] / spp).astype(first.aov["radiance"].dtype)
        return first

    def render_many(
        self,
        scene: Scene,
        cameras: Iterable[Camera],
        *,
        aovs: str | Sequence[str] | None = None,
        progress: bool = False,
        **settings: Any,
    ) -> Iterator[Frame]:
        """Frames of `scene` from each camera in turn, as an iterator: frame N+1 renders on the GPU while frame N is
        read back and handed to the caller (two readback buffers in turn). The temporal history carries over from
        frame to frame as it does for render().

        Threads: each step (submitting a frame, reading the last one back) holds the renderer's lock, which is let go
        between frames with one frame in flight. Any other call on the renderer (render(), submit(), resize(), another
        render_many) first waits for that frame and reads it back for this iterator, so each frame is the one a lone
        render() of its camera gives, and several iterators, in one thread or in several, may be used at once
        (docs/architecture.md, "Threads"). A renderer closed meanwhile makes the next step raise.

        `progress=True` draws a progress bar of the frames handed out (tqdm: a widget in Jupyter, text on a terminal
        on stderr; none where stderr is neither); its length is `len(cameras)` where `cameras` has one."""
        names = resolve_aovs(aovs)
        if progress:
            yield from _with_bar(self.render_many(scene, cameras, aovs=names, **settings), cameras)
            return
        if _spp(scene, settings) > 1:  # (the raster's) each frame is several (render()'s), read back before the next
            for camera in cameras:
                yield self.render(scene, camera, aovs=names, **settings)
            return
        mine = _Owner()  # this iterator: its frame in flight is `self._flight` while that names it
        try:
            for camera in cameras:
                with self._lock:
                    frame = self._many_step(scene, camera, names, settings, mine)
                if frame is not None:
                    yield frame
            with self._lock:
                self._check_open("render_many()")
                flight = self._own_flight(mine)
                if flight is not None:
                    self._flight = None
                    flight.wait(self.ctx)
                    mine.frame = self._frame(*flight.frame_args)
                frame, mine.frame = mine.frame, None
            if frame is not None:
                yield frame
        finally:  # ended or abandoned: its frame in flight, if any, finishes before its slot is used again
            with self._lock:
                flight = self._own_flight(mine)
                if flight is not None:
                    self._flight = None
                    if self.ctx is not None:
                        flight.wait(self.ctx)

    def _many_step(self, scene, camera, names, settings, mine) -> Frame | None:
        """One step of render_many (under the lock): submit the frame of `camera` and return the iterator's last
        one (None after the first), read back while the new one renders. Its own frame in flight is waited for (the
        frame block is rewritten); anyone else's is read back for them first (`_drain`)."""
        self._check_open("render_many()")
        last = self._own_flight(mine)
        if last is not None:
            last.wait(self.ctx)
        else:
            self._drain()
        slot = 1 - last.slot if last is not None else 0  # (not the slot whose readback is still to be read)
        cmd, marks, cfg, n_lights = self._prepare(scene, camera, settings, readback=(readback_aovs(names), slot))
        if cfg["integrator"] == "path":
            self._path_samples(scene, camera, cfg, n_lights)
        self.ctx.submit(cmd, wait=False, fence=self._fences[slot])
        last = self._own_flight(mine)  # (None if _prepare read it back: new targets)
        self._flight = _Flight(mine, slot, self._fences[slot], (scene, names, slot, marks, cfg, n_lights, camera))
        if last is not None:
            return self._frame(*last.frame_args)
        frame, mine.frame = mine.frame, None
        return frame

    def _own_flight(self, owner) -> _Flight | None:
        flight = self._flight
        return flight if flight is not None and flight.owner is owner else None

    def _drain(self) -> None:
        """Before any other call uses the frame block, the slots or the targets: a render_many frame in flight is
        waited for and read back for its iterator, which yields it when resumed."""
        flight, self._flight = self._flight, None
        if flight is not None:
            flight.wait(self.ctx)
            flight.owner.frame = self._frame(*flight.frame_args)

    @serialized
    def reset_history(self) -> None:
        """Start the next frame as a fresh renderer would: no temporal history and frame index 0 (which seeds the
        soft-shadow and AO samples), so a view's frames do not depend on what was rendered before (batch jobs)."""
        self._check_open("reset_history()")
        self._history_key = None
        self.frame_block.restart()
        self._steady = None

    def _frame(self, scene, names, slot, marks, cfg, n_lights, camera) -> Frame:
        buf, offsets = self.targets.readback(self.ctx, readback_aovs(names), slot)
        aov = self.targets.read(buf, offsets, n_lights)
        classes: list[str] = []
        if "semantic_id" in names:  # the objects' classes through a table: exact, on the host
            ids = aov["object_id"] if "object_id" in names else aov.pop("object_id")
            aov["semantic_id"] = scene.semantic_lookup().take(ids + 1)
            classes = scene.class_names
        return Frame(
            color=aov.pop("color", None),
            aov=aov,
            timings=self._timestamps[slot].read(marks),
            settings=cfg,
            object_names=scene.object_names,
            material_names=[m.name for m in scene.materials],
            class_names=classes,
            camera=camera if camera is not None else scene.camera,
            scene_name=scene.name,
        )

    @serialized
    def submit(
        self,
        scene: Scene,
        camera: Camera | None = None,
        *,
        wait: bool = True,
        signal_semaphores: Sequence[Any] = (),
        fence: Any = None,
        shadows: ShadowMode = default("shadows"),
        shadow_samples: int = default("shadow_samples"),
        reference_samples: int = default("reference_samples"),
        shadow_terminator: bool = default("shadow_terminator"),
        accumulate: bool = default("accumulate"),
        denoise: bool = default("denoise"),
        ao: bool = default("ao"),
        ao_samples: int | None = default("ao_samples"),
        ao_radius: float | None = default("ao_radius"),
        reflections: bool = default("reflections"),
        gi: bool = default("gi"),
        gi_resolution: str = default("gi_resolution"),
        transparency: bool = default("transparency"),
        exposure: float = default("exposure"),
        auto_exposure: bool = default("auto_exposure"),
        tonemap: Tonemap = default("tonemap"),
        ambient: float | Sequence[float] | None = default("ambient"),
        view: ViewMode = default("view"),
        integrator: str = default("integrator"),
        spp: int | None = default("spp"),
        max_depth: int = default("max_depth"),
        pixel_filter: str = default("pixel_filter"),
        seed: int = default("seed"),
        taa: bool = default("taa"),
        **unknown: Any,
    ) -> dict[str, Any]:
        """Render one frame into `self.targets.color` without reading it back (the viewer's path).

        The settings are `render()`'s, with the same defaults and checks. With `wait=False` the caller
        synchronizes through `signal_semaphores` (VkSemaphore handles signalled when the frame is done) or `fence`
        (a VkFence), and reads `last_timings()` once that frame has finished.

        Returns:
            The settings the frame was rendered with (a copy: `DEFAULT_SETTINGS` keys, checked values).
        """
        settings = given_settings(locals(), unknown)
        self._check_open("submit()")
        self._drain()
        cmd, marks, cfg, n_lights = self._prepare(scene, camera, settings, readback=None)
        if cfg["integrator"] == "path":  # the viewer: a batch more while nothing changes, else start over
            self._path_samples(scene, camera, cfg, n_lights, progressive=True)
        self._last_marks = marks
        self.ctx.submit(cmd, wait=wait, signal_semaphores=signal_semaphores, fence=fence)
        return cfg

    @serialized
    def last_timings(self) -> dict[str, float]:
        """GPU ms per pass of the last submitted frame (blocks until its queries are available)."""
        self._check_open("last_timings()")
        self._drain()  # (a render_many frame in flight may write the same queries)
        return self.timestamps.read(self._last_marks) if getattr(self, "_last_marks", None) else {}

    @serialized
    def resize(self, width: int, height: int) -> None:
        """New render size: targets are recreated and recorded command buffers dropped. A render_many frame in
        flight is finished and read back first, at the size it was rendered at."""
        self._check_open("resize()")
        check_size(width, height)
        if (width, height) != (self.width, self.height):
            Targets.check_capacity(self.ctx, width, height, self.targets.light_capacity)
            self.width, self.height = int(width), int(height)
            self._resize_targets(self.targets.light_capacity)

    def _check_open(self, call: str) -> None:
        """A clear error, not a crash in freed objects, for `call` ("render()") on a closed renderer."""
        if self._device is not None and self._device.closed:
            raise ConfigError(f"{call} on a closed Renderer: its engine.Device was closed")
        if self.ctx is None:
            raise EngineError(f"{call} on a closed Renderer")
        self.ctx.check_open(f"Renderer.{call}")  # a shared context its owner closed: no Vulkan call may follow

    def _prepare(self, scene, camera, settings, readback):
        """The frame's command buffer, its timestamp marks, settings and light count, with the frame block written
        (the caller has checked that the renderer is open and that no other frame in flight reads the block)."""
        polled = False
        if isinstance(scene, Scene) and scene.pixel_points:  # point clouds sized in pixels: for this camera, height
            cam = camera if camera is not None else scene.camera
            if isinstance(cam, Camera):
                scene.size_points(cam, self.height)
        if scene is self._scene and self._geometry is not None:
            self._frame_start(scene)  # moved instances: their transforms, the BVH (may drop the recordings)
        if self._steady is not None:
            self._poll_shaders()  # a reload drops the recorded commands, and with them self._steady
            polled = True
            steady = self._steady
            if steady is not None:
                cam = camera if camera is not None else scene.camera
                if steady.same(scene, settings, readback):
                    if cam is steady.camera:
                        return self._prepare_steady(steady)
                    if isinstance(cam, Camera) and traced(cam) == traced(steady.camera):
                        return self._prepare_moved(steady, cam)
        self._steady = None
        if not isinstance(scene, Scene):
            raise ConfigError(f"render(): scene must be an engine.Scene (Scene.load(path)), got {type(scene).__name__}")
        if camera is not None and not isinstance(camera, Camera):
            raise ConfigError(f"render(): camera must be an engine.Camera or None, got {type(camera).__name__}")
        asked, cfg = frame_settings(scene, settings)
        camera = camera if camera is not None else scene.camera
        if not polled:
            self._poll_shaders()
        if self._use_scene(scene):
            self._frame_start(scene)
        lights = list(scene.lights)
        self._use_environment(environment.resolve(scene.environment, lights))
        if len(lights) > MAX_LIGHTS:
            raise ConfigError(f"{scene.name}: {len(lights)} lights, at most {MAX_LIGHTS} are supported")
        if len(lights) > self.targets.light_capacity:
            self._resize_targets(light_capacity=len(lights))

        view_proj = camera.projection_matrix(self.width / self.height) @ camera.view_matrix()
        diag = float(np.linalg.norm(scene.bounds[1] - scene.bounds[0])) or 1.0
        # The temporal history holds the light masks and AO as traced under these: when any of them changes
        # (another scene, light, shadow mode or sample count, size), the next frame starts over.
        packed_lights = [pack_light(light) for light in lights]
        history_key = (
            scene.uid if hasattr(scene, "uid") else id(scene),
            self.width,
            self.height,
            b"".join(p.tobytes() for p in packed_lights),
            tuple(
                cfg[k]
                for k in (
                    "shadows",
                    "shadow_samples",
                    "ao",
                    "ao_samples",
                    "ao_radius",
                    "accumulate",
                    "shadow_terminator",
                    "taa",
                    "reflections",
                    "gi",
                    "gi_resolution",
                    "transparency",
                )
            ),
        )
        reset = history_key != self._history_key
        if reset:  # no motion on a frame without history (as the camera's previous matrix is this one)
            self._changes.still(self._geometry)
        rays = self._uses_rays(camera, scene)
        key = (
            cfg["shadows"],
            cfg["ao"],
            cfg["accumulate"],
            cfg["denoise"],
            cfg["view"],
            cfg["auto_exposure"],
            cfg["integrator"],
            cfg["taa"],
            cfg["reflections"],
            cfg["gi"],
            cfg["gi_resolution"],
            cfg["transparency"],
            len(lights),
            readback,
            self._raster,
            rays,
        )
        if cfg["shadows"] == "reference":
            key += (cfg["reference_samples"],)
        self._path_ready(scene, cfg)
        self._traced_ready(scene, cfg)
        self._transparency_ready(scene, cfg)
        self._gi_bounce_ready(cfg)
        if key not in self._commands:
            cmd, ts = self._record(cfg, len(lights), readback, rays)
            self._commands[key] = (cmd, list(ts.names))
        cmd, marks = self._commands[key]
        reference = cfg["shadows"] == "reference"
        # The raster is jittered for TAA (the raster integrator's) where the frame reads back the colour alone (data
        # AOVs stay exact), and for spp's frames at their own samples (the first, which reads the data AOVs, at sample
        # 0: the centre).
        colour_only = readback is None or set(readback[0]) <= {"color", "radiance"}
        colour_view = cfg["view"] in ("color", "radiance", "taa_history")
        taa = cfg["taa"] and cfg["integrator"] == "raster"
        self.frame_block.jitter = (taa and colour_only and colour_view) or self._spp_index is not None
        self.frame_block.jitter_index = self._spp_index
        self.frame_block.write(
            view_proj=view_proj,
            camera=camera,
            width=self.width,
            height=self.height,
            lights=lights,
            packed_lights=packed_lights,
            history_reset=reset,
            objects_moved=not self._changes.settled,
            ao_radius=cfg["ao_radius"] or 0.1 * diag,
            ao_samples=cfg["reference_samples"] if reference else ao_samples(cfg),
            shadow_samples=cfg["reference_samples"] if reference else cfg["shadow_samples"],
            exposure=2.0 ** cfg["exposure"],
            ambient=cfg["ambient"],
            tonemap=cfg["tonemap"],
            auto_exposure=cfg["auto_exposure"],
            shadow_terminator=cfg["shadow_terminator"],
            scene_scale=diag,
            accum_alpha=ALPHA_MIN,
            bounds=scene.bounds,
        )
        self._ray_camera(camera, reset)
        self._history_key = history_key
        self._steady = Steady.capture(scene, camera, settings, readback, lights, (cmd, marks, asked, len(lights)))
        return cmd, marks, dict(asked), len(lights)

    def _prepare_steady(self, steady):
        """The same scene, lights, camera and settings as the last frame: its command buffer, and a frame block
        that differs from the last one only in the frame index (plus, on the first such frame, the previous
        camera, now this one, and the history-reset flag, now off). What the full path would write, bit for bit."""
        self.frame_block.again(objects_moved=not self._changes.settled)
        self._ray_camera(steady.camera, False)
        cmd, marks, cfg, n_lights = steady.result
        return cmd, marks, dict(cfg), n_lights

    def _prepare_moved(self, steady, camera):
        """As the last frame but for the camera (the viewer while flying): the camera's fields of the frame block
        are rewritten, the rest (lights, settings, scene) stays; the temporal history is kept, as the full path
        keeps it (the camera is not part of the history key)."""
        view_proj = camera.projection_matrix(self.width / self.height) @ camera.view_matrix()
        self.frame_block.move_camera(view_proj, camera, self.height, objects_moved=not self._changes.settled)
        self._ray_camera(camera, False)
        steady.camera = camera
        cmd, marks, cfg, n_lights = steady.result
        return cmd, marks, dict(cfg), n_lights

    @serialized
    def close(self) -> None:
        """Free every Vulkan object (and the device, unless it was given: an `engine.Device` or a `context`); safe
        to call twice."""
        self._flight = None  # (its iterator's next step raises: closed)
        if self.ctx is not None:
            if not self._owns_ctx and not self.ctx.closed and not self.ctx.hung:
                self._invalidate_commands()
            self.ctx.close()  # its own context, or its Scope of a shared one: what this renderer made
            self.ctx = None
        if self._device is not None:
            self._device._detach(self)
        if getattr(self, "library", None) is not None:
            self.library.close()

    # ---- internals ------------------------------------------------------------------------
    def _uses_rays(self, camera, scene) -> bool:
        """Is `camera` traced (a model other than the pinhole)? Then the traced cameras' pass, for this scene's
        geometry and BVH, is made if it was not yet (a renderer of pinhole cameras never compiles it)."""
        if not traced(camera):
            return False
        if self.camera_rays is None:
            self._make_camera_rays(scene)
        return True

    def _make_camera_rays(self, scene):
        p = CameraRaysPass(
            self.ctx, self.library, self.targets.resources, self.bvh_set, self.bvh_layout, self.width * self.height
        )
        p.bind_scene(self._geometry, scene)
        p.specialize_for(self._scene_bvh)
        self.camera_rays = p
        self.passes.append(p)

    def _ray_camera(self, camera, reset: bool):
        """A traced camera's block (and the previous frame's camera, for motion: none after a history reset)."""
        if traced(camera):
            last = getattr(self, "_last_ray_camera", None)
            self.camera_rays.set_camera(camera, self.width, self.height, None if reset or last is None else last)
        self._last_ray_camera = camera

    def _poll_shaders(self):
        updated = self.library.poll()
        if not updated:
            return
        for p in self.passes:
            if updated & set(p.shaders):
                try:
                    p.reload(self.library)
                except EngineError as exc:  # the last good pipeline stays; listed under the (first) edited shader
                    name = next(n for n in p.shaders if n in updated)
                    self.library.errors[str(self.library.glsl_dir / name)] = str(exc)
        self._invalidate_commands()

    def _invalidate_commands(self):
        self._steady = None
        if self._commands:
            self.ctx.wait_idle()
            for cmd, _ in self._commands.values():
                self.ctx.free_command_buffer(cmd)
            self._commands.clear()

    def _frame_start(self, scene):
        """Before each frame: moved instances into the instance buffer (in place: the recordings stay valid), the
        geometry uploaded again after a mesh deformed or the material overrides changed, then the ray passes' BVH."""
        todo = self._changes.begin(scene)  # None: nothing to do; else (a mesh deformed, something changed)
        if todo is not None:
            if todo[0] or self._geometry.overrides_changed(scene) or self._geometry.mirrors_changed(scene):
                self._upload_geometry(scene)
            self._changes.write(scene, self._geometry)
            self._update_bvh(scene, todo[1])
            for trace in self._secondary_traces():
                if trace.scene_data is not None:
                    trace.scene_data.update(scene)  # the hits' instance transforms (in place)

    def _ray_passes(self):
        extra = (self.path,) if self.path is not None else ()
        return (self.shadows, self.ao, *extra, *self._secondary_traces())

    def _secondary_traces(self):
        """The trace passes made so far of the effects whose hits are shaded (reflections, diffuse GI,
        transparency)."""
        traces = [passes[0] for passes in (self.reflections, self.gi) if passes is not None]
        return traces + ([self.transparency] if self.transparency is not None else [])

    def _path_ready(self, scene, cfg):
        """For a path-traced frame: the path tracer's pass (made on first use) and its scene buffers (made again
        after a new upload)."""
        if cfg["integrator"] != "path":
            return
        if self.path is None:
            self.path = PathPass(self.ctx, self.library, self.targets.resources, self.bvh_set, self.bvh_layout)
            self.passes.append(self.path)
            self.path.bind_scene(self._geometry)
            if self._environment is not None:
                self.path.bind_environment(self._environment)
            if self._scene_bvh is not None:
                self.path.specialize_for(self._scene_bvh)
            self._invalidate_commands()
        if self.path.scene_data is None:
            self._invalidate_commands()  # (the recordings bound the last scene's buffers)
            self.path.bind_data(PathScene(self.ctx, scene), self._geometry)
            self._path_key = None

    def _traced_ready(self, scene, cfg):
        """For a frame with reflections or diffuse GI: their passes (made on first use) and the scene buffers their
        hits read (made again after a new upload)."""
        for setting, kinds in SECONDARY_EFFECTS.items():
            if cfg[setting] and cfg["integrator"] != "path":
                self._effect_ready(scene, setting, kinds)
        if cfg["gi"] and cfg["integrator"] != "path" and set_gi_resolution(self.gi, cfg["gi_resolution"]):
            self._invalidate_commands()

    def _effect_ready(self, scene, setting, kinds):
        if getattr(self, setting) is None:
            lib, res = self.library, self.targets.resources
            trace = self._new_trace(kinds[0])
            setattr(self, setting, (trace, *(kind(self.ctx, lib, res) for kind in kinds[1:])))
            self.passes += getattr(self, setting)
        self._trace_data_ready(getattr(self, setting)[0], scene)

    def _transparency_ready(self, scene, cfg):
        """For a frame with transparency: its pass (made on first use) and the scene buffers its rays read (made
        again after a new upload)."""
        if not cfg["transparency"] or cfg["integrator"] == "path":
            return
        if self.transparency is None:
            self.transparency = self._new_trace(TransparencyPass)
            self.passes.append(self.transparency)
        self._trace_data_ready(self.transparency, scene)

    def _gi_bounce_ready(self, cfg):
        """The reflection and transmission rays' hits lit by the diffuse GI's irradiance where it is traced
        (gi_lookup.glsl), by the environment's where not."""
        bounce = bool(cfg["gi"]) and cfg["integrator"] != "path"
        for p in (self.reflections[0] if self.reflections else None, self.transparency):
            if p is not None and p.values.get("GI_BOUNCE", False) != bounce:
                p.specialize(GI_BOUNCE=bounce)
                self._invalidate_commands()

    def _new_trace(self, kind):
        """A pass of class `kind` whose rays are shaded at their hits, bound to the scene's geometry, environment
        and BVH."""
        trace = kind(self.ctx, self.library, self.targets.resources, self.bvh_set, self.bvh_layout)
        trace.bind_scene(self._geometry)
        if self._environment is not None:
            trace.bind_environment(self._environment)
        if self._scene_bvh is not None:
            trace.specialize_for(self._scene_bvh)
        self._invalidate_commands()
        return trace

    def _trace_data_ready(self, trace, scene):
        """The scene buffers a trace pass's hits read (made again after a new upload)."""
        if trace.scene_data is None:
            self._invalidate_commands()  # (the recordings bound the last scene's buffers)
            trace.bind_data(PathScene(self.ctx, scene), self._geometry)

    def _drop_path_data(self):
        if self.path is not None and self.path.scene_data is not None:
            self.ctx.wait_idle()
            self.path.scene_data.destroy()
            self.path.scene_data = None
            self._path_key = None
        for trace in self._secondary_traces():
            if trace.scene_data is not None:
                self.ctx.wait_idle()
                trace.scene_data.destroy()
                trace.scene_data = None

    def _path_samples(self, scene, camera, cfg, n_lights, progressive=False):
        """Trace `cfg["spp"]` (None: 64) samples per pixel into the path tracer's sum (the frame's recording then
        resolves it), one batch per submit of one recorded batch of dispatches; `progressive` (the viewer): one sample
        added to the samples so far when the scene, camera and settings are those they were traced under, else a first
        one."""
        camera = camera if camera is not None else scene.camera
        if traced(camera):
            raise ConfigError(
                f"integrator='path' takes pinhole cameras; a {camera.model!r} camera is rendered by the raster "
                "integrator only"
            )
        view_proj = camera.projection_matrix(self.width / self.height) @ camera.view_matrix()
        data = self.path.scene_data
        data.update(scene)
        key = (
            id(scene),
            scene.version,
            np.asarray(view_proj, np.float64).tobytes(),
            tuple(np.asarray(camera.eye, np.float64)),
            tuple(sorted((k, str(v)) for k, v in cfg.items())),
            b"".join(pack_light(light).tobytes() for light in scene.lights),
            self.width,
            self.height,
        )
        first = self.path_samples if progressive and key == self._path_key else 0
        total = cfg["spp"] or DEFAULT_SPP["path"]
        if first >= total:
            return
        batch = self.path.batch_size(self.width, self.height)
        end = first + 1 if progressive else total  # (the viewer: a sample per frame, to stay interactive)
        cmd_key = ("path-trace",)
        if cmd_key not in self._commands:
            rec = Recorder(self.ctx)
            self.path.record_trace(rec, self.targets)
            self._commands[cmd_key] = (rec.finish(), [])
        cmd = self._commands[cmd_key][0]
        inv = np.linalg.inv(np.asarray(view_proj, np.float64))
        done = first
        while done < end:
            count = min(batch, end - done)
            self.path.write_params(
                inv, camera.eye, done, count, cfg["max_depth"], cfg["pixel_filter"], cfg["seed"], n_lights
            )
            self.ctx.submit(cmd)
            done += count
            self.path_samples, self._path_key = done, key
            if self.path_progress is not None:
                self.path_progress(done, total)

    def _update_bvh(self, scene, changed: bool):
        """The one hook per frame where the ray passes' BVH follows the scene (`changed`; `follow_scene`)."""
        if self._scene_bvh is None or changed:
            old = self._scene_bvh
            self._scene_bvh = follow_scene(
                self.ctx,
                old,
                scene,
                self.bvh_set,
                self.bvh_layout,
                tuple(p for p in (*self._ray_passes(), self.camera_rays) if p is not None),
                self._invalidate_commands,
                self._geometry.alpha_index,
            )
            if self._scene_bvh is not old:
                self.bvh_builds += 1
            self.bvh_stats = dict(self._scene_bvh.bvh.stats, layout=self._scene_bvh.layout)

    def _upload_geometry(self, scene):
        """The scene's raster data onto the GPU (again after a mesh deformed: the recordings bind it, dropped)."""
        self._invalidate_commands()
        if self._geometry is not None:
            self.ctx.wait_idle()
            self._geometry.destroy()
            self._geometry = None
        self._geometry = SceneGeometry(
            self.ctx, scene, self.gbuffer.white, self.gbuffer.sampler, levels=self._raster.lod_pixels > 0
        )
        self.gbuffer.bind_scene(self._geometry)
        self.lighting.bind_scene(self._geometry)
        for p in self._ray_passes():  # the alpha test's records and textures
            p.bind_scene(self._geometry)
        if self.camera_rays is not None:
            self.camera_rays.bind_scene(self._geometry, scene)
        self._drop_path_data()

    def _use_scene(self, scene):
        """Upload a scene that is not the last one; True when it did."""
        if scene is self._scene:
            return False
        self._steady = None
        self._invalidate_commands()
        self.ctx.wait_idle()
        for old in (self._geometry, self._scene_bvh):
            if old is not None:
                old.destroy()
        self._geometry = self._scene_bvh = None
        self._upload_geometry(scene)
        self._changes = SceneChanges()  # the BVH is built by the first frame's _frame_start
        self._scene = scene
        self.frame_block.forget_camera()
        self.uploads += 1
        return True

    def _use_environment(self, env):
        """The environment's tables on the GPU, bound to every pass with a `bind_environment(env)` (again only when
        it changed)."""
        key = env.key()
        if self._environment is not None and self._environment.key == key:
            return
        self._steady = None
        self._invalidate_commands()
        if self._environment is not None:
            self.ctx.wait_idle()
            self._environment.destroy()
        self._environment = None
        self._environment = GpuEnvironment(self.ctx, env)
        for p in self.passes:  # the passes that read it (environment.glsl): lighting, and any with the hook
            if hasattr(p, "bind_environment"):
                p.bind_environment(self._environment)

    def _resize_targets(self, light_capacity):
        Targets.check_capacity(self.ctx, self.width, self.height, light_capacity)
        self._drain()  # a render_many frame in flight is read back from the targets it was rendered into
        self._invalidate_commands()
        self.ctx.wait_idle()
        self.targets.destroy()
        self.targets = Targets(self.ctx, self.width, self.height, light_capacity, frame_ubo=self.frame_block.buffer)
        for p in self.passes:
            p.bind(self.targets.resources, self.targets)
        self._history_key = None
        self._steady = None

    def _record(self, cfg, n_lights, readback=None, rays=False):
        """The frame's command buffer (and the timestamps it writes): the passes in order; the recorder derives the
        barriers between them. `readback`: (AOV names, slot) to copy out, or None (the viewer's path); `rays`: the
        G-buffer from traced primary rays (a camera model other than the pinhole) instead of the raster."""
        t = self.targets
        ts = self._timestamps[readback[1] if readback else 0]
        rec = Recorder(self.ctx, ts)
        if rays:
            self.camera_rays.record(rec, t, self._geometry)
        else:
            self.gbuffer.record(rec, t, self._geometry, self._raster)
        rec.mark("gbuffer")
        path = cfg["integrator"] == "path"  # (the path tracer's own light transport: no masks, AO or filters)
        mode = cfg["shadows"] if not path else "off"
        reference = cfg["reference_samples"] if mode == "reference" else None
        if mode == "off" or n_lights == 0:
            rec.fill(t["masks.raw"], ONE_F32)
        else:
            self.shadows.record(rec, t, mode, n_lights=n_lights, reference_samples=reference)
        rec.mark("shadows")
        if cfg["ao"] and not path:
            self.ao.record(rec, t, reference_samples=reference)
        else:
            rec.fill(t["ao.raw"], ONE_F32)
        rec.mark("ao")

        self._record_traced(rec, cfg, path, "reflections", "refl")
        self._record_traced(rec, cfg, path, "gi", "gi")
        if cfg["transparency"] and not path:
            self.transparency.record(rec, t)
            rec.mark("transparency")
        elif self.transparency is not None:  # (zero until the pass first ran; its making re-records every frame)
            rec.fill(t["transp"], 0)
        copied = self._record_filters(rec, cfg, n_lights, mode, path)
        if not copied and (cfg["reflections"] or cfg["gi"]) and not path:
            AccumulatePass.record_history_copy(rec, t, ())  # their reprojection reads the G-buffer's history
        (self.path.record_resolve if path else self.lighting.record)(rec, t)
        rec.mark("lighting")
        if cfg["taa"] and not path:
            self.taa.record(rec, t)
            rec.mark("taa")
        if cfg["auto_exposure"]:
            self.exposure.record(rec, t)
            rec.mark("exposure")
        if cfg["view"] != "color":
            self.debug_view.record(rec, t, cfg["view"])
            rec.mark("view")
        if readback:
            t.record_readback(rec, *t.readback(self.ctx, *readback))
            rec.mark("readback")
        else:  # the colour image is copied out by the caller (the viewer's presenter)
            rec.use(reads=[t.color], stage=TRANSFER)
        return rec.finish(), ts

    def _record_traced(self, rec, cfg, path, setting, prefix):
        """The traced reflections (`setting` "reflections") or diffuse GI ("gi"), accumulated and filtered where the
        settings ask for it, into `<prefix>.final` (all zero, nothing traced, when they are off)."""
        t = self.targets
        if not cfg[setting] or path:
            rec.fill(t[f"{prefix}.final"], 0)
            return
        trace, temporal, spatial, *after = getattr(self, setting)
        trace.record(rec, t)
        rec.mark(setting)
        if cfg["accumulate"]:
            temporal.record(rec, t)
        else:
            rec.copy(t[f"{prefix}.raw"], t[f"{prefix}.cur"])
        if cfg["denoise"]:
            spatial.record(rec, t)
        else:
            rec.copy(t[f"{prefix}.cur"], t[f"{prefix}.{spatial.output}"])
        for p in after:  # (the GI's upsampling)
            p.record(rec, t)
        rec.mark(f"{setting}.filter")

    def _record_filters(self, rec, cfg, n_lights, mode, path) -> bool:
        """The temporal accumulation and denoiser of the soft light masks and AO, where the settings ask for them
        (else their raw signals are the final ones). True where it copied this frame's G-buffer into the history."""
        t = self.targets
        # Which signals are filtered: soft light masks and (outside the reference mode) AO.
        filtered = []
        if mode == "soft" and n_lights and (cfg["accumulate"] or cfg["denoise"]):
            filtered.append("masks")
        if cfg["ao"] and not path and mode != "reference" and (cfg["accumulate"] or cfg["denoise"]):
            filtered.append("ao")
        flags = (FILTER_MASKS if "masks" in filtered else 0) | (FILTER_AO if "ao" in filtered else 0)
        if filtered:
            self.accumulate.record(rec, t, flags | (FILTER_TEMPORAL if cfg["accumulate"] else 0), n_lights)
            if cfg["accumulate"]:
                self.accumulate.record_history_copy(rec, t, filtered)
            rec.mark("accumulate")
            copied = bool(cfg["accumulate"])
            if cfg["denoise"]:
                self.denoise.record(rec, t, flags, n_lights)
                rec.mark("denoise")
            else:
                for name in filtered:
                    rec.copy(t.signals[name].cur, t.signals[name].final)
        else:
            rec.fill(t.len_cur, 0)
            copied = False
        for name in ("masks", "ao"):
            if name not in filtered:
                rec.copy(t.signals[name].raw, t.signals[name].final)
        return copied


def _spp(scene, settings) -> int:
    """The raster's samples per pixel for `settings` over the scene's own (checked; 1 where neither sets it, or where
    the integrator is the path tracer, which takes its samples within one frame)."""
    own = getattr(scene, "settings", None) or {}
    own = own if isinstance(own, dict) else {}
    cfg = check_settings({k: settings.get(k, own.get(k, DEFAULT_SETTINGS[k])) for k in ("spp", "integrator")})
    return (cfg["spp"] or DEFAULT_SPP["raster"]) if cfg["integrator"] == "raster" else 1


class _Owner:
    """A render_many iterator, as `_Flight.owner`: the frame another call read back for it (`Renderer._drain`) until
    the iterator yields it."""

    __slots__ = ("frame",)

    def __init__(self):
        self.frame = None


def _with_bar(frames: Iterator[Frame], cameras) -> Iterator[Frame]:
    """`frames` as they come, counted on a progress bar (closed when the iterator ends or is abandoned)."""
    total = len(cameras) if hasattr(cameras, "__len__") else None
    with progress_bar(total, "frame") as shown_bar:
        for frame in frames:
            shown_bar.update(1)
            yield frame


class _Flight:
    """A render_many frame submitted and not yet read back: its iterator, readback slot and fence, and what
    `Renderer._frame` needs to read it. At most one per renderer, outside the lock."""

    __slots__ = ("owner", "slot", "fence", "frame_args", "waited")

    def __init__(self, owner, slot, fence, frame_args):
        self.owner, self.slot, self.fence, self.frame_args, self.waited = owner, slot, fence, frame_args, False

    def wait(self, ctx) -> None:
        """Until the frame is done (its fence then reset for the next frame of the slot); once."""
        if not self.waited:
            wait_fences(ctx, [self.fence])
            reset_fences(ctx, [self.fence])
            self.waited = True


def frame_settings(scene: Scene, settings: dict) -> tuple[dict, dict]:
    """(the settings asked for, the settings drawn with): `settings` over the scene's [settings], checked (an error
    names the scene's [settings] where the bad value came from there); drawn, transparency is off where no material
    needs it (nothing to draw: no pass recorded)."""
    own = getattr(scene, "settings", None) or {}
    try:
        cfg = check_settings({**own, **settings})
    except ConfigError as exc:  # where the bad setting came from: the scene's [settings] (not overridden)?
        try:
            check_settings({k: v for k, v in own.items() if k not in settings})
        except ConfigError as own_exc:
            raise ConfigError(f"{scene.name}: [settings]: {own_exc}") from None
        raise exc from None
    if cfg["transparency"] and not draws_transparency(scene):
        return cfg, dict(cfg, transparency=False)
    return cfg, cfg


def draws_transparency(scene: Scene) -> bool:
    """Whether a material of `scene` is transmissive or blended: the transparency pass has something to draw."""
    return any(m.transmission > 0.0 or m.alpha_mode == "BLEND" for m in scene.materials)
