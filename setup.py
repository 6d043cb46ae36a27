"""Build hook: the shaders and scenes live at the top of the checkout (shaders/glsl, shaders/spv, scenes/); a built
wheel carries a copy of them as package data in engine/_data/, which engine/data.py finds. The rest of the metadata
is in pyproject.toml."""
import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = Path(__file__).resolve().parent


class BuildPyWithData(build_py):
    def run(self):
        super().run()
        if getattr(self, "editable_mode", False):   # an editable install reads the checkout's own folders
            return
        dst = Path(self.build_lib) / "engine" / "_data"
        if dst.exists():   # a stale copy from an earlier build
            shutil.rmtree(dst)
        skip = shutil.ignore_patterns("__pycache__", "*.pyc", ".*")
        for part in ("shaders/glsl", "shaders/spv", "scenes/assets"):
            shutil.copytree(HERE / part, dst / part, ignore=skip)
        for scene in sorted((HERE / "scenes").glob("*.toml")):
            shutil.copy2(scene, dst / "scenes" / scene.name)


setup(cmdclass={"build_py": BuildPyWithData})
