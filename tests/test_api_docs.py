"""The API reference builds from the docstrings without a warning (tools/build_api_docs.py: pdoc's warnings, and
backticked references and docs/ paths that do not resolve, are errors) into a folder a user opens at index.html, and
says what a user looks up there: every public name with its docstring."""

import html
import importlib.util
import inspect
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import engine

REPO = Path(__file__).resolve().parent.parent
TOOL = REPO / "tools" / "build_api_docs.py"

pytest.importorskip("pdoc", reason="pdoc is a dev dependency: pip install -e .[dev]")


def load_tool():
    spec = importlib.util.spec_from_file_location("build_api_docs", TOOL)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def text_of(page: str) -> str:
    """A page's text: tags dropped, entities decoded, runs of white space one space."""
    return re.sub(r"\s+", " ", html.unescape(re.sub(r"<[^>]+>", " ", page)))


def first_paragraph(obj) -> str:
    """The first paragraph of an object's docstring as the page shows it: backticks gone, spaces collapsed."""
    return re.sub(r"\s+", " ", inspect.getdoc(obj).split("\n\n")[0].replace("`", "")).strip()


def test_api_reference_builds_without_warnings(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(REPO))
    res = subprocess.run(
        [sys.executable, str(TOOL), "-o", "api"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300
    )
    assert res.returncode == 0 and res.stderr == "", res.stderr[-4000:]
    assert "api/index.html" in res.stdout  # where to open it, relative to the caller's folder
    # index.html, the page a user opens: every module's page, and every public name on the package's page
    index = (tmp_path / "api" / "index.html").read_text()
    assert f"hybrid {engine.__version__}: API reference" in index
    for module in ("engine", "engine/settings", "engine/limits", "engine/outputs", "engine/sequence"):
        assert f'href="{module}.html"' in index and (tmp_path / "api" / f"{module}.html").is_file(), module
    assert all(f'href="engine.html#{name}"' in index for name in engine.__all__ if name != "__version__")
    page = text_of((tmp_path / "api" / "engine.html").read_text())
    # every public name (engine/__init__.py's __all__) with its docstring, and the public methods of its classes
    squeezed = page.replace(" ", "")
    for name in engine.__all__:
        obj = getattr(engine, name)
        if name == "__version__":
            continue
        assert f"{'class' if inspect.isclass(obj) else 'def'} {name}" in page, name
        assert first_paragraph(obj).replace(" ", "") in squeezed, f"{name}: its docstring is not on the page"
        for attr, member in vars(obj).items() if inspect.isclass(obj) else ():
            if not attr.startswith("_") and inspect.isfunction(member) and member.__doc__:
                assert first_paragraph(member).replace(" ", "") in squeezed, f"{name}.{attr}"
    # the render options with their defaults and units, the conventions, the AOVs' shapes
    assert "shadow_samples:int=Default(1)" in page.replace(" ", "")  # (the signature is in spans per token)
    assert "ao_radius: the AO rays' length in world units" in page
    assert "linear view depth" in page and "(H, W, 4) uint8 RGBA, sRGB-encoded" in page
    assert "reverse-Z" in page and "barycentric" in page
    # numpy's array aliases by name, not expanded into the Union they stand for
    assert "origins:numpy.typing.ArrayLike" in page.replace(" ", "") and "_SupportsArray" not in page
    assert "DEFAULT_SETTINGS" in text_of((tmp_path / "api" / "engine" / "settings.html").read_text())


def test_the_check_reports_broken_references(tmp_path, monkeypatch):
    """A module with an annotation pdoc cannot evaluate, references to names that do not exist and a missing
    docs page: each is reported; the references that exist are not."""
    (tmp_path / "fake_api.py").write_text(
        '"""See `engine.settings.NO_SUCH`, `Frame.colour`, docs/nothing.md; `engine.settings.DEFAULT_SETTINGS`,\n'
        '`Frame.aov`, `Camera.forward` and docs/scenes.md exist."""\n'
        "from __future__ import annotations\n\n\n"
        "def f(x: NoSuchType) -> None:\n"
        '    """`Renderer.render` is fine, `Scene.nope()` is not."""\n'
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    tool = load_tool()
    monkeypatch.setattr(tool, "MODULES", ["fake_api"])
    problems = tool.build(None)
    assert len(problems) == 5, problems
    assert "Error parsing type annotation NoSuchType" in problems[0]
    assert problems[1:] == [
        "fake_api: `engine.settings.NO_SUCH` does not resolve",
        "fake_api: `Frame.colour` does not resolve",
        "fake_api: docs/nothing.md does not exist",
        "fake_api.f: `Scene.nope` does not resolve",
    ]
