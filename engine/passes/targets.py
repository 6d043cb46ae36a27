"""The frame's resources: every per-size image and buffer the passes read and write, by name, and the host buffer
a frame is read back into.

The light masks and AO each go through a `Signal`'s buffers: the ray pass writes `raw`; accumulation blends it with
the reprojected `hist` into `cur` (then copied to `hist` for the next frame); the denoiser ping-pongs `cur` / `val_b`
and writes `final`, which the lighting pass reads. A signal that is not filtered this frame has `raw` copied to
`final`. Passes name these as "masks.raw", "ao.final", ...; images by their attribute names ("position", ...).
"""

from __future__ import annotations

import numpy as np

from ..errors import ConfigError
from ..parallel import default_threads, run
from ..vk import Buffer, BufferView, Image
from ..vk.formats import (
    COLOR_ATTACHMENT,
    COPY_DST,
    COPY_SRC,
    D32F,
    DEPTH_ATTACHMENT,
    R32F,
    R32UI,
    RG32F,
    RGBA8,
    RGBA8_SNORM,
    RGBA16F,
    RGBA32F,
    SAMPLED,
    STORAGE_IMAGE,
)
from ..vk.recorder import TRANSFER, Recorder, fill, to_general
from ..vk.resources import STORAGE, STORAGE_TEXEL, TRANSFER_DST, TRANSFER_SRC
from .interface import AOVS

POSITION_FORMAT = RGBA32F  # xyz world position, w linear view depth
NORMAL_FORMAT = RGBA32F  # xyz unit normal, w 1 where covered
ALBEDO_FORMAT = RGBA16F
VISIBILITY_FORMAT = R32UI  # triangle id + 1 (0: background)
DEPTH_FORMAT = D32F
REFLECTION = ("raw", "cur", "hist", "tmp", "final")  # the reflections' buffers (vec4 per pixel)
#: the diffuse GI's (engine/passes/gi.py; vec4 per cell, 2 in `cells`; half-resolution cells use a quarter of each)
GI_BUFFERS = ("raw", "cur", "hist", "tmp", "half", "final", "cells", "raw_full")


class Signal:
    """The buffers one filtered per-pixel signal goes through in a frame: the light masks (`channels` = lights,
    light-major [channel][y][x] floats) or AO (1 channel)."""

    NAMES = ("raw", "cur", "hist", "var_a", "val_b", "var_b", "final")
    #: The parts the denoiser reads, also as R32F storage texel buffers (`views`).
    READ = ("cur", "var_a", "val_b", "var_b")

    def __init__(self, ctx, name, n_pixels, channels):
        usage = STORAGE | STORAGE_TEXEL | TRANSFER_SRC | TRANSFER_DST
        for part in self.NAMES:
            setattr(self, part, Buffer(ctx, n_pixels * 4 * channels, usage, name=f"{name} {part}"))
        # (a GPU may allow larger storage buffers than texel buffers: the views then cover the first
        # maxTexelBufferElements floats and are never read there)
        size = min(n_pixels * 4 * channels, int(ctx.limits.maxTexelBufferElements) * 4)
        self.texel_ok = size == n_pixels * 4 * channels  # the views hold the whole signal (the denoiser may read them)
        self.views = {part: BufferView(getattr(self, part), R32F, 0, size) for part in self.READ}

    def buffers(self):
        """Everything to destroy, the views before their buffers."""
        return list(self.views.values()) + [getattr(self, part) for part in self.NAMES]


