"""Build hooks. The shaders and scenes live at the top of the checkout (shaders/glsl, shaders/spv, scenes/); a built
wheel carries a copy of them as package data in engine/_data/, which engine/data.py finds. The host steps in C
(engine/native.c) become the extension module engine._native through cffi (engine/_native_build.py), an optional
one: where it cannot be compiled (no C compiler) the package installs without it and engine/native.py runs numpy's
steps, saying so once. The rest of the metadata is in pyproject.toml."""

import shutil
import sys
from pathlib import Path

from setuptools import setup
from setuptools.command.build_ext import build_ext
from setuptools.command.build_py import build_py
from setuptools.errors import CCompilerError, ExecError, PlatformError

HERE = Path(__file__).resolve().parent


class BuildPyWithData(build_py):
    def run(self):
        super().run()
        if getattr(self, "editable_mode", False):  # an editable install reads the checkout's own folders
            return
        dst = Path(self.build_lib) / "engine" / "_data"
        if dst.exists():  # a stale copy from an earlier build
            shutil.rmtree(dst)
        skip = shutil.ignore_patterns("__pycache__", "*.pyc", ".*")
        for part in ("shaders/glsl", "shaders/spv", "scenes/assets"):
            shutil.copytree(HERE / part, dst / part, ignore=skip)
        for scene in sorted((HERE / "scenes").glob("*.toml")):
            shutil.copy2(scene, dst / "scenes" / scene.name)


class OptionalBuildExt(build_ext):
    """build_ext that leaves out an extension it cannot compile (no compiler, or a failing one), with a message."""

    def run(self):
        try:
            super().run()
        except (CCompilerError, ExecError, PlatformError, OSError) as e:  # (no compiler at all: found before any file)
            self._skip("engine._native", e)

    def build_extension(self, ext):
        try:
            super().build_extension(ext)
        except (CCompilerError, ExecError, PlatformError, OSError) as e:
            self._skip(ext.name, e)

    @staticmethod
    def _skip(name, e):
        print(
            f"warning: {name} not built ({e}); the package installs without it and runs numpy's steps instead "
            "(slower BVH builds): install a C compiler and reinstall to have it",
            file=sys.stderr,
        )


try:
    import cffi  # noqa: F401   (a build requirement; a build without isolation may lack it)

    native = {"cffi_modules": ["engine/_native_build.py:ffibuilder"]}
except ImportError:
    print("warning: cffi is not installed: engine._native not built (numpy's steps instead)", file=sys.stderr)
    native = {}

setup(cmdclass={"build_py": BuildPyWithData, "build_ext": OptionalBuildExt}, **native)
