"""Where the files a TOML scene names may be: inside the scene's folder, or inside folders the user allows.

A scene file may come from anyone; the paths in it (`file`, `texture`) must not reach the rest of the disk, and an
error must not tell what exists outside (docs/scenes.md, "Paths").
"""

from __future__ import annotations

import os

from engine.errors import ConfigError, shown


class Folders:
    """The folders a scene's `file` / `texture` paths must resolve into, symlinks followed: the scene file's own
    (`base_dir`) and the folders of `allow_paths` (each a folder path or a list of them; relative ones are relative
    to the current folder)."""

    def __init__(self, base_dir: str, allow_paths=None):
        self.base = os.path.abspath(base_dir)
        self.allowed = allowed_folders(allow_paths)
        self._roots = [os.path.realpath(self.base)] + [os.path.realpath(a) for a in self.allowed]

    def resolve(self, value: str) -> str | None:
        """The real path of `value` (relative to the scene's folder, or absolute), or None when it leads outside
        every folder, whether or not it exists. Without allowed folders, an absolute path or one that climbs out
        ('../x') is refused before the disk is looked at."""
        if not self.allowed:
            rel = os.path.normpath(value)
            if os.path.isabs(rel) or rel == os.pardir or rel.startswith(os.pardir + os.sep):
                return None
        real = os.path.realpath(os.path.join(self.base, value))
        return real if any(_inside(real, root) for root in self._roots) else None

    def refusal(self, key: str, value: str) -> str:
        """The message for a path that resolve() refused (the same for every such path)."""
        return (
            f"{key} = '{shown(value)}' is outside the scene's folder: a scene may name only files inside its "
            f"folder, unless a folder is allowed (--allow-path DIR, Scene.load(path, allow_paths=[DIR]))"
        )


def allowed_folders(allow_paths) -> list[str]:
    """`allow_paths` (None, a folder, or a list of folders) checked: absolute paths of existing folders."""
    if allow_paths is None:
        return []
    if isinstance(allow_paths, (str, bytes, os.PathLike)):
        allow_paths = [allow_paths]
    try:
        items = list(allow_paths)
    except TypeError:
        raise ConfigError(
            f"allow_paths must be a folder or a list of folders, got {type(allow_paths).__name__}"
        ) from None
    out = []
    for item in items:
        path = os.fspath(item) if isinstance(item, os.PathLike) else item
        if not isinstance(path, str):
            raise ConfigError(f"allow_paths: a folder must be a str path, got {type(item).__name__}")
        if not path or "\0" in path or not os.path.isdir(path):
            raise ConfigError(f"allow_paths: '{shown(path)}' is not a folder")
        out.append(os.path.abspath(path))
    return out


def _inside(path: str, root: str) -> bool:
    return path == root or path.startswith(root.rstrip(os.sep) + os.sep)
