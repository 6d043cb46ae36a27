"""The text overlay: lines of text drawn with pillow into a premultiplied RGBA image (TextImage), and the compute
pass (overlay.comp) that composites it over the renderer's colour into a small image per swapchain image, which the
presenter blits over the frame's top-left corner. The renderer's colour target itself is never written.
"""

from __future__ import annotations

import math

import numpy as np
from PIL import Image as PILImage, ImageDraw, ImageFont

from ..errors import ShaderError
from ..vk import SB, SI, Buffer, ComputePipeline, DescriptorSet
from ..vk.present import COMPUTE_STAGES, composite_image
from ..vk.reflect import reflect
from ..vk.resources import STORAGE

OVERLAY_MAX = (1024, 512)  # largest overlay rectangle (pixels, top-left corner of the window)
OVERLAY_STEP = (64, 32)  # the rectangle grows/shrinks in these steps (each change re-records)
FONT_SIZE = 13
LINE_H = 16
PAD = 6
SHADER = "overlay.comp"
# The layout the pass is built for: (set, binding, kind) of each binding, and the push-constant bytes
LAYOUT = ((0, 0, "image"), (0, 1, "image"), (0, 2, "buffer"))
PUSH_SIZE = 32


# ---------------------------------------------------------------------------------------------------------------
# Text -> premultiplied RGBA image (pillow)
# ---------------------------------------------------------------------------------------------------------------
def wrap(text: str, cols: int) -> list[str]:
    """`text` cut into lines of at most `cols` (>= 1) characters. Continuation lines start with two spaces where
    that leaves room for at least one character of text, so every line takes some of the text."""
    indent = "  " if cols > 2 else ""
    out = []
    for part in text.splitlines() or [""]:
        while len(part) > cols:
            out.append(part[:cols])
            part = indent + part[cols:]
        out.append(part)
    return out


