"""Path-tracing pass (shaders/glsl/path.comp): progressive samples per pixel added into a float32 sum, and the sum's
mean tonemapped into the colour targets.

A megakernel rather than a wavefront: one invocation follows a pixel's path to its end (no queues between kernels,
no per-bounce dispatches or ray buffers, one recorded dispatch per batch of samples). On lavapipe, where the
"threads" of a SIMD group are lanes of one CPU core, a wavefront's regrouping would cost more memory traffic than
the divergence it saves. A batch's dispatches (one per sample) are recorded once and re-submitted; the batch's first
sample index and count come from a host-written uniform block (`write_params`).
"""

from __future__ import annotations

import numpy as np

from ..vk import Buffer
from ..vk.resources import STORAGE, UNIFORM
from .base import read, update, write
from .raypass import RayPass

FILTERS = ("box", "gaussian")
#: Paths per submitted batch at most (pixels x samples; one dispatch per sample): a batch that no driver's watchdog
#: would cut short, and the progress bar's step; at most MAX_BATCH samples.
PATHS_PER_BATCH = 1 << 20
MAX_BATCH = 64
PARAMS = np.dtype(
    [("inv_view_proj", "<f4", (4, 4)), ("eye", "<f4", 4), ("batch", "<u4", 4), ("info", "<u4", 4)]
)  # path.comp's PathBlock (std140)


class PathPass(RayPass):
    name = "path"
    shader = "path.comp"
    bindings = {
        "frame": read("uniform", "frame"),
        "path": read("uniform"),
        "accum": update("buffer"),
        "vertices": read("uniform_texel"),
        "triangles": read("uniform_texel"),
        "materials": read("uniform_texel"),
        "alpha_tris": read("uniform_texel"),
        "textures": read("texture"),
        "instances": read("uniform_texel"),
        "emitters": read("uniform_texel"),
        "out_color": write("image", "color"),
        "out_hdr": write("image", "hdr"),
        "env": read("buffer"),  # environment.glsl: bound by bind_environment
    }

    def __init__(self, ctx, library, resources, bvh_set, bvh_layout="binary"):
        self.accum = None
        self.params_buffer = Buffer(ctx, PARAMS.itemsize, UNIFORM, host=True, name="path params")
        self.params = self.params_buffer.view(PARAMS).reshape(())
        self.scene_data = None  # the PathScene bound (engine/gpu/pathscene.py)
        super().__init__(ctx, library, resources, bvh_set, bvh_layout)
        self.set.bind("path", self.params_buffer)

    def bind(self, resources, targets=None):
        super().bind(resources, targets)
        size = resources["color"].width * resources["color"].height * 16
        if self.accum is None or self.accum.size != size:
            if self.accum is not None:
                self.accum.destroy()
            self.accum = Buffer(self.ctx, size, STORAGE, name="path radiance")
            self.set.bind("accum", self.accum)

    def bind_environment(self, env) -> None:
        """The scene's environment buffer (engine/gpu/environment.py)."""
        self.set.bind("env", env.buffer)

    def bind_data(self, data, geometry) -> None:
        """The scene's path-tracing buffers (a PathScene) and its materials (SceneGeometry's texel view)."""
        data.bind(self.set)
        self.set.bind("materials", geometry.views[3])
        self.scene_data = data

    @staticmethod
    def batch_size(width: int, height: int) -> int:
        """Samples per pixel in one trace dispatch."""
        return max(1, min(MAX_BATCH, PATHS_PER_BATCH // (width * height)))

    def write_params(self, inv_view_proj, eye, first, count, max_depth, pixel_filter, seed, lights) -> None:
        p = self.params
        p["inv_view_proj"] = np.asarray(inv_view_proj, np.float32).T  # GLSL: column-major
        p["eye"][:3] = eye
        p["batch"] = first, count, max_depth, FILTERS.index(pixel_filter)
        p["info"] = seed, self.scene_data.emitter_count, lights, 0

    def record_trace(self, rec, targets) -> None:
        """A batch: `batch_size` dispatches, sample k of the batch in each."""
        for k in range(self.batch_size(targets.width, targets.height)):
            self.dispatch(
                rec,
                self.tiles(targets.width, targets.height),
                push=np.array([0, k], np.uint32),
                reads=[self.accum],
                writes=[self.accum],
            )

    def record_resolve(self, rec, targets) -> None:
        self.dispatch(
            rec,
            self.tiles(targets.width, targets.height),
            push=np.array([1, 0], np.uint32),
            reads=[self.accum],
            writes=[targets.color, targets.hdr],
        )

    def destroy(self) -> None:
        if self.accum is not None:
            self.accum.destroy()
        self.params_buffer.destroy()
