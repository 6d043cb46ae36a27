"""The Python examples of README.md and docs/scenes.md run as written (the renderer's at a small size)."""

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
from PIL import Image

REPO = Path(__file__).resolve().parent.parent


def python_blocks(doc: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", (REPO / doc).read_text(), flags=re.S)


def run_block(code: str, cwd: Path):
    (cwd / "scenes").symlink_to(REPO / "scenes")  # the examples load scenes/... from the checkout's root
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.run([sys.executable, "-c", code], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


def test_readme_has_the_three_examples():
    blocks = python_blocks("README.md")
    assert len(blocks) == 4 and "engine.Renderer(" in blocks[0] and "render_many(" in blocks[1]
    assert "engine.Tracer(" in blocks[2]
    assert "engine.RayMeshIntersector(" in blocks[3] and "engine.RaycastingScene(" in blocks[3]


def test_readme_render_example(tmp_path):
    code = python_blocks("README.md")[0]
    assert "engine.Renderer(1280, 720)" in code
    res = run_block(code.replace("engine.Renderer(1280, 720)", "engine.Renderer(96, 54)"), tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    assert Image.open(tmp_path / "out.png").size == (96, 54)


def test_readme_tracer_example(tmp_path):
    res = run_block(python_blocks("README.md")[2], tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    m = re.search(r"([\d.]+)% occluded within t <= 2, ([\d.]+)% hit at all", res.stdout)
    assert m, res.stdout
    occluded, hit = float(m.group(1)), float(m.group(2))
    assert 0 < occluded < hit < 100  # rays from inside and outside a unit sphere, in every direction


def small_dataset(code: str, size: str) -> str:
    """A dataset example at 48x36 with 3 views."""
    assert f"engine.Renderer({size})" in code and "orbit_cameras(scene, 24)" in code
    return code.replace(f"engine.Renderer({size})", "engine.Renderer(48, 36)").replace(
        "orbit_cameras(scene, 24)", "orbit_cameras(scene, 3)"
    )


def test_readme_dataset_example(tmp_path):
    res = run_block(small_dataset(python_blocks("README.md")[1], "640, 480"), tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    assert sorted(p.name for p in (tmp_path / "dataset").iterdir()) == [
        f"{i:04d}.{s}" for i in range(3) for s in ("exr", "npz")
    ]
    with np.load(tmp_path / "dataset" / "0002.npz") as z:
        assert z["depth"].shape == (36, 48) and z["object_id"].dtype == np.int32 and z["K"].shape == (3, 3)
        assert np.isinf(z["depth"]).any() and (z["object_id"] == -1).any()


def test_datasets_doc_example(tmp_path):
    block = python_blocks("docs/datasets.md")[0]
    res = run_block(small_dataset(block, "640, 480") + "\nprint(sorted(arrays), camera['width'])\n", tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    assert "['color', 'depth', 'normal', 'object_id'] 48" in res.stdout
    assert len(list((tmp_path / "dataset").iterdir())) == 12


def test_readme_drop_in_example(tmp_path):
    res = run_block(python_blocks("README.md")[3], tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    m = re.search(r"(\d+) rays hit, (\d+) hits; inside: \[True, False\]", res.stdout)
    assert m, res.stdout
    rays, hits = int(m.group(1)), int(m.group(2))
    assert 0 < rays < 1000 and hits == 2 * rays  # each ray that hits the sphere goes in and out
    m = re.search(r"(\d+)% of the pixels see the sphere, (\d+)% within t <= 3.5", res.stdout)
    assert m, res.stdout
    assert 15 <= int(m.group(1)) <= 27 and 0 < int(m.group(2)) < int(m.group(1))  # a unit sphere 4 away, 60 deg
    m = re.search(r"(\d+)% of the grid inside, sdf < 0 there: True", res.stdout)
    assert m, res.stdout
    assert 13 <= int(m.group(1)) <= 18  # a unit sphere in a cube of side 3: 4.19 / 27 of it


def test_scenes_doc_example(tmp_path):
    (block,) = python_blocks("docs/scenes.md")
    res = run_block(block, tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]


def test_the_quality_tool_rewrites_its_section_and_keeps_the_words_below_it(tmp_path):
    """tools/make_hybrid_quality.py replaces docs/quality.md's section between its two markers: the words after the
    end marker (the hand-written reading of the table) and the other tools' sections stay."""
    sys.path.insert(0, str(REPO / "tools"))
    import make_hybrid_quality as m

    text = (REPO / "docs" / "quality.md").read_text()
    assert text.count(m.MARKER) == 1 and text.count(m.END) == 1
    below = text.split(m.END, 1)[1].strip()
    md = tmp_path / "quality.md"
    md.write_text(text)
    m.write_md(md, f"{m.MARKER}\nthe new table\n\n{m.END}\n")
    out = md.read_text()
    assert "the new table" in out and out.count(m.MARKER) == 1
    assert out.startswith(text.split(m.MARKER, 1)[0]) and out.rstrip().endswith(below)
