"""Committed SPIR-V must match its GLSL sources and includes (by the manifest of source hashes)."""

import shutil

from engine.shaders import GLSL_DIR, SPV_DIR, compile_all, shader_sources, stale_shaders


def test_committed_spirv_is_up_to_date():
    stale = stale_shaders(GLSL_DIR, SPV_DIR)
    assert not stale, f"stale SPIR-V, run tools/compile_shaders.py: {stale}"


def test_every_shader_has_spirv():
    for src in shader_sources(GLSL_DIR):
        assert (SPV_DIR / (src.name + ".spv")).exists(), src.name


def test_editing_an_include_makes_its_users_stale(tmp_path):
    glsl, spv = tmp_path / "glsl", tmp_path / "spv"
    shutil.copytree(GLSL_DIR, glsl)
    compile_all(glsl, spv)
    assert stale_shaders(glsl, spv) == []
    common = glsl / "include" / "common.glsl"
    common.write_text(common.read_text() + "\n// an edit\n")
    stale = stale_shaders(glsl, spv)
    assert "lighting.comp" in stale and "gbuffer_resolve.comp" in stale and "gbuffer.frag" not in stale