class TextImage:
    WHITE, GREY, RED, YELLOW = (235, 235, 235), (170, 180, 190), (255, 110, 100), (255, 220, 120)

    def __init__(self):
        self.font = None
        for name in ("DejaVuSansMono.ttf", "/usr/share/fonts/truetype/dejavu/DejaVuSansMono.ttf"):
            try:
                self.font = ImageFont.truetype(name, FONT_SIZE)
                break
            except OSError:
                pass
        if self.font is None:
            try:
                self.font = ImageFont.load_default(size=FONT_SIZE)
            except TypeError:  # Pillow < 10.1
                self.font = ImageFont.load_default()
        self.char_w = max(1, int(math.ceil(self.font.getlength("M"))))

    def render(self, lines, max_w, max_h) -> np.ndarray:
        """lines: [(text, rgb)] -> (h, w, 4) uint8 premultiplied RGBA, at most max_w x max_h (text is cut)."""
        if not lines:
            return np.zeros((0, 0, 4), np.uint8)
        cols = max(1, (max_w - 2 * PAD) // self.char_w)
        max_lines = max(1, (max_h - 2 * PAD) // LINE_H)
        wrapped = []
        for text, rgb in lines:
            wrapped += [(part, rgb) for part in wrap(text, cols)]
            if len(wrapped) > max_lines:
                break
        if len(wrapped) > max_lines:
            wrapped = wrapped[: max_lines - 1] + [("...", self.GREY)]
        w = min(max_w, 2 * PAD + self.char_w * max(len(t) for t, _ in wrapped))
        h = min(max_h, 2 * PAD + LINE_H * len(wrapped))
        img = PILImage.new("RGBA", (w, h), (0, 0, 0, 150))
        draw = ImageDraw.Draw(img)
        for i, (text, rgb) in enumerate(wrapped):
            draw.text((PAD, PAD + i * LINE_H), text, font=self.font, fill=rgb + (255,))
        a = np.asarray(img, np.uint16)
        out = np.empty(a.shape, np.uint8)
        out[..., :3] = (a[..., :3] * a[..., 3:4] + 127) // 255
        out[..., 3] = a[..., 3]
        return out


# ---------------------------------------------------------------------------------------------------------------
# The compute pass: text image over the colour target -> a composite image per swapchain image
# ---------------------------------------------------------------------------------------------------------------
def check_layout(spirv: bytes):
    """A ShaderError unless overlay.comp's bindings and push constants are the ones the pass was built for."""
    interface = reflect(spirv, SHADER)
    got = tuple((b.set, b.binding, b.kind) for b in interface.bindings)
    if got != LAYOUT or interface.push_size != PUSH_SIZE:
        raise ShaderError(
            f"{SHADER}: the overlay pass needs {_layout_text(LAYOUT, PUSH_SIZE)}; the shader has "
            f"{_layout_text(got, interface.push_size)}"
        )


def _layout_text(layout, push_size) -> str:
    return ", ".join(f"set {s} binding {b} {kind}" for s, b, kind in layout) + f", {push_size} bytes of push constants"


class _Target:
    """What overlay.comp uses for one swapchain image: its descriptor set, text buffer and composite image."""

    def __init__(self, ctx, set_, max_w, max_h):
        self.set = set_
        self.composite = composite_image(ctx, max_w, max_h, name="overlay")
        self.text = Buffer(ctx, 16 + max_w * max_h * 4, STORAGE, host=True, name="overlay-text")
        self.text.view(np.uint32)[:4] = 0
        self.text_version = -1
        set_.image(1, self.composite).buffer(2, self.text)

    def destroy(self):
        self.composite.destroy()
        self.text.destroy()


class OverlayPass:
    """overlay.comp with one target per swapchain image, the current text image and the rectangle it covers.

    `rect` (w, h) is what the present command buffers blit; it changes in OVERLAY_STEP steps so that text of
    changing width does not force a re-recording every frame. `generation` is bumped when the pipeline is rebuilt.
    """

    def __init__(self, ctx, library):
        self.ctx, self.library = ctx, library
        self.sets: list[DescriptorSet] = []  # reused across resizes (their pools live until Context.close)
        self.targets: list[_Target] = []
        self.rect = self.max_rect = (0, 0)
        self.text = np.zeros((0, 0, 4), np.uint8)
        self.text_version = 0
        self.generation = 0
        self._new_set()
        spirv = library.get(SHADER)
        check_layout(spirv)
        self.pipeline = ComputePipeline(ctx, spirv, [self.sets[0]], push_size=PUSH_SIZE, name="overlay")
        self._shader_version = self._library_version()

    def _new_set(self):
        s = DescriptorSet(self.ctx, [(0, SI), (1, SI), (2, SB)], stages=COMPUTE_STAGES)
        self.sets.append(s)
        return s

    def _library_version(self):
        return getattr(self.library, "versions", {}).get(SHADER)

    # ---- targets ------------------------------------------------------------------------------------------------
    def make_targets(self, extent, count):
        """One target per swapchain image, for a swapchain of `extent`."""
        mw, mh = min(extent[0], OVERLAY_MAX[0]), min(extent[1], OVERLAY_MAX[1])
        while len(self.sets) < count:
            self._new_set()
        self.targets = [_Target(self.ctx, self.sets[i], mw, mh) for i in range(count)]
        self.max_rect = (mw, mh)
        self.rect = (min(self.rect[0], mw), min(self.rect[1], mh))

    def free_targets(self):
        for t in self.targets:
            t.destroy()
        self.targets = []

    def destroy(self):
        self.free_targets()
        if self.pipeline is not None:
            self.pipeline.destroy()
            self.pipeline = None

    # ---- text ---------------------------------------------------------------------------------------------------
    def set_text(self, rgba: np.ndarray):
        """A new text image (h, w, 4) premultiplied RGBA; each target uploads it before its next use."""
        self.text = rgba
        self.text_version += 1
        h, w = rgba.shape[:2]
        sx, sy = OVERLAY_STEP
        mw, mh = self.max_rect
        need = (min(mw, -(-w // sx) * sx), min(mh, -(-h // sy) * sy)) if w and h else (0, 0)
        rw, rh = self.rect
        # Grow at once; shrink only by more than one step, so that text whose width wobbles around a step
        # (changing digits) does not re-record every few frames.
        if need[0] > rw or need[1] > rh or rw - need[0] > sx or rh - need[1] > sy or not (need[0] and need[1]):
            self.rect = need

    def upload(self, index):
        """Write the current text into target `index`'s buffer if it has an older one (the GPU must be done
        with that target)."""
        t = self.targets[index]
        if t.text_version == self.text_version:
            return
        view = t.text.view(np.uint32)
        img = self.text
        h, w = img.shape[:2]
        mw, mh = self.max_rect
        w, h = min(w, mw), min(h, mh)
        view[0], view[1] = w, h
        if w and h:
            view[4 : 4 + w * h] = np.ascontiguousarray(img[:h, :w]).view(np.uint32).reshape(-1)
        t.text_version = self.text_version

    # ---- hot reload ---------------------------------------------------------------------------------------------
    def shader_changed(self) -> bool:
        """Whether hot reload compiled a new overlay.comp since the pipeline was built."""
        return self._library_version() != self._shader_version

    def rebuild(self):
        """Rebuild the pipeline from the library's overlay.comp (the GPU must be idle); a failure keeps the last
        good pipeline and is listed in the library's errors."""
        lib = self.library
        self._shader_version = self._library_version()
        try:
            spirv = lib.get(SHADER)
            check_layout(spirv)
            self.pipeline.rebuild(spirv)
            self.generation += 1
        except ShaderError as exc:
            lib.errors[str(lib.glsl_dir / SHADER)] = str(exc)

    # ---- recording ----------------------------------------------------------------------------------------------
    def draw(self, cmd, index, color, extent):
        """Record overlay.comp for target `index`: the colour image (scaled from the swapchain's `extent`) under
        the text, into the target's composite image, over `rect`."""
        t = self.targets[index]
        t.set.image(0, color)
        rw, rh = self.rect
        push = np.zeros(8, np.float32)
        push[:4].view(np.int32)[:] = (0, 0, rw, rh)
        push[4:] = (color.width / extent[0], color.height / extent[1], color.width, color.height)
        self.pipeline.dispatch(cmd, [t.set], (rw + 7) // 8, (rh + 7) // 8, push=push)
