"""The rules of pyproject.toml's [tool.ruff]: `ruff check` (pyflakes, pycodestyle, bugbear, and the size of each
function: complexity, branches, statements) and `ruff format` (CONTRIBUTING.md, "Rules")."""

import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("ruff", reason="ruff is a dev dependency: pip install -e .[dev]")

ROOT = Path(__file__).resolve().parents[1]
PATHS = ["engine", "tests", "tools", "benchmarks", "examples", "setup.py"]


def ruff(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "ruff", *args, *PATHS], cwd=ROOT, capture_output=True, text=True, timeout=300
    )


def test_ruff_lint():
    res = ruff("check", "--no-cache", "--output-format", "concise")
    assert res.returncode == 0, f'ruff check (fix, or see CONTRIBUTING.md, "Rules"):\n{res.stdout}{res.stderr}'


def test_ruff_format():
    res = ruff("format", "--no-cache", "--check")
    assert res.returncode == 0, (
        f"ruff format would change these (run .venv/bin/ruff format):\n{res.stdout[-4000:]}{res.stderr}"
    )
