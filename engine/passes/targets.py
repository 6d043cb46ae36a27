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
from ..vk import Buffer, BufferView, Image
from ..vk.formats import (COLOR_ATTACHMENT, COPY_DST, COPY_SRC, D32F, DEPTH_ATTACHMENT, R32F, R32UI, RGBA8,
                          RGBA8_SNORM, RGBA16F, RGBA32F, STORAGE_IMAGE)
from ..vk.recorder import TRANSFER, Recorder, fill, to_general
from ..vk.resources import STORAGE, STORAGE_TEXEL, TRANSFER_DST, TRANSFER_SRC

POSITION_FORMAT = RGBA32F   # xyz world position, w linear view depth
NORMAL_FORMAT = RGBA32F     # xyz unit normal, w 1 where covered
ALBEDO_FORMAT = RGBA16F
VISIBILITY_FORMAT = R32UI   # triangle id + 1 (0: background)
DEPTH_FORMAT = D32F


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


#: What is read back after a frame: (name, bytes per pixel, or None for a buffer sized by the light count)
READBACK = (("color", 4), ("position", 16), ("normal", 16), ("albedo", 8), ("masks", None), ("ao", 4),
            ("masks_raw", None), ("ao_raw", 4), ("history", 4))


class Targets:
    """Every per-size image and buffer of a frame, plus the host buffer the frame is read back into."""

    def __init__(self, ctx, width, height, light_capacity, frame_ubo=None):
        self.width, self.height, self.light_capacity = width, height, light_capacity
        n = width * height
        self.check_capacity(ctx, width, height, light_capacity)
        resolved = STORAGE_IMAGE | COPY_SRC   # written by the G-buffer resolve
        self.visibility = Image(ctx, width, height, VISIBILITY_FORMAT, COLOR_ATTACHMENT | STORAGE_IMAGE | COPY_DST,
                                name="visibility")
        self.position = Image(ctx, width, height, POSITION_FORMAT, resolved, name="position")
        self.normal = Image(ctx, width, height, NORMAL_FORMAT, resolved, name="normal")
        self.albedo = Image(ctx, width, height, ALBEDO_FORMAT, resolved, name="albedo")
        self.gbuffer = [self.position, self.normal, self.albedo]
        self.normal8 = Image(ctx, width, height, RGBA8_SNORM, STORAGE_IMAGE, name="normal (8-bit)")  # the denoiser's
        self.depth = Image(ctx, width, height, DEPTH_FORMAT, DEPTH_ATTACHMENT)
        self.color = Image(ctx, width, height, RGBA8, STORAGE_IMAGE | COPY_SRC, name="color")
        self.hdr = Image(ctx, width, height, RGBA16F, STORAGE_IMAGE | COPY_SRC, name="hdr")
        # The previous frame's G-buffer position and normal (temporal reprojection / disocclusion tests).
        self.hist_position = Image(ctx, width, height, POSITION_FORMAT, STORAGE_IMAGE | COPY_DST,
                                   name="history position")
        self.hist_normal = Image(ctx, width, height, NORMAL_FORMAT, STORAGE_IMAGE | COPY_DST, name="history normal")
        self.signals = {"masks": Signal(ctx, "masks", n, light_capacity), "ao": Signal(ctx, "ao", n, 1)}
        buf_usage = STORAGE | TRANSFER_SRC | TRANSFER_DST
        self.len_cur = Buffer(ctx, n * 4, buf_usage, name="history length")
        self.len_hist = Buffer(ctx, n * 4, buf_usage, name="previous history length")
        self.offsets = {}
        off = 0
        for name, size in READBACK:
            off = -(-off // 16) * 16  # a copy's buffer offset is a multiple of its texel size (16 B at most here)
            self.offsets[name] = off
            off += n * (size if size is not None else 4 * light_capacity)
        self.readback = Buffer(ctx, off, TRANSFER_DST, host=True, name="readback")
        images = [self.visibility, self.normal8, self.position, self.normal, self.albedo, self.depth, self.color,
                  self.hdr, self.hist_position, self.hist_normal]
        self._objects = images + [self.len_cur, self.len_hist, self.readback]
        for sig in self.signals.values():
            self._objects += sig.buffers()
        self.resources = {"frame": frame_ubo, **{name: getattr(self, name) for name in (
            "visibility", "position", "normal", "albedo", "normal8", "depth", "color", "hdr", "hist_position",
            "hist_normal", "len_cur", "len_hist", "readback")}}
        for sname, sig in self.signals.items():
            self.resources.update({f"{sname}.{part}": getattr(sig, part) for part in Signal.NAMES})
        # Every colour image in GENERAL layout; the visibility image starts as background (each frame's resolve leaves
        # it so again); the histories zero.
        with ctx.one_shot() as cmd:
            for img in images:
                if img is not self.depth:
                    to_general(cmd, img, clear=img in (self.visibility, self.hist_position, self.hist_normal))
            for buf in (self.len_cur, self.len_hist):
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
                f"or a smaller size")

    def record_readback(self, rec: Recorder):
        """Copy every target into the host buffer (after the lighting pass): disjoint parts of one buffer."""
        images = (("color", self.color), ("position", self.position), ("normal", self.normal),
                  ("albedo", self.albedo))
        sig_m, sig_a = self.signals["masks"], self.signals["ao"]
        buffers = (("masks", sig_m.final), ("ao", sig_a.final), ("masks_raw", sig_m.raw), ("ao_raw", sig_a.raw),
                   ("history", self.len_cur))
        rec.use(reads=[src for _, src in images + buffers], writes=[self.readback], stage=TRANSFER)
        for name, img in images:
            rec.image_to_buffer(img, self.readback, self.offsets[name], declared=True)
        for name, buf in buffers:
            rec.copy(buf, self.readback, [(0, self.offsets[name], buf.size)], declared=True)
        rec.to_host(self.readback)

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
