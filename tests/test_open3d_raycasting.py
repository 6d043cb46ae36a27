"""Open3D's own RaycastingScene tests (tests/data/open3d/, its python/test/t/geometry/test_raycasting_scene.py) run
with engine.RaycastingScene substituted for Open3D's (tests/open3d_raycasting_plugin.py), on both backends."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

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
    report = tmp_path / "junit.xml"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(HERE.parent), str(HERE), os.environ.get("PYTHONPATH", "")]))
    env["HYBRID_TEST_RT_BACKEND"] = backend
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "pytest",
            "-q",
            "-p",
            "open3d_raycasting_plugin",
            "-p",
            "no:cacheprovider",
            "-p",
            "no:dash",
            "-c",
            str(tmp_path / "pytest.ini"),
            f"--junitxml={report}",
            SUITE.name,
        ],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert report.exists(), f"pytest did not run: {proc.stdout[-2000:]}{proc.stderr[-2000:]}"
    outcome = {}
    for case in ET.parse(report).getroot().iter("testcase"):
        kind = next((c.tag for c in case if c.tag in ("failure", "error", "skipped")), "passed")
        outcome[case.get("name")] = (kind, next((c.get("message") or "" for c in case if c.tag != "properties"), ""))
    summary = "\n".join(f"  {kind:8} {name} {msg[:150]}" for name, (kind, msg) in sorted(outcome.items()))
    print(f"Open3D's RaycastingScene tests with engine.RaycastingScene ({backend}):\n{summary}")
    assert proc.returncode == 0 and all(kind == "passed" for kind, _ in outcome.values()), (
        f"{proc.stdout[-4000:]}\n{summary}"
    )
    assert len(outcome) >= 18, summary  # every test of the file ran (16 functions, 3 shapes of one)
