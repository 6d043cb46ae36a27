"""The public API as a user's tools see it: render options as keyword parameters (help(), IDEs) whose defaults are
`DEFAULT_SETTINGS`, scene settings still applying where a keyword is left out, type hints on everything public
(checked by mypy over the examples), and a `Frame` that shows itself in Jupyter and has a short repr."""

import inspect
import io
import os
import pydoc
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

import engine
from engine import ConfigError, Renderer, Scene
from engine.settings import DEFAULT_SETTINGS, Default

REPO = Path(__file__).resolve().parent.parent
OWN = {
    "render": ("self", "scene", "camera", "aovs"),
    "submit": ("self", "scene", "camera", "wait", "signal_semaphores", "fence"),
}


def small_scene(**kw):
    box = trimesh.creation.box(extents=(1, 1, 1))
    ground = trimesh.creation.box(extents=(4, 0.05, 4))
    ground.apply_translation((0, -0.55, 0))
    return Scene.from_trimesh(trimesh.util.concatenate([box, ground]), **kw)


@pytest.mark.parametrize("method", ["render", "submit"])
def test_render_options_are_the_default_settings(method):
    """Every setting is a keyword-only parameter, in DEFAULT_SETTINGS' order, whose default wraps the very object
    DEFAULT_SETTINGS holds; nothing else but `**unknown` (which check_settings turns into a clear error)."""
    params = inspect.signature(getattr(Renderer, method)).parameters
    names = [n for n in params if n not in OWN[method]]
    assert names == list(DEFAULT_SETTINGS) + ["unknown"]
    for name in DEFAULT_SETTINGS:
        p = params[name]
        assert p.kind is inspect.Parameter.KEYWORD_ONLY and isinstance(p.default, Default), name
        assert p.default.value is DEFAULT_SETTINGS[name], name
        assert p.annotation is not inspect.Parameter.empty, name
    assert params["unknown"].kind is inspect.Parameter.VAR_KEYWORD


def test_help_shows_and_explains_every_option():
    text = pydoc.render_doc(Renderer.render, renderer=pydoc.plaintext)
    signature, doc = text.split("\n", 2)[2].split("\n", 1)  # (after the "Help on ..." header)
    for name, value in DEFAULT_SETTINGS.items():
        assert re.search(rf"\b{name}: '[\w |\[\]]+' = Default\({re.escape(repr(value))}\)", signature), name
        assert f"\n        {name}: " in doc, name  # explained on a line of its own under Args


def test_left_out_keywords_take_the_scene_settings(make_renderer):
    r = make_renderer(32, 24)
    scene = small_scene()
    scene.settings = {"shadows": "soft", "ao_radius": 0.5, "exposure": 2.0}
    cfg = r.render(scene).settings
    assert (cfg["shadows"], cfg["ao_radius"], cfg["exposure"]) == ("soft", 0.5, 2.0)
    assert cfg["ao_samples"] == DEFAULT_SETTINGS["ao_samples"]  # neither set it
    # A keyword given wins over the scene, even when it equals the renderer's default.
    cfg = r.render(scene, shadows="hard", ao_radius=None, exposure=1.0).settings
    assert (cfg["shadows"], cfg["ao_radius"], cfg["exposure"]) == ("hard", None, 1.0)
    cfg = r.submit(scene, exposure=1.0)
    assert (cfg["shadows"], cfg["exposure"]) == ("soft", 1.0)


@pytest.mark.parametrize("method", ["render", "submit"])
def test_unknown_keywords_are_a_clear_error(make_renderer, method):
    r = make_renderer(16, 16)
    with pytest.raises(ConfigError, match=r"^unknown render setting 'shadow_sampels' \(known: accumulate, ambient, "):
        getattr(r, method)(small_scene(), shadow_sampels=4)


def test_public_api_is_fully_annotated():
    """Every public method, property and constructor of the classes engine exports has annotated parameters and
    return type, and the annotations evaluate (no stale names in the string annotations)."""
    missing = []
    for name in engine.__all__:
        obj = getattr(engine, name)
        if inspect.isfunction(obj):  # a module-level function of the API
            sig = inspect.signature(obj, eval_str=True)
            missing += [f"{name}({p.name})" for p in sig.parameters.values() if p.annotation is inspect.Parameter.empty]
            if sig.return_annotation is inspect.Signature.empty:
                missing.append(f"{name}: return")
            continue
        if not isinstance(obj, type) or issubclass(obj, Exception):
            continue
        for attr, member in vars(obj).items():
            if attr.startswith("_") and attr != "__init__":
                continue
            fn = member.fget if isinstance(member, property) else getattr(member, "__func__", member)
            if not inspect.isfunction(fn):
                continue
            sig = inspect.signature(fn, eval_str=True)
            missing += [
                f"{name}.{attr}({p.name})"
                for p in list(sig.parameters.values())[1:]
                if p.annotation is inspect.Parameter.empty
            ]
            if attr != "__init__" and sig.return_annotation is inspect.Signature.empty:
                missing.append(f"{name}.{attr}: return")
    assert missing == []
    assert (REPO / "engine" / "py.typed").is_file()


@pytest.mark.slow
def test_mypy_checks_calls_against_the_api(tmp_path):
    """mypy reads the annotations: the examples pass, and a script with a wrong shadow mode, a misspelt Frame
    attribute and a wrong camera fails with exactly those errors."""
    pytest.importorskip("mypy", reason="mypy is a dev dependency: pip install -e .[dev]")
    bad = tmp_path / "bad.py"
    bad.write_text(
        "import engine\n"
        "scene = engine.Scene.load('x.toml')\n"
        "with engine.Renderer(64, 48) as r:\n"
        "    frame = r.render(scene, shadows='blurry')\n"
        "    frame.colour\n"
        "    r.render(scene, 'camera')\n"
    )
    env = dict(os.environ, MYPYPATH=str(REPO))
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "mypy",
            "--follow-imports=silent",
            "--cache-dir",
            str(tmp_path / "cache"),
            "--no-error-summary",
            str(REPO / "examples"),
            str(bad),
        ],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    lines = [line for line in res.stdout.splitlines() if ": error:" in line]
    assert [line.split(":")[1] for line in lines] == ["4", "5", "6"], res.stdout + res.stderr
    assert "blurry" in lines[0] and "colour" in lines[1] and "Camera" in lines[2]


def test_frame_repr_and_jupyter_png(make_renderer):
    frame = make_renderer(40, 30).render(small_scene(), ao=False)
    text = repr(frame)
    assert text.startswith("<Frame 40x30, aov: color, position, normal, albedo, depth, shadow")
    assert f"GPU {sum(frame.timings.values()):.2f} ms>" in text and len(text) < 200  # no arrays dumped
    shown = np.asarray(Image.open(io.BytesIO(frame._repr_png_())))
    assert np.array_equal(shown, frame.color)
    assert "view depth" in repr(make_renderer(16, 12).render(small_scene(), view="depth"))


def test_hits_repr_is_short():
    hits = engine.Hits(
        np.array([1.0, np.inf], np.float32),
        np.array([3, -1], np.int32),
        np.zeros(2, np.float32),
        np.zeros(2, np.float32),
    )
    assert repr(hits) == "<Hits 2 rays, 1 hit>" and list(hits.hit) == [True, False]
