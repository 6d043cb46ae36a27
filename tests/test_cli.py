"""The `hybrid` command as a user runs it: output files, one-line errors, non-zero exit codes."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
from PIL import Image

from engine.errors import ConfigError
from engine.outputs import check_output_path, read_exr

REPO = Path(__file__).resolve().parent.parent


def hybrid(*args, timeout=300):
    return subprocess.run(
        [sys.executable, "-m", "engine", *map(str, args)], capture_output=True, text=True, cwd=REPO, timeout=timeout
    )


def test_render_writes_png_with_validation(tmp_path):
    out = tmp_path / "s.png"
    res = hybrid("render", "scenes/sphere.toml", "-o", out, "--size", "64x48", "--validation")
    assert res.returncode == 0, res.stderr
    assert Image.open(out).size == (64, 48)
    assert "validation: no errors" in res.stdout


def test_render_aov(tmp_path):
    out = tmp_path / "n.png"
    res = hybrid("render", "scenes/sphere.toml", "-o", out, "--size", "32x32", "--aov", "normal")
    assert res.returncode == 0, res.stderr
    img = Image.open(out).convert("RGB")
    r, g, b = img.getpixel((16, 16))
    assert b > 240 and 100 < r < 155 and 100 < g < 155  # +z normal maps to (0.5, 0.5, 1.0)


def test_info_lists_lavapipe():
    res = hybrid("info")
    assert res.returncode == 0, res.stderr
    assert "llvmpipe" in res.stdout and "would use" in res.stdout


def one_line_error(res, *words):
    assert res.returncode != 0
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), res.stderr
    for w in words:
        assert w in lines[0], (w, lines[0])


def test_missing_scene(tmp_path):
    one_line_error(hybrid("render", tmp_path / "nope.obj", "-o", tmp_path / "x.png"), "nope.obj")


def test_bad_size_option(tmp_path):
    one_line_error(hybrid("render", "scenes/sphere.toml", "-o", tmp_path / "x.png", "--size", "0x10"), "size")
    one_line_error(hybrid("render", "scenes/sphere.toml", "-o", tmp_path / "x.png", "--size", "big"), "size")


def test_corrupt_mesh(tmp_path):
    bad = tmp_path / "broken.glb"
    bad.write_bytes(b"glTF\x02\x00\x00\x00garbage" * 10)
    one_line_error(hybrid("render", bad, "-o", tmp_path / "x.png", "--size", "16x16"), "broken.glb")


def test_toml_syntax_error(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[camera\neye = [0, 0, 5]\n")
    one_line_error(hybrid("render", bad, "-o", tmp_path / "x.png", "--size", "16x16"), "bad.toml")


def test_unwritable_output(tmp_path):
    one_line_error(
        hybrid("render", "scenes/sphere.toml", "-o", tmp_path / "no" / "dir" / "x.png", "--size", "16x16"), "x.png"
    )


def test_wrapper_script_runs_the_cli_in_the_callers_folder(tmp_path):
    """`./hybrid` sets itself up in the checkout but runs the command where it was called: relative paths (the
    output here) are the caller's, not the checkout's."""
    if not (REPO / ".venv" / ".installed").exists():
        import pytest

        pytest.skip("the checkout's .venv is not set up (./hybrid would create it)")
    (tmp_path / "bin").mkdir()
    (tmp_path / "bin" / "hybrid").symlink_to(REPO / "hybrid")  # called through a link on the PATH, too
    for script in (REPO / "hybrid", tmp_path / "bin" / "hybrid"):
        res = subprocess.run(
            [str(script), "render", str(REPO / "scenes" / "sphere.toml"), "-o", "rel.png", "--size", "32x18"],
            capture_output=True,
            text=True,
            cwd=tmp_path,
            timeout=300,
        )
        assert res.returncode == 0, res.stderr
        assert Image.open(tmp_path / "rel.png").size == (32, 18)
        assert not (REPO / "rel.png").exists()
        (tmp_path / "rel.png").unlink()


def test_render_checks_the_output_before_rendering(tmp_path):
    one_line_error(hybrid("render", "scenes/sphere.toml", "-o", tmp_path / "x.gif", "--size", "16x16"), "x.gif", ".png")
    one_line_error(
        hybrid("render", "scenes/sphere.toml", "-o", tmp_path / "x.png", "--frames", "10000000000"), "--frames"
    )


def test_bench_checks_its_outputs_and_device_before_running(tmp_path):
    """Bad --json / --plot / --device fail at once (not after minutes of benchmarks whose results they would lose)."""
    (tmp_path / "dir.json").mkdir()
    for args, words in (
        (["--json", tmp_path / "dir.json"], ("--json", "folder")),
        (["--plot", tmp_path / "plot.txt"], ("--plot", ".png")),
        (["--json", "/proc/nope/b.json"], ("--json", "/proc/nope/b.json")),
        (["--device", "no-such-gpu"], ("no-such-gpu",)),
    ):
        res = hybrid("bench", "build", "--quick", *args, timeout=60)
        one_line_error(res, *words)
        assert "BVH build" not in res.stdout  # nothing ran


def test_bundled_scene_by_name_from_any_folder(tmp_path):
    """A name with no folder and no suffix is a bundled scene; an unknown one lists them."""
    for name in ("sphere", "penumbra"):
        res = subprocess.run(
            [sys.executable, "-m", "engine", "render", name, "-o", "b.png", "--size", "32x24"],
            capture_output=True,
            text=True,
            cwd=tmp_path,
            timeout=300,
            env=dict(os.environ, PYTHONPATH=str(REPO)),
        )
        assert res.returncode == 0, res.stderr
        assert f"scenes/{name}.toml" in res.stdout and Image.open(tmp_path / "b.png").size == (32, 24)
    one_line_error(hybrid("render", "nope", "-o", tmp_path / "x.png"), "nope", "bundled: default, penumbra, sphere")


def test_no_vulkan_driver_is_one_clear_line():
    res = subprocess.run(
        [sys.executable, "-m", "engine", "info"],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=120,
        env=dict(os.environ, VK_DRIVER_FILES="/nonexistent", HYBRID_VALIDATION="0"),
    )
    one_line_error(res, "no Vulkan driver found", "mesa-vulkan-drivers")


NO_LOADER = """
import sys

