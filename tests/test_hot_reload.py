"""Shader hot reload on a copy of shaders/glsl: a changed lighting shader changes the next frame, a syntax error keeps
the last good pipeline and names the file with the compiler's message, fixing it clears the error; only affected
shaders are recompiled, and nothing is written into shaders/spv/."""

import hashlib
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from engine import Camera, DirectionalLight, Scene
from engine.errors import ShaderError
from engine.shaders import GLSL_DIR, SPV_DIR, ShaderLibrary, compile_shader

SETTINGS = dict(ao=False)  # deterministic frames: no per-frame sampling


def spv_snapshot():
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(SPV_DIR.iterdir())}


def edit(path: Path, text: str):
    """Write `text` and make sure the modification time moves (coarse file-system clocks)."""
    before = path.stat().st_mtime_ns
    path.write_text(text)
    if path.stat().st_mtime_ns == before:
        os.utime(path, ns=(before + 1_000_000, before + 1_000_000))


def black_lighting(src: str) -> str:
    """lighting.comp with the colour multiplied by 0: the original main() runs, then the rgba8 output is
    overwritten with black (found by its format, so edits elsewhere in the shader do not break this test)."""
    m = re.search(r"layout\([^)]*\brgba8\)\s*uniform\s+(?:writeonly\s+)?image2D\s+(\w+)\s*;", src)
    assert m, "lighting.comp: no rgba8 output image found; update black_lighting() in this test"
    out = m.group(1)
    assert src.count("void main()") == 1
    return (
        src.replace("void main()", "void original_main()")
        + f"\nvoid main() {{\n    original_main();\n    ivec2 p = ivec2(gl_GlobalInvocationID.xy);\n"
        f"    if (all(lessThan(p, imageSize({out})))) imageStore({out}, p, vec4(0.0, 0.0, 0.0, 1.0));\n}}\n"
    )


@pytest.fixture
def glsl_copy(tmp_path):
    dst = tmp_path / "glsl"
    shutil.copytree(GLSL_DIR, dst)
    return dst


@pytest.fixture
def scene():
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=3)
    return Scene.from_trimesh(
        m, camera=Camera.look_at((0, 0, 4), (0, 0, 0), fov_y=45.0), lights=[DirectionalLight((-0.3, -0.5, -1.0))]
    )


def test_lighting_edit_error_and_fix(make_renderer, glsl_copy, scene):
    spv_before = spv_snapshot()
    lighting = glsl_copy / "lighting.comp"
    key = str(lighting)
    original = lighting.read_text()
    r = make_renderer(64, 48, shader_dir=glsl_copy, hot_reload=True)
    baseline = dict(r.shader_errors)  # errors of shaders other than lighting.comp are not this test's business
    assert key not in baseline, baseline[key] if key in baseline else ""
    lit = r.render(scene, **SETTINGS).color
    assert lit[24, 32, :3].max() > 40  # the sphere is lit

    # A good edit: the next frame uses it.
    edit(lighting, black_lighting(original))
    black = r.render(scene, **SETTINGS).color
    assert black[..., :3].max() == 0 and np.all(black[..., 3] == 255)
    assert key not in r.shader_errors

    # A syntax error: rendering goes on with the last good (black) pipeline; the error names file and line.
    broken = original.replace("void main()", "void main() oops", 1)
    edit(lighting, broken)
    frame = r.render(scene, **SETTINGS)
    assert np.array_equal(frame.color, black)
    assert key in r.shader_errors, r.shader_errors
    msg = r.shader_errors[key]
    line = broken[: broken.index("oops")].count("\n") + 1
    assert f"lighting.comp:{line}:" in msg and "syntax error" in msg, msg
    assert "compilation errors" not in msg and "Missing entry point" not in msg, msg
    # ... and stays reported while nothing changes.
    r.render(scene, **SETTINGS)
    assert key in r.shader_errors

    # A byte that is not UTF-8: a shader error naming file and line, not a UnicodeDecodeError out of render().
    lighting.write_bytes(b"// caf\xe9\n" + original.encode())
    os.utime(lighting, ns=(1_000_000_000, 1_000_000_000))
    frame = r.render(scene, **SETTINGS)
    assert np.array_equal(frame.color, black)
    assert r.shader_errors.get(key, "").endswith("lighting.comp:1: not UTF-8 text (byte 0xe9 at offset 6)")

    # The fix: the error is gone and the original shading is back.
    edit(lighting, original)
    again = r.render(scene, **SETTINGS).color
    assert key not in r.shader_errors and r.shader_errors == baseline
    assert np.array_equal(again, lit)
    assert spv_snapshot() == spv_before, "hot reload wrote into shaders/spv/"


