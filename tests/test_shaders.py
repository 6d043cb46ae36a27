"""Committed SPIR-V must match its GLSL sources and includes (by the manifest of source hashes)."""

import shutil

import pytest

from engine.shaders import GLSL_DIR, SPV_DIR, compile_all, shader_sources, stale_shaders


def test_committed_spirv_is_up_to_date():
    stale = stale_shaders(GLSL_DIR, SPV_DIR)
    assert not stale, f"stale SPIR-V, run tools/compile_shaders.py: {stale}"


def test_every_shader_has_spirv():
    for src in shader_sources(GLSL_DIR):
        assert (SPV_DIR / (src.name + ".spv")).exists(), src.name


def test_editing_an_include_makes_its_users_stale(tmp_path):
    """On a copy of the sources and the committed SPIR-V with its manifest (compiling them all: the slow test below)."""
    glsl, spv = tmp_path / "glsl", tmp_path / "spv"
    shutil.copytree(GLSL_DIR, glsl)
    shutil.copytree(SPV_DIR, spv)
    assert stale_shaders(glsl, spv) == []
    common = glsl / "include" / "common.glsl"
    common.write_text(common.read_text() + "\n// an edit\n")
    stale = stale_shaders(glsl, spv)
    assert "lighting.comp" in stale and "gbuffer_resolve.comp" in stale and "gbuffer.frag" not in stale


@pytest.mark.slow
def test_compile_all_writes_spirv_and_a_manifest_that_matches(tmp_path):
    """compile_all (tools/compile_shaders.py's step) over a copy of the sources: every shader's SPIR-V and a manifest
    under which none is stale."""
    glsl, spv = tmp_path / "glsl", tmp_path / "spv"
    shutil.copytree(GLSL_DIR, glsl)
    manifest = compile_all(glsl, spv)
    assert sorted(manifest) == sorted(src.name for src in shader_sources(glsl))
    assert all((spv / (name + ".spv")).stat().st_size > 0 for name in manifest)
    assert stale_shaders(glsl, spv) == []
