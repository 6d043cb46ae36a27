"""Where the bundled data lives: the shaders (GLSL sources, committed SPIR-V and its manifest) and the scenes.

An installed package carries them as package data in `engine/_data/` (setup.py copies the checkout's top-level
`shaders/` and `scenes/` there when a wheel is built), found through importlib.resources. A source checkout (run with
PYTHONPATH or installed editable) has no `engine/_data/` and uses the checkout's own folders, where
tools/compile_shaders.py writes.

A bundled scene is named by its file's stem (`default`, `sphere`, `penumbra`): `scene_path("default")`, and
`Scene.load("default")`, `hybrid render default` through it.
"""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path

from .errors import SceneError

CHECKOUT = Path(__file__).resolve().parent.parent  # the folder holding the package: a checkout's root


def _package_data() -> Path | None:
    """engine/_data as a folder, when the package carries it (an installed wheel)."""
    root = resources.files(__package__).joinpath("_data")
    # A package imported from a zip has no folders to hand glslangValidator or the mesh loader: not supported.
    return root if isinstance(root, Path) and root.is_dir() else None


DATA_ROOT = _package_data() or CHECKOUT
SHADERS_DIR = DATA_ROOT / "shaders"  # glsl/ (include/ inside), spv/ (+ manifest.json)
SCENES_DIR = DATA_ROOT / "scenes"  # *.toml, assets/


def bundled_scenes() -> list[str]:
    """The names of the bundled scenes, sorted: the stems of the scene folder's TOML files."""
    try:
        return sorted(p.stem for p in SCENES_DIR.glob("*.toml"))
    except OSError:
        return []


def scene_path(name: str | os.PathLike) -> Path:
    """The path of a bundled scene by name, or `name` itself as a path.

    The rule: a path that exists is itself; otherwise a name with no folder separator and no suffix is a bundled
    scene (`default`, `sphere`, `penumbra`; `bundled_scenes()`), and a SceneError lists the bundled names when there
    is none of that name; anything else is returned unchanged for the loader to open (and name when missing)."""
    text = os.fspath(name)
    if isinstance(text, bytes):
        text = os.fsdecode(text)
    if not text:
        raise SceneError("the scene path is empty")
    if os.path.exists(text) or os.sep in text or (os.altsep and os.altsep in text) or Path(text).suffix:
        return Path(text)
    if text in bundled_scenes():
        return SCENES_DIR / f"{text}.toml"
    known = ", ".join(bundled_scenes()) or f"none: {SCENES_DIR} is missing"
    raise SceneError(f"{text}: no such file, and no bundled scene of that name (bundled: {known})")
