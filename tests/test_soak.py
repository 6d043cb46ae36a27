"""A short soak in the suite: 2,000 frames with a moving camera and soft shadows, 1,000 Tracer queries; memory and
Vulkan allocations stay flat and the validation layer stays silent (benchmarks/soak.py runs the long version)."""

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import soak  # noqa: E402

pytestmark = pytest.mark.slow  # thousands of frames and queries: the slow tier (CONTRIBUTING.md, "Tests")


def test_two_thousand_frames_stay_flat():
    marks, errors = soak.soak_frames(2000, (32, 32), str(ROOT / "scenes" / "penumbra.toml"), 100, validation=True)
    assert errors == []
    warm = [m for m in marks if m[0] >= 200]
    assert len({m[2] for m in warm}) == 1, f"Vulkan allocations changed: {[m[2] for m in warm]}"
    growth = warm[-1][1] - warm[0][1]
    assert growth < 8.0, f"RSS grew {growth:.1f} MB over {warm[-1][0] - warm[0][0]} frames"


def test_a_thousand_tracer_queries_stay_flat():
    marks, errors = soak.soak_queries(1000, 50, validation=True)
    assert errors == []
    warm = [m for m in marks if m[0] >= 200]
    assert len({m[2] for m in warm}) == 1
    assert warm[-1][1] - warm[0][1] < 8.0
