"""A pytest plugin (`-p open3d_raycasting_plugin`) that runs Open3D's own RaycastingScene tests
(tests/data/open3d/test_raycasting_scene.py) with `engine.RaycastingScene` substituted for
`open3d.t.geometry.RaycastingScene`, on the backend $HYBRID_TEST_RT_BACKEND names (default "vulkan");
tests/test_open3d_raycasting.py runs it in a subprocess.

The shim: Open3D's test helper module `open3d_test` (its `list_devices`: the CPU only, as the suite runs here) and
the `device=` argument of an Open3D device (an `open3d.core.Device`) dropped: ours picks its Vulkan device itself.
"""

from __future__ import annotations

import os
import sys
import types

import open3d as o3d
import pytest

import engine

BACKEND = os.environ.get("HYBRID_TEST_RT_BACKEND", "vulkan")
MADE: list[engine.RaycastingScene] = []


class SubstitutedScene(engine.RaycastingScene):
    """Ours, taking Open3D's device argument, recorded so that each test's scenes are closed and checked after it."""

    def __init__(self, nthreads=0, device=None, **kwargs):
        if isinstance(device, o3d.core.Device):
            device = None
        kwargs.setdefault("backend", BACKEND)
        super().__init__(nthreads, device, **kwargs)
        MADE.append(self)


def _open3d_test() -> types.ModuleType:
    """What the suite uses of Open3D's `python/test/open3d_test.py`."""
    m = types.ModuleType("open3d_test")
    m.list_devices = lambda **kwargs: [o3d.core.Device("CPU:0")]
    return m


def pytest_configure(config):
    sys.modules["open3d_test"] = _open3d_test()
    o3d.t.geometry.RaycastingScene = SubstitutedScene


@pytest.fixture(autouse=True)
def _close_and_check():
    """Close the scenes a test made; a Vulkan validation error fails the test."""
    start = len(MADE)
    yield
    errors = []
    for scene in MADE[start:]:
        assert scene.backend == BACKEND, scene.backend
        scene.close()
        errors += scene.validation_errors
    del MADE[start:]
    assert not errors, "Vulkan validation errors:\n" + "\n".join(errors[:10])