def test_include_edits_reach_their_users(make_renderer, glsl_copy, scene):
    """An include is watched like its users: an error in it names the include's file and line, keeps the last
    good pipeline, and only the shaders that include it are recompiled."""
    r = make_renderer(64, 48, shader_dir=glsl_copy, hot_reload=True)
    before = r.render(scene, **SETTINGS).color
    lighting, probe = glsl_copy / "lighting.comp", glsl_copy / "include" / "probe.glsl"
    original = lighting.read_text()
    probe.write_text("// a new include, used by lighting.comp only\n")
    edit(lighting, original.replace("void main()", '#include "probe.glsl"\nvoid main()', 1))
    assert np.array_equal(r.render(scene, **SETTINGS).color, before)
    assert str(lighting) not in r.shader_errors
    versions = dict(r.library.versions)
    edit(probe, "// a new include, used by lighting.comp only\nfloat broken( {\n")
    frame = r.render(scene, **SETTINGS)
    assert np.array_equal(frame.color, before)  # the last good pipeline
    msg = r.shader_errors.get(str(lighting), "")
    assert re.search(r"include/probe\.glsl:2:", msg), r.shader_errors
    assert {n for n, v in r.library.versions.items() if versions.get(n) != v} == set()  # nothing else rebuilt
    edit(probe, "// fixed\n")
    r.render(scene, **SETTINGS)
    assert str(lighting) not in r.shader_errors
    assert {n for n, v in r.library.versions.items() if versions.get(n) != v} == {"lighting.comp"}


def test_only_affected_shaders_are_recompiled(glsl_copy):
    lib = ShaderLibrary(glsl_copy, hot_reload=True)
    try:
        start = dict(lib.versions)
        assert lib.poll() == set()
        edit(glsl_copy / "lighting.comp", (glsl_copy / "lighting.comp").read_text() + "\n// edit\n")
        assert lib.poll() == {"lighting.comp"}
        changed = {n for n, v in lib.versions.items() if start.get(n) != v}
        assert changed == {"lighting.comp"}
        tmp = Path(lib._tmp.name)
        assert tmp.is_dir() and not tmp.is_relative_to(SPV_DIR)
    finally:
        lib.close()
    assert not tmp.exists()


def test_compiler_message_is_the_located_error(tmp_path):
    src = tmp_path / "bad.comp"
    src.write_text("#version 450\nlayout(local_size_x = 1) in;\nvoid main() {\n    float x = undefined_name;\n}\n")
    with pytest.raises(ShaderError) as exc:
        compile_shader(src, tmp_path / "bad.spv", tmp_path)
    msg = str(exc.value)
    assert msg.splitlines()[0] == f"{src}:4: 'undefined_name': undeclared identifier", msg
    assert "compilation errors" not in msg and "compilation terminated" not in msg
    assert not (tmp_path / "bad.spv").exists()


def test_a_refused_shader_stays_out_of_later_pipelines(make_renderer, glsl_copy, scene):
    """SPIR-V refused for a changed layout is not used later either, when a pass re-specializes its pipeline (a
    textured scene changes the G-buffer resolve's TEXTURE_ARRAYS): that frame used to crash."""
    import trimesh
    from PIL import Image

    resolve = glsl_copy / "gbuffer_resolve.comp"
    body = glsl_copy / "include" / "gbuffer_fill.glsl"  # the resolve's body (shared with gbuffer_rays.comp)
    r = make_renderer(64, 48, shader_dir=glsl_copy, hot_reload=True)
    plain = r.render(scene, **SETTINGS).color
    original = body.read_text()
    assert original.count("binding = 10, rgba8_snorm") == 1
    edit(body, original.replace("binding = 10, rgba8_snorm", "binding = 11, rgba8_snorm"))
    assert np.array_equal(r.render(scene, **SETTINGS).color, plain)
    assert "g_normal8" in r.shader_errors.get(str(resolve), ""), r.shader_errors
    meshes = []
    # two textures of two sizes: two texture arrays instead of one
    for x, rgba, size in ((0.0, (255, 0, 0, 255), 4), (5.0, (0, 255, 0, 255), 8)):
        mesh = trimesh.creation.icosphere(subdivisions=3)
        mesh.apply_translation((x, 0, 0))
        mesh.visual = trimesh.visual.TextureVisuals(
            uv=np.zeros((len(mesh.vertices), 2)), image=Image.new("RGBA", (size, size), rgba)
        )
        meshes.append(mesh)
    textured = Scene.from_trimesh(trimesh.Scene(meshes), camera=scene.camera, lights=scene.lights)
    assert sum(m.texture is not None for m in textured.materials) == 2
    red = r.render(textured, **SETTINGS).color
    assert red[24, 32, 0] > 40 and red[24, 32, 1] < red[24, 32, 0] // 2, red[24, 32]  # the texture's red


