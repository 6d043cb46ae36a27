"""A pytest plugin (`-p trimesh_ray_plugin`) that runs trimesh's own ray tests with `engine.RayMeshIntersector`
substituted for both of trimesh's intersectors; tests/test_trimesh_ray.py runs it in a subprocess over the test files
of trimesh's source distribution.

Every intersector those tests make, through `mesh.ray` (`Trimesh.__init__`) or by name (`ray_triangle.` /
`ray_pyembree.RayMeshIntersector(mesh)`), is ours, on the backend $HYBRID_TEST_RT_BACKEND names (default "vulkan").
The sdist ships trimesh's test files but not their helper module `generic` nor the `models/` folder: `generic` is
provided here (what the ray tests use of it), loading the models the ray tests need from tests/data/trimesh/ (copied
from trimesh's repository); a test that loads another file is skipped, naming it.
"""

from __future__ import annotations

import gzip
import json
import logging
import os
import sys
import time
import types
from pathlib import Path

import numpy as np
import pytest
import trimesh
import trimesh.ray
import trimesh.ray.ray_triangle

import engine

MADE: list[engine.RayMeshIntersector] = []
MODELS = Path(__file__).resolve().parent / "data" / "trimesh"
BACKEND = os.environ.get("HYBRID_TEST_RT_BACKEND", "vulkan")


class SubstitutedIntersector(engine.RayMeshIntersector):
    """Ours, recorded so that each test's intersectors are closed and checked for validation errors after it."""

    def __init__(self, mesh, *args, **kwargs):
        kwargs.setdefault("backend", BACKEND)
        super().__init__(mesh, *args, **kwargs)
        MADE.append(self)


def _get_mesh(file_name, *args, **kwargs):
    """trimesh's `generic.get_mesh` over tests/data/trimesh/ (one file, or a list for several)."""
    meshes = []
    for name in (file_name, *args):
        if not (MODELS / name).is_file():
            pytest.skip(f"needs trimesh's test model {name!r}: not in tests/data/trimesh (its sdist ships none)")
        meshes.append(trimesh.load(MODELS / name, **kwargs))
    return meshes[0] if len(meshes) == 1 else meshes


class _Data(dict):
    """trimesh's `generic.data`: the JSON files of its tests/data/ that tests/data/trimesh/ has (gzipped)."""

    def __missing__(self, key):
        path = MODELS / f"{key}.json.gz"
        if not path.is_file():
            pytest.skip(f"needs trimesh's test data {key!r}: not in tests/data/trimesh (its sdist ships none)")
        with gzip.open(path, "rt") as file:
            self[key] = json.load(file)
        return self[key]


def _generic() -> types.ModuleType:
    """What trimesh's ray tests use of their helper module `tests/generic.py`."""
    g = types.ModuleType("generic")
    g.np = np
    g.trimesh = trimesh
    g.time = time
    g.log = logging.getLogger("trimesh")
    g.random = np.random.random
    g.get_mesh = _get_mesh
    g.data = _Data()
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
