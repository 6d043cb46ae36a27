"""trimesh's own ray tests, from its source distribution at the installed version, run with engine.RayMeshIntersector
substituted for trimesh's intersectors (tests/trimesh_ray_plugin.py does the substituting), on both backends; the
model files they load (not in the sdist) are in tests/data/trimesh/."""

from __future__ import annotations

from pathlib import Path

import pytest
import trimesh
from helpers import pip_files, run_plugin_suite

HERE = Path(__file__).resolve().parent
#: trimesh's ray test files (both are in its sdist's tests/)
FILES = ("test_ray.py", "test_ray_upstream.py")
#: trimesh's tests that must run and pass here: all of them (the model files they load are in tests/data/trimesh/);
#: the upstream ones need embreex installed (pytest.importorskip in that file)
MUST_PASS = {
    "test_ray.py": [
        "test_rays",
        "test_rps",
        "test_empty",
        "test_contains",
        "test_contains_cavity",
        "test_on_vertex",
        "test_on_edge",
        "test_multiple_hits",
        "test_contain_single",
        "test_box",
        "test_embree_duplicate_hits",
    ],
    "test_ray_upstream.py": [
        "test_issue_1362_many_rays_consistency",
        "test_issue_2504_duplicate_hits_small_scale",
        "test_issue_2324_apply_scale_breaks_embree",
        "test_issue_1496_edge_vertex_hits_any_vs_id",
        "test_issue_2317_robust_edge_hits",
        "test_issue_1898_locations_colinear_with_directions",
        "test_issue_306_single_vs_batched_rays",
        "test_issue_93_triangle_index_correct_for_first_hit",
        "test_issue_181_contains_deterministic",
        "test_issue_242_contains_matches_ground_truth",
        "test_issue_545_contains_simple_sphere",
        "test_issue_48_large_coordinate_ray_offset",
        "test_issue_331_surface_origin_no_self_hit",
        "test_issue_72_axis_aligned_voxel_hits",
        "test_issue_457_multihit_cylinder_count",
        "test_issue_1919_engines_agree_simple_mesh",
        "test_issue_1180_first_hit_arrays_aligned",
        "test_issue_1786_contains_stable_over_many_calls",
        "test_issue_2462_coplanar_ray_no_error",
    ],
}


@pytest.fixture(scope="session")
def trimesh_ray_tests() -> Path:
    """A folder with trimesh's ray test files from its sdist at the installed version, downloaded once (pip) and
    kept under the temp dir; skipped, with pip's last line, when the download fails."""
    version = trimesh.__version__
    members = {name: f"trimesh-{version}/tests/{name}" for name in FILES}
    home = pip_files(f"trimesh=={version}", members, f"hybrid-trimesh-{version}-tests", sdist=True)
    (home / "pytest.ini").write_text("[pytest]\n")  # the rootdir: none of trimesh's or our settings apply
    return home


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["vulkan", "embree"])
def test_trimesh_ray_tests_pass_with_our_intersector(trimesh_ray_tests, tmp_path, backend):
    if backend == "embree":
        pytest.importorskip("embreex", reason="the embree backend needs embreex (the [embree] extra)")
    proc, outcome = run_plugin_suite(
        trimesh_ray_tests,
        FILES,
        plugin="trimesh_ray_plugin",
        ini=trimesh_ray_tests / "pytest.ini",
        backend=backend,
        report=tmp_path / "junit.xml",
        name=lambda case: f"{case.get('classname').split('.')[-1]}.py::{case.get('name')}",
    )
    summary = "\n".join(f"  {kind:8} {name} {msg[:150]}" for name, (kind, msg) in sorted(outcome.items()))
    print(f"trimesh {trimesh.__version__}'s ray tests with engine.RayMeshIntersector ({backend}):\n{summary}")
    failed = {n: o for n, o in outcome.items() if o[0] in ("failure", "error")}
    assert not failed and proc.returncode in (0, 5), f"{proc.stdout[-4000:]}\n{summary}"
    # a skip only where embreex is not installed (the upstream file)
    for name, (kind, msg) in outcome.items():
        if kind == "skipped":
            assert "embreex" in msg or "ray_pyembree" in msg, (name, msg)
    has_embree = trimesh.ray.has_embree
    for file, tests in MUST_PASS.items():
        if file == "test_ray_upstream.py" and not has_embree:
            continue
        missing = {t for t in tests if outcome.get(f"{file}::{t}", ("absent",))[0] != "passed"}
        assert not missing, f"{file}: expected to pass: {sorted(missing)}\n{summary}"