def test_a_refused_raster_shader_stays_out_of_its_specialized_pipelines(make_renderer, glsl_copy, scene):
    """The visibility raster re-specializes its pipelines for each scene (INSTANCES_TEXEL): a vertex shader refused
    for a changed layout must not come back through that (its pipelines would not match their descriptor set)."""
    vert = glsl_copy / "gbuffer.vert"
    plain = make_renderer(64, 48).render(scene, **SETTINGS).color
    r = make_renderer(64, 48, shader_dir=glsl_copy, hot_reload=True)
    original = vert.read_text()
    assert original.count("binding = 2) readonly buffer Visible") == 1
    edit(vert, original.replace("binding = 2) readonly buffer Visible", "binding = 9) readonly buffer Visible"))
    assert np.array_equal(r.render(scene, **SETTINGS).color, plain)  # the scene's first frame: specialized here
    assert "visible" in r.shader_errors.get(str(vert), ""), r.shader_errors
    assert r.gbuffer.raster.values["INSTANCES_TEXEL"] is r.gbuffer.instances_texel(r._geometry)


TINY = (
    "#version 450\n#extension GL_GOOGLE_include_directive : require\n"
    'layout(local_size_x = 1) in;\n#include "tiny.glsl"\nvoid main() {}\n'
)


@pytest.fixture
def tiny_glsl(tmp_path):
    """A folder of one small shader and its include: quick to compile."""
    (tmp_path / "include").mkdir()
    (tmp_path / "include" / "tiny.glsl").write_text("// nothing\n")
    (tmp_path / "tiny.comp").write_text(TINY)
    return tmp_path


def poll_within(lib, seconds=10.0):
    """lib.poll() on a thread: a poll that blocks (opening a FIFO) fails the test instead of hanging it."""
    import threading

    out = {}

    def run():
        try:
            out["result"] = lib.poll()
        except BaseException as exc:  # raised again on the test's thread
            out["error"] = exc

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(seconds)
    assert not t.is_alive(), "poll() blocked"
    if "error" in out:
        raise out["error"]
    return out["result"]


@pytest.mark.parametrize("bad", ["tiny.comp", "include/tiny.glsl"])
def test_a_source_that_is_not_utf8_is_a_shader_error(tiny_glsl, bad):
    lib = ShaderLibrary(tiny_glsl, hot_reload=True)
    try:
        assert lib.errors == {} and lib.versions == {"tiny.comp": 1}
        good = (tiny_glsl / bad).read_bytes()
        edit_bytes = good.replace(b"\n", b" // \xff\xfe\n", 2)  # on lines 1 and 2
        (tiny_glsl / bad).write_bytes(edit_bytes)
        os.utime(tiny_glsl / bad, ns=(1_000_000_000, 1_000_000_000))
        assert poll_within(lib) == set()  # the last good SPIR-V stays
        expect = f"{tiny_glsl / bad}:1: not UTF-8 text (byte 0xff at offset {edit_bytes.index(bytes([255]))})"
        assert lib.errors == {str(tiny_glsl / "tiny.comp"): expect}
        (tiny_glsl / bad).write_bytes(good)
        assert poll_within(lib) == {"tiny.comp"} and lib.errors == {}
    finally:
        lib.close()


def test_only_regular_files_are_watched(tiny_glsl):
    """A FIFO named like a shader is neither compiled nor opened; one where an include is looked up is an error."""
    lib = ShaderLibrary(tiny_glsl, hot_reload=True)
    try:
        os.mkfifo(tiny_glsl / "fifo.comp")
        assert poll_within(lib) == set() and lib.errors == {}
        (tiny_glsl / "include" / "tiny.glsl").unlink()
        os.mkfifo(tiny_glsl / "include" / "tiny.glsl")
        assert poll_within(lib) == set()
        assert lib.errors == {
            str(tiny_glsl / "tiny.comp"): f"{tiny_glsl / 'include' / 'tiny.glsl'}: not a regular file"
        }
    finally:
        lib.close()
