"""The environment light on the GPU: the tables of engine/scene/envtables.py in one storage buffer (read by
shaders/glsl/include/environment.glsl). Tables are made once per environment (`key()`) and kept for the next
scene that has the same (the default sky of many scenes with one sun)."""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from ..scene import envtables
from ..vk import upload_buffer
from ..vk.resources import STORAGE

_TABLES: OrderedDict = OrderedDict()  # key -> float32 words (a few recent environments)
_KEEP = 4


def tables(environment) -> np.ndarray:
    """The buffer's words for an Environment or Sky (cached by its key)."""
    key = environment.key()
    words = _TABLES.get(key)
    if words is None:
        words = envtables.build(environment.image(), environment.intensity, environment.rotation)
        _TABLES[key] = words
        while len(_TABLES) > _KEEP:
            _TABLES.popitem(last=False)
    _TABLES.move_to_end(key)
    return words


class GpuEnvironment:
    """One environment's buffer; `key` tells whether it is still the scene's."""

    def __init__(self, ctx, environment):
        self.key = environment.key()
        self.buffer = upload_buffer(ctx, tables(environment), STORAGE, name="environment")

    def destroy(self):
        self.buffer.destroy()
