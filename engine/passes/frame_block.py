"""The FRAME uniform block (engine/passes/interface.py `FRAME`, set 0 binding 0 of every pass that reads it): its
host-visible buffer, the frame resource "frame", and the one place that writes it, in place, before each submit.

A frame is written whole (`write`) when its scene, lights or settings changed; a frame that repeats the last one
changes only the frame index (`again`), or also the camera's fields (`move_camera`): what `write` would have
written, bit for bit (tests/test_host_cost.py). The block also keeps the frame index (which seeds the soft-shadow and
AO samples) and the last frame's camera, the next frame's previous camera (temporal reprojection). Where `jitter`
is on (TAA, or `spp`'s sub-frames: frames that read back no data AOV), the raster's sample point moves within the
pixel with the frame index (engine/passes/taa.py `jitter_offset`), or with `jitter_index` where that is set.
"""

from __future__ import annotations

import math

import numpy as np

from ..vk import Buffer
from ..vk.resources import UNIFORM
from .interface import FRAME, FRAME_BYTES, camera_fields, pack_frame
from .taa import TAA_ALPHA, camera_cut, jitter_offset


class FrameBlock:
    """The frame block of one renderer: `buffer` (bound by the passes as "frame") and its mapped FRAME record."""

    def __init__(self, ctx):
        self.buffer = Buffer(ctx, FRAME_BYTES, UNIFORM, host=True, name="frame")
        self.record = self.buffer.view(FRAME.dtype).reshape(())  # the mapped block, written in place
        self.frame_index = 0  # frames written since the renderer was made or its history reset
        self.view_proj = None  # the last frame's view-projection matrix (None: no previous frame to reproject)
        self.settled = False  # prev_view_proj is view_proj and history_reset is off (a still camera's block)
        self.jitter = False  # the raster's sample point moves within the pixel, frame by frame
        self.jitter_index = None  # the jitter sample to use instead of the frame index's (spp's sub-frames)
        self.last_camera = None  # the last frame's (eye, forward): camera cuts (TAA starts over)

    def _jitter(self) -> tuple:
        """This frame's sample point, in pixels from the pixel centre (0, 0 without jitter)."""
        if not self.jitter:
            return (0.0, 0.0)
        if self.jitter_index is None:
            return jitter_offset(self.frame_index)
        return jitter_offset(self.jitter_index, period=None)

    def restart(self) -> None:
        """The next frame as a fresh renderer's: frame index 0."""
        self.frame_index = 0

    def forget_camera(self) -> None:
        """No previous camera (another scene): the next frame's previous camera is its own."""
        self.view_proj = self.last_camera = None

    def write(
        self,
        *,
        view_proj,
        camera,
        width: int,
        height: int,
        lights,
        packed_lights,
        history_reset: bool,
        objects_moved: bool,
        ao_radius: float,
        ao_samples,
        shadow_samples,
        exposure: float,
        ambient,
        scene_scale: float,
        accum_alpha: float,
        bounds,
        tonemap: str = "neutral",
        auto_exposure: bool = False,
        shadow_terminator: bool = True,
    ) -> None:
        """The whole block: camera (`view_proj` its matrix; the previous camera the last frame's, or this one on a
        `history_reset`), image size, lights (with `packed_lights`, their LIGHT records), sampling and the rest."""
        prev = self.view_proj if self.view_proj is not None and not history_reset else view_proj
        pack_frame(
            view_proj=view_proj,
            prev_view_proj=prev,
            eye=getattr(camera, "shading_eye", camera.eye),
            forward=camera.forward,
            near=camera.near,
            width=width,
            height=height,
            frame_index=self.frame_index,
            lights=lights,
            ao_radius=ao_radius,
            ao_samples=ao_samples,
            shadow_samples=shadow_samples,
            exposure=exposure,
            ambient=ambient,
            scene_scale=scene_scale,
            accum_alpha=accum_alpha,
            pixel_footprint=2.0 * math.tan(math.radians(camera.fov_y) / 2.0) / height,
            history_reset=history_reset,
            bounds=bounds,
            out=self.record,
            packed_lights=packed_lights,
            objects_moved=objects_moved,
            tonemap=tonemap,
            auto_exposure=auto_exposure,
            shadow_terminator=shadow_terminator,
            jitter=self._jitter(),
            taa_alpha=TAA_ALPHA,
            camera_cut=camera_cut(self.last_camera, camera, scene_scale),
        )
        self.settled = False
        self._next(view_proj, camera)

    def again(self, objects_moved: bool) -> None:
        """The last frame again (same scene, lights, settings and camera): its block but for the frame index and
        whether an instance moved; on the first such frame also the previous camera, now this one, and the history
        reset flag, now off."""
        block = self.record
        if not self.settled:
            block["prev_view_proj"] = block["view_proj"]
            block["history_reset"] = block["camera_cut"] = 0.0
            self.settled = True
        block["frame_index"], block["objects_moved"] = self.frame_index, objects_moved
        block["jitter"] = self._jitter()
        self.frame_index += 1

    def move_camera(self, view_proj, camera, height: int, objects_moved: bool) -> None:
        """The last frame from another camera (the viewer while flying): the camera's fields rewritten, the last
        frame's camera the previous one; lights, settings and scene stay, and so does the temporal history."""
        block = self.record
        block["prev_view_proj"] = block["view_proj"]  # the last frame's camera
        block["camera_cut"] = camera_cut(self.last_camera, camera, float(block["scene_scale"]))
        camera_fields(block, view_proj, camera, height)
        block["history_reset"] = 0.0
        block["frame_index"], block["objects_moved"] = self.frame_index, objects_moved
        block["jitter"] = self._jitter()
        self.settled = False
        self._next(view_proj, camera)

    def _next(self, view_proj, camera) -> None:
        self.frame_index += 1
        self.view_proj = view_proj
        self.last_camera = (np.asarray(camera.eye, np.float64), np.asarray(camera.forward, np.float64))
