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
except ModuleNotFoundError:  # Python 3.10 (tomli is in the dev extra)
    import tomli as tomllib

REPO = Path(__file__).resolve().parent.parent
PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())
IMPORT_NAME = {"pillow": "PIL", "openexr": "OpenEXR"}  # distribution name -> the module it is imported as


def test_version_has_one_source():
    project = PYPROJECT["project"]
    assert "version" not in project and "version" in project["dynamic"]
    assert PYPROJECT["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "engine._version.__version__"}
    assert re.fullmatch(r"\d+\.\d+\.\d+", engine.__version__)
    res = subprocess.run(
        [sys.executable, "-m", "engine", "--version"], capture_output=True, text=True, cwd=REPO, timeout=120
    )
    assert res.returncode == 0 and res.stdout.strip() == f"hybrid {engine.__version__}"


def test_licence_in_the_repo_and_the_metadata():
    text = (REPO / "LICENSE").read_text()
    assert text.startswith("MIT License") and 'THE SOFTWARE IS PROVIDED "AS IS"' in text
    assert PYPROJECT["project"]["license"] == "MIT" and PYPROJECT["project"]["license-files"] == ["LICENSE"]


#: The kinds of change of a Keep a Changelog entry (https://keepachangelog.com/en/1.1.0/).
CHANGE_TYPES = {"Added", "Changed", "Deprecated", "Removed", "Fixed", "Security"}


def test_changelog_has_the_version():
    """CHANGELOG.md is in the Keep a Changelog form and its newest version is this one, so that a user who runs
    `hybrid --version` finds at the top what that version brings: `## [Unreleased]` (optional, first), then
    `## [X.Y.Z] - YYYY-MM-DD` entries, newest first (only the newest may say "Unreleased" for its date), each with
    changes listed under Added / Changed / Deprecated / Removed / Fixed / Security."""
    text = (REPO / "CHANGELOG.md").read_text()
    entries = re.split(r"^(?=## )", text, flags=re.M)[1:]
    heads = [re.fullmatch(r"## \[([^\]]+)\](?: - (\S+))?", e.splitlines()[0]) for e in entries]
    assert heads and all(heads), [e.splitlines()[0] for e, h in zip(entries, heads) if not h]
    if heads[0].group(1) == "Unreleased":
        entries, heads = entries[1:], heads[1:]
    versions = [h.group(1) for h in heads]
    assert all(re.fullmatch(r"\d+\.\d+\.\d+", v) for v in versions), versions
    assert versions and versions[0] == engine.__version__, f"the newest entry is {versions[:1]}, not this version"
    assert versions == sorted(versions, key=lambda v: tuple(map(int, v.split("."))), reverse=True)
    for i, (entry, head) in enumerate(zip(entries, heads)):
        assert re.fullmatch(r"\d{4}-\d\d-\d\d", head.group(2) or "") or (i == 0 and head.group(2) == "Unreleased"), (
            head.group(0)
        )
        kinds = re.findall(r"^### (.+)$", entry, re.M)
        assert kinds and set(kinds) <= CHANGE_TYPES, (head.group(0), kinds)
        assert re.search(r"^- \S", entry, re.M), f"{head.group(0)}: no change listed"


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
    minors = sorted(
        int(c.rsplit(".", 1)[1])
        for c in PYPROJECT["project"]["classifiers"]
        if re.fullmatch(r"Programming Language :: Python :: 3\.\d+", c)
    )
    assert minors[0] == int(low)
    tomli = [d for d in PYPROJECT["project"]["dependencies"] if d.startswith("tomli")]
    assert int(low) >= 11 or tomli == ["tomli>=1.1; python_version<'3.11'"]  # tomllib is 3.11+


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
    res = subprocess.run(
        [sys.executable, "-c", TOMLI_SCENE, str(bad)],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        timeout=120,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    counts, error = res.stdout.strip().splitlines()
    ref = engine.Scene.load(REPO / "scenes" / "sphere.toml")
    assert counts == f"{ref.triangle_count} {len(ref.lights)}"
    assert error.startswith(f"{bad}: TOML syntax error") and "line 1" in error