class Targets:
    """Every per-size image and buffer of a frame, plus the host buffer the frame is read back into."""

    def __init__(self, ctx, width, height, light_capacity, frame_ubo=None):
        self.width, self.height, self.light_capacity = width, height, light_capacity
        n = width * height
        self.check_capacity(ctx, width, height, light_capacity)
        resolved = STORAGE_IMAGE | COPY_SRC  # written by the G-buffer resolve
        self.visibility = Image(
            ctx, width, height, VISIBILITY_FORMAT, COLOR_ATTACHMENT | STORAGE_IMAGE | COPY_DST, name="visibility"
        )
        self.position = Image(ctx, width, height, POSITION_FORMAT, resolved, name="position")
        self.normal = Image(ctx, width, height, NORMAL_FORMAT, resolved, name="normal")
        self.albedo = Image(ctx, width, height, ALBEDO_FORMAT, resolved, name="albedo")
        self.gbuffer = [self.position, self.normal, self.albedo]
        self.normal8 = Image(ctx, width, height, RGBA8_SNORM, STORAGE_IMAGE, name="normal (8-bit)")  # the denoiser's
        # the data AOVs the resolve writes (only read back)
        self.view_depth = Image(ctx, width, height, R32F, resolved, name="depth")
        self.triangle_id = Image(ctx, width, height, R32UI, resolved, name="triangle id")
        self.object_id = Image(ctx, width, height, R32UI, resolved, name="object id")
        self.material_id = Image(ctx, width, height, R32UI, resolved, name="material id")
        self.motion = Image(ctx, width, height, RG32F, resolved, name="motion")
        # the lighting's material inputs: roughness, metallic, occlusion (RGBA8 unorm) and emitted radiance
        self.material = Image(ctx, width, height, RGBA8, resolved, name="material")
        self.emissive = Image(ctx, width, height, RGBA16F, resolved, name="emissive")
        self.instance_id = Image(ctx, width, height, R32UI, resolved, name="instance id")
        # where each pixel's surface point was in the previous frame (its instance's previous transform): the
        # temporal reprojection's same-surface tests
        self.prev_position = Image(ctx, width, height, POSITION_FORMAT, STORAGE_IMAGE, name="previous position")
        self.prev_normal = Image(ctx, width, height, RGBA16F, STORAGE_IMAGE, name="previous normal")
        # where the shadow rays start relative to `position` (the terminator shift: terminator.glsl)
        self.terminator = Image(ctx, width, height, RGBA16F, STORAGE_IMAGE, name="terminator shift")
        # (sampled: the software raster's merge compares its depth with the hardware raster's)
        self.depth = Image(ctx, width, height, DEPTH_FORMAT, DEPTH_ATTACHMENT | SAMPLED, name="raster depth")
        self.color = Image(ctx, width, height, RGBA8, STORAGE_IMAGE | COPY_SRC, name="color")
        self.hdr = Image(ctx, width, height, RGBA16F, STORAGE_IMAGE | COPY_SRC | COPY_DST, name="hdr")
        # temporal anti-aliasing (engine/passes/taa.py): this frame's resolved radiance and the history it becomes
        # (alpha: the frames it holds)
        self.taa_out = Image(ctx, width, height, RGBA16F, STORAGE_IMAGE | COPY_SRC | COPY_DST, name="taa output")
        self.taa_history = Image(ctx, width, height, RGBA16F, STORAGE_IMAGE | COPY_DST, name="taa history")
        # The previous frame's G-buffer position and normal (temporal reprojection / disocclusion tests).
        self.hist_position = Image(
            ctx, width, height, POSITION_FORMAT, STORAGE_IMAGE | COPY_DST, name="history position"
        )
        self.hist_normal = Image(ctx, width, height, NORMAL_FORMAT, STORAGE_IMAGE | COPY_DST, name="history normal")
        self.hist_instance = Image(ctx, width, height, R32UI, STORAGE_IMAGE | COPY_DST, name="history instance")
        self.signals = {"masks": Signal(ctx, "masks", n, light_capacity), "ao": Signal(ctx, "ao", n, 1)}
        buf_usage = STORAGE | TRANSFER_SRC | TRANSFER_DST
        self.len_cur = Buffer(ctx, n * 4, buf_usage, name="history length")
        self.len_hist = Buffer(ctx, n * 4, buf_usage, name="previous history length")
        # the traced reflections (engine/passes/reflections.py): radiance and a weight per pixel (vec4), raw, the
        # temporal blend (cur) and its copy for the next frame (hist), the spatial filter's ping-pong and result
        self.reflection = {part: Buffer(ctx, n * 16, buf_usage, name=f"reflection {part}") for part in REFLECTION}
        # the diffuse GI's irradiance (engine/passes/gi.py): a like chain on half-resolution cells, upsampled
        self.gi = {
            part: Buffer(ctx, n * (32 if part == "cells" else 16), buf_usage, name=f"gi {part}") for part in GI_BUFFERS
        }
        # transparent surfaces drawn by rays (engine/passes/transparency.py): radiance and its weight per pixel
        self.transparency = Buffer(ctx, n * 16, buf_usage, name="transparency")
        self.readbacks: dict = {}  # (AOV names, slot) -> (host buffer, {name: offset})
        images = [
            self.visibility,
            self.normal8,
            self.position,
            self.normal,
            self.albedo,
            self.depth,
            self.color,
            self.hdr,
            self.hist_position,
            self.hist_normal,
            self.view_depth,
            self.triangle_id,
            self.object_id,
            self.material_id,
            self.motion,
            self.material,
            self.emissive,
            self.instance_id,
            self.prev_position,
            self.prev_normal,
            self.terminator,
            self.hist_instance,
            self.taa_out,
            self.taa_history,
        ]
        self._objects = images + [
            self.len_cur,
            self.len_hist,
            *self.reflection.values(),
            *self.gi.values(),
            self.transparency,
        ]
        # the software raster's 64-bit depth + visibility id per pixel (engine/passes/soft_raster.py), on devices
        # with 64-bit buffer atomics, where one storage buffer can hold it
        soft = ctx.int64_atomics and n * 8 <= int(ctx.limits.maxStorageBufferRange)
        self.soft_visibility = Buffer(ctx, n * 8, STORAGE | TRANSFER_DST, name="soft visibility") if soft else None
        if self.soft_visibility is not None:
            self._objects.append(self.soft_visibility)
        for sig in self.signals.values():
            self._objects += sig.buffers()
        self.resources = {
            "frame": frame_ubo,
            **{
                name: getattr(self, name)
                for name in (
                    "visibility",
                    "position",
                    "normal",
                    "albedo",
                    "normal8",
                    "depth",
                    "color",
                    "hdr",
                    "hist_position",
                    "hist_normal",
                    "len_cur",
                    "len_hist",
                    "view_depth",
                    "triangle_id",
                    "object_id",
                    "material_id",
                    "motion",
                    "material",
                    "emissive",
                    "instance_id",
                    "prev_position",
                    "prev_normal",
                    "terminator",
                    "hist_instance",
                    "soft_visibility",
                    "taa_out",
                    "taa_history",
                )
            },
        }
        for sname, sig in self.signals.items():
            self.resources.update({f"{sname}.{part}": getattr(sig, part) for part in Signal.NAMES})
        self.resources.update({f"refl.{part}": buf for part, buf in self.reflection.items()})
        self.resources.update({f"gi.{part}": buf for part, buf in self.gi.items()})
        self.resources["transp"] = self.transparency
        # Every colour image in GENERAL layout; the visibility image starts as background (each frame's resolve leaves
        # it so again); the histories zero.
        with ctx.one_shot() as cmd:
            for img in images:
                if img is not self.depth:
                    to_general(
                        cmd,
                        img,
                        clear=img
                        in (
                            self.visibility,
                            self.hist_position,
                            self.hist_normal,
                            self.hist_instance,
                            self.taa_history,
                            self.taa_out,
                        ),
                    )
            for buf in (self.len_cur, self.len_hist, *self.reflection.values(), *self.gi.values(), self.transparency):
                fill(cmd, buf, 0)

    def __getitem__(self, name: str):
        return self.resources[name]

    @staticmethod
    def check_capacity(ctx, width, height, lights):
        """The light masks are one storage buffer per stage, light-major: it must fit the device's
        maxStorageBufferRange (128 MiB on lavapipe: 16 lights at 1920x1080, 8 up to 2560x1600)."""
        need, limit = width * height * 4 * max(lights, 1), int(ctx.limits.maxStorageBufferRange)
        if need > limit:
            raise ConfigError(
                f"size {width}x{height} with {lights} lights: the light masks need {need / 2**20:.1f} MiB per "
                f"buffer, over this device's maxStorageBufferRange of {limit / 2**20:.0f} MiB; use fewer lights "
                f"or a smaller size"
            )

    def readback(self, ctx, aovs: tuple, slot: int = 0):
        """The host buffer (host-cached memory where the device has it) that `aovs` are read back into, and each
        one's offset in it: exactly their bytes, each part aligned to 16 bytes. One per (aovs, slot)."""
        key = (aovs, slot)
        if key not in self.readbacks:
            n, offsets, off = self.width * self.height, {}, 0
            for name in aovs:
                spec = AOVS[name]
                off = -(-off // 16) * 16  # a copy's buffer offset is a multiple of its texel size (16 B at most)
                offsets[name] = off
                off += n * spec.bytes * (self.light_capacity if spec.per_light else 1)
            buf = Buffer(ctx, max(off, 16), TRANSFER_DST, host=True, name=f"readback {slot}")
            self.readbacks[key] = (buf, offsets)
        return self.readbacks[key]

    def record_readback(self, rec: Recorder, buf, offsets: dict):
        """Copy the AOVs' targets into their parts of `buf` (after the lighting pass): disjoint parts of one buffer,
        one barrier before them all."""
        sources = {name: self.resources[AOVS[name].target] for name in offsets}
        rec.use(reads=list(sources.values()), writes=[buf], stage=TRANSFER)
        for name, src in sources.items():
            if isinstance(src, Image):
                rec.image_to_buffer(src, buf, offsets[name], declared=True)
            else:
                rec.copy(src, buf, [(0, offsets[name], src.size)], declared=True)
        rec.to_host(buf)

    def read(self, buf, offsets: dict, n_lights: int) -> dict:
        """The AOVs as numpy arrays, each one copy of the mapped memory (the buffer is written again by a later
        frame), made in row blocks on the worker pool: large frames are memory-bound copies that numpy runs without
        the GIL. The light masks come as (H, W, lights), ids as int32 (-1: background)."""
        h, w = self.height, self.width
        raw = buf.view(np.uint8)
        out, tasks = {}, []
        rows = max(1, (1 << 18) // max(w, 1))  # about 256k pixels' worth of rows per task
        for name, off in offsets.items():
            spec = AOVS[name]
            if spec.per_light:
                lights = max(n_lights, 1)
                src = np.frombuffer(raw, np.float32, h * w * lights, off).reshape(lights, h, w)[:n_lights]
                dst = out[name] = np.empty((h, w, n_lights), np.float32)
                view = np.moveaxis(src, 0, -1)
            elif spec.dtype == "unorm8":  # one 8-bit unorm channel of an RGBA8 target, as float32 in [0, 1]
                src = np.frombuffer(raw, np.uint8, h * w * spec.bytes, off).reshape(h, w, spec.bytes)
                dst = out[name] = np.empty((h, w), np.float32)
                view = src[..., spec.first]
                tasks += [
                    lambda d=dst, v=view, a=a: np.divide(v[a : a + rows], np.float32(255.0), out=d[a : a + rows])
                    for a in range(0, h, rows)
                ]
                continue
            else:
                item = np.dtype(spec.dtype).itemsize
                per_pixel = spec.bytes // item
                src = np.frombuffer(raw, spec.dtype, h * w * per_pixel, off).reshape(h, w, per_pixel)
                dtype = np.float32 if spec.dtype == "float16" else spec.dtype
                shape = (h, w, spec.channels) if spec.channels > 1 else (h, w)
                dst = out[name] = np.empty(shape, dtype)
                if spec.channels < per_pixel and spec.dtype != "float16":  # the first channels of each pixel: as
                    view = raw[off : off + h * w * spec.bytes].reshape(h, w, spec.bytes)[..., : spec.channels * item]
                    dst = dst.view(np.uint8).reshape(h, w, spec.channels * item)  # bytes (a faster strided copy)
                else:
                    view = src[..., : spec.channels] if spec.channels > 1 else src[..., 0]
            tasks += [lambda d=dst, v=view, a=a: np.copyto(d[a : a + rows], v[a : a + rows]) for a in range(0, h, rows)]
        run(tasks, default_threads())
        return out

    def destroy(self):
        for buf, _ in self.readbacks.values():
            buf.destroy()
        self.readbacks.clear()
        self._destroy_targets()

    def _destroy_targets(self):
        for obj in self._objects:
            obj.destroy()
