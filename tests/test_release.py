"""Release hygiene: the metadata says what is true. One version, a licence, dependencies that are used, a changelog
entry for the version, and Python 3.10 (no tomllib) loading TOML scenes through tomli."""
import ast
import os
import re
import subprocess
import sys
from pathlib import Path

import engine

try:
    import tomllib
except ModuleNotFoundError:   # Python 3.10 (tomli is in the dev extra)
    import tomli as tomllib

REPO = Path(__file__).resolve().parent.parent
PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())
IMPORT_NAME = {"pillow": "PIL", "openexr": "OpenEXR"}   # distribution name -> the module it is imported as


def test_version_has_one_source():
    project = PYPROJECT["project"]
    assert "version" not in project and "version" in project["dynamic"]
    assert PYPROJECT["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "engine._version.__version__"}
    assert re.fullmatch(r"\d+\.\d+\.\d+", engine.__version__)
    res = subprocess.run([sys.executable, "-m", "engine", "--version"], capture_output=True, text=True, cwd=REPO,
                         timeout=120)
    assert res.returncode == 0 and res.stdout.strip() == f"hybrid {engine.__version__}"


def test_licence_in_the_repo_and_the_metadata():
    text = (REPO / "LICENSE").read_text()
    assert text.startswith("MIT License") and "THE SOFTWARE IS PROVIDED \"AS IS\"" in text
    assert PYPROJECT["project"]["license"] == "MIT" and PYPROJECT["project"]["license-files"] == ["LICENSE"]


def test_changelog_has_the_version():
    text = (REPO / "CHANGELOG.md").read_text()
    assert re.search(rf"^## \[?{re.escape(engine.__version__)}\]?", text, re.M), "no entry for this version"


def engine_imports() -> set[str]:
    """Top-level names of every module imported anywhere under engine/ (at module level or deferred)."""
    names = set()
    for path in (REPO / "engine").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names.update(a.name.split(".")[0] for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module.split(".")[0])
    return names


def test_every_dependency_is_imported():
    used = engine_imports()
    for req in PYPROJECT["project"]["dependencies"]:
        name = re.match(r"[A-Za-z0-9_.-]+", req).group(0).lower()
        assert IMPORT_NAME.get(name, name) in used, f"{req}: a dependency nothing in engine/ imports"


def test_requires_python_matches_the_classifiers():
    low = re.fullmatch(r">=3\.(\d+)", PYPROJECT["project"]["requires-python"]).group(1)
    minors = sorted(int(c.rsplit(".", 1)[1]) for c in PYPROJECT["project"]["classifiers"]
                    if re.fullmatch(r"Programming Language :: Python :: 3\.\d+", c))
    assert minors[0] == int(low)
    tomli = [d for d in PYPROJECT["project"]["dependencies"] if d.startswith("tomli")]
    assert int(low) >= 11 or tomli == ["tomli>=1.1; python_version<'3.11'"]   # tomllib is 3.11+


TOMLI_SCENE = """
import sys
sys.modules["tomllib"] = None   # as on Python 3.10, which has no tomllib
import engine
from engine.scene import toml_format
assert toml_format.tomllib.__name__ == "tomli", toml_format.tomllib
scene = engine.Scene.load("sphere")
print(scene.triangle_count, len(scene.lights))
try:
    engine.Scene.load(sys.argv[1])
except engine.SceneError as exc:
    print(exc)
"""


def test_toml_scenes_load_through_tomli_without_tomllib(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[camera\neye = [0, 0, 5]\n")
    env = dict(os.environ, PYTHONPATH=str(REPO))
    res = subprocess.run([sys.executable, "-c", TOMLI_SCENE, str(bad)], capture_output=True, text=True, env=env,
                         cwd=tmp_path, timeout=120)
    assert res.returncode == 0, res.stderr[-3000:]
    counts, error = res.stdout.strip().splitlines()
    ref = engine.Scene.load(REPO / "scenes" / "sphere.toml")
    assert counts == f"{ref.triangle_count} {len(ref.lights)}"
    assert error.startswith(f"{bad}: TOML syntax error") and "line 1" in error
