"""A pytest plugin (`-p trimesh_ray_plugin`) that runs trimesh's own ray tests with `engine.RayMeshIntersector`
substituted for both of trimesh's intersectors; tests/test_trimesh_ray.py runs it in a subprocess over the test files
of trimesh's source distribution.

Every intersector those tests make, through `mesh.ray` (`Trimesh.__init__`) or by name (`ray_triangle.` /
`ray_pyembree.RayMeshIntersector(mesh)`), is ours. The sdist ships trimesh's test files but not their helper module
`generic` nor the `models/` folder: `generic` is provided here (what the ray tests use of it), and a test that loads a
model file is skipped, naming the file.
"""

from __future__ import annotations

import logging
import sys
import time
import types

import numpy as np
import pytest
import trimesh
import trimesh.ray
import trimesh.ray.ray_triangle

import engine

MADE: list[engine.RayMeshIntersector] = []


class SubstitutedIntersector(engine.RayMeshIntersector):
    """Ours, recorded so that each test's intersectors are closed and checked for validation errors after it."""

    def __init__(self, mesh, *args, **kwargs):
        super().__init__(mesh, *args, **kwargs)
        MADE.append(self)


def _needs_model(name, *args, **kwargs):
    pytest.skip(f"needs trimesh's test model {name!r}: its sdist does not ship models/ (only its git repository)")


class _NoData(dict):
    def __getitem__(self, key):
        pytest.skip(f"needs trimesh's test data {key!r}: its sdist does not ship models/ (only its git repository)")


def _generic() -> types.ModuleType:
    """What trimesh's ray tests use of their helper module `tests/generic.py`."""
    g = types.ModuleType("generic")
    g.np = np
    g.trimesh = trimesh
    g.time = time
    g.log = logging.getLogger("trimesh")
    g.random = np.random.random
    g.get_mesh = _needs_model
    g.data = _NoData()
    return g


def pytest_configure(config):
    sys.modules["generic"] = _generic()
    trimesh.ray.ray_triangle.RayMeshIntersector = SubstitutedIntersector
    if trimesh.ray.has_embree:
        trimesh.ray.ray_pyembree.RayMeshIntersector = SubstitutedIntersector


@pytest.fixture(autouse=True)
def _close_and_check():
    """Close the intersectors a test made; a Vulkan validation error fails the test."""
    start = len(MADE)
    yield
    errors = []
    for intersector in MADE[start:]:
        intersector.close()
        errors += intersector.validation_errors
    del MADE[start:]
    assert not errors, "Vulkan validation errors:\n" + "\n".join(errors[:10])