class NoLoader:   # what the vulkan module does when libvulkan.so.1 cannot be opened
    def find_spec(self, name, path=None, target=None):
        if name == "vulkan":
            raise OSError("Cannot find Vulkan SDK version")

sys.meta_path.insert(0, NoLoader())
import engine
"""


def test_no_vulkan_loader_names_the_package():
    res = subprocess.run([sys.executable, "-c", NO_LOADER], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert res.returncode == 1
    assert res.stderr.strip().splitlines()[-1] == (
        "engine.errors.VulkanError: the Vulkan loader (libvulkan.so.1) is not installed: install it and a driver, "
        "e.g. apt-get install libvulkan1 mesa-vulkan-drivers"
    )


def test_printed_paths_are_escaped_and_names_that_are_not_utf8_are_written(tmp_path):
    """Issue #36: the success line printed a path's newline and escape sequence raw (errors escape them); a scene
    file name that is not UTF-8 failed the .exr write after the rendering (OpenEXR's text attributes are UTF-8); a
    name no file can have is refused before the work."""
    scene = Path(os.fsdecode(bytes(tmp_path) + b"/sc\xff.toml"))
    scene.write_text((REPO / "scenes" / "sphere.toml").read_text())
    out = Path(os.fsdecode(bytes(tmp_path) + b"/o\n\x1b[31m\xff.exr"))
    res = hybrid("render", scene, "-o", out, "--size", "16x12", "--aov", "depth")
    assert res.returncode == 0, res.stderr
    (line,) = res.stdout.splitlines()
    assert line.startswith(f"{tmp_path}/o\\n\\x1b[31m\\udcff.exr: 16x12 depth of {tmp_path}/sc\\udcff.toml ("), line
    arrays, rec = read_exr(out)
    assert rec["scene"] == str(scene) and arrays["depth"].shape == (12, 16)
    for bad in ("x\ud800.exr", "x\0.exr"):
        with pytest.raises(ConfigError, match="not a valid file name"):
            check_output_path(tmp_path / bad)
