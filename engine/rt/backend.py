"""Which engine traces the rays: the `backend` argument of Tracer, RaycastingScene and RayMeshIntersector.

"vulkan" is the GLSL kernels (engine/rt/tracer.py), "embree" Embree on the host's cores through embreex
(engine/rt/embree.py, which registers its Tracer in TRACERS), "auto" Embree where the only Vulkan device is a CPU.
"""

from __future__ import annotations

import functools
import os
from typing import Any

from ..errors import ConfigError, VulkanError
from ..vk import choose_device, describe_devices

#: the Tracer class of each backend other than Vulkan, registered by its module (engine/rt/embree.py)
TRACERS: dict[str, type] = {}
#: the values of a `backend` argument
BACKENDS = ("auto", "vulkan", "embree")
#: what to install for backend="embree"
INSTALL = "pip install 'hybrid-renderer[embree]' (embreex)"


@functools.cache
def embree_available() -> bool:
    """Whether embreex imports here (a wheel exists for x86_64 Linux, macOS and Windows)."""
    try:  # (optional: the [embree] extra)
        from embreex import mesh_construction, rtcore_scene  # noqa: F401
    except (ImportError, OSError):
        return False
    return True


@functools.cache
def _default_device_is_cpu(selector: str | None) -> bool:
    """Whether the Vulkan device a Tracer would open by default ($HYBRID_DEVICE, else the best) is a CPU, or there is
    no usable Vulkan device at all (cached per process and $HYBRID_DEVICE value: device lists do not change)."""
    try:
        devices = describe_devices()
        return devices[choose_device(devices)]["type"] == "CPU"
    except VulkanError:
        return True


def check_backend(backend: Any, who: str) -> str:
    """`backend` if it is one of BACKENDS, else a ConfigError naming `who`; "embree" without embreex is one too."""
    if not isinstance(backend, str) or backend not in BACKENDS:
        raise ConfigError(f"{who}: backend must be one of {', '.join(map(repr, BACKENDS))}, got {backend!r}")
    if backend == "embree" and not embree_available():
        raise ConfigError(f"{who}: backend='embree' needs embreex, which does not import here: {INSTALL}")
    return backend


def resolve_backend(backend: str, device: Any = None, context: Any = None) -> str:
    """ "vulkan" or "embree" for a checked `backend`: "auto" is Embree where embreex imports, no Vulkan device or
    context was given (sharing one asks for the Vulkan kernels) and the device a Tracer would open by default is a
    CPU (lavapipe / llvmpipe, or none at all); the Vulkan kernels otherwise."""
    if backend != "auto":
        return backend
    if device is not None or context is not None or not embree_available():
        return "vulkan"
    return "embree" if _default_device_is_cpu(os.environ.get("HYBRID_DEVICE") or None) else "vulkan"
