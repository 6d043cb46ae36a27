"""Open3D's own RaycastingScene tests (tests/data/open3d/, its python/test/t/geometry/test_raycasting_scene.py) run
with engine.RaycastingScene substituted for Open3D's (tests/open3d_raycasting_plugin.py), on both backends."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from helpers import run_plugin_suite

HERE = Path(__file__).resolve().parent
SUITE = HERE / "data" / "open3d" / "test_raycasting_scene.py"


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["vulkan", "embree"])
def test_open3d_raycasting_tests_pass_with_our_scene(tmp_path, backend):
    pytest.importorskip("open3d", reason="Open3D's suite imports open3d (the dev extra)")
    if backend == "embree":
        pytest.importorskip("embreex", reason="the embree backend needs embreex (the [embree] extra)")
    shutil.copy(SUITE, tmp_path / SUITE.name)
    (tmp_path / "pytest.ini").write_text("[pytest]\n")  # the rootdir: none of our settings apply
    proc, outcome = run_plugin_suite(
        tmp_path,
        [SUITE.name],
        plugin="open3d_raycasting_plugin",
        ini=tmp_path / "pytest.ini",
        backend=backend,
        report=tmp_path / "junit.xml",
    )
    summary = "\n".join(f"  {kind:8} {name} {msg[:150]}" for name, (kind, msg) in sorted(outcome.items()))
    print(f"Open3D's RaycastingScene tests with engine.RaycastingScene ({backend}):\n{summary}")
    assert proc.returncode == 0 and all(kind == "passed" for kind, _ in outcome.values()), (
        f"{proc.stdout[-4000:]}\n{summary}"
    )
    assert len(outcome) >= 18, summary  # every test of the file ran (16 functions, 3 shapes of one)
