"""Shared fixtures: renderers with the validation layer on (any validation error fails the test that
caused it), image regression against committed references, and an Xvfb display for window tests."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parent.parent
REFERENCE_DIR = Path(__file__).resolve().parent / "reference"
#: not our tests: peers' test files kept as data (tests/data/open3d/), run by the tests that substitute our classes
collect_ignore = ["data"]


# HYBRID_VALIDATION=0 runs the tests without the validation layer (a GPU machine that lacks it); `hybrid test`
# sets it to 1
VALIDATE = os.environ.get("HYBRID_VALIDATION", "1") != "0"


@pytest.fixture(autouse=True, scope="session")
def _validation_as_configured():
    """With HYBRID_VALIDATION=0, objects a test makes with validation=True run without the layer too (the tests
    then check everything but the layer's messages). Session-wide, so that module-scoped fixtures get it too."""
    if VALIDATE:
        yield
        return
    from engine.vk import context

    real = context.Context.__init__

    def init(self, device=None, validation=None, *args, **kw):
        real(self, device, False, *args, **kw)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(context.Context, "__init__", init)
        yield


def pytest_addoption(parser):
    parser.addoption(
        "--regen-refs",
        action="store_true",
        help="rewrite the reference images in tests/reference/ instead of comparing",
    )


@pytest.fixture(scope="session")
def shared_device():
    """One validated engine.Device for the session's renderers (`make_renderer`): Renderers on one device share
    its compiled pipelines, so each shader and specialization compiles once per session, not once per test.
    Closed at the end, which reports any object a test leaked as a validation error."""
    from engine import Device

    dev = Device(validation=VALIDATE)
    yield dev
    dev.close()
    assert not dev.validation_errors, "Vulkan validation errors:\n" + "\n".join(dev.validation_errors[:10])


@pytest.fixture
def make_renderer(shared_device):
    """`make_renderer(w, h, **kw)`: a validated Renderer, closed after the test; validation errors fail it. On the
    session's shared device unless `kw` names a device, context or validation setting of its own."""
    from engine import Renderer

    made = []
    seen = len(shared_device.validation_errors)

    def make(width=64, height=48, **kw):
        if not {"device", "context", "validation"} & kw.keys():
            kw["device"] = shared_device
        kw.setdefault("validation", VALIDATE)
        r = Renderer(width, height, **kw)
        made.append(r)
        return r

    yield make
    errors = []
    for r in made:
        r.close()  # leaked Vulkan objects are reported here (on the shared device: when it closes), as errors
        if r.validation_errors is not shared_device.validation_errors:
            errors += r.validation_errors
    errors += shared_device.validation_errors[seen:]
    assert not errors, "Vulkan validation errors:\n" + "\n".join(errors[:10])


@pytest.fixture
def renderer(make_renderer):
    return make_renderer(64, 48)


@pytest.fixture
def image_regression(request):
    """`image_regression(name, rgba, max_mean=.., max_bad_fraction=..)` against tests/reference/NAME.png.

    The images are compared as a user would look at them: the mean absolute difference over all channels
    (0..255) and the fraction of pixels whose difference exceeds 32 levels in some channel."""
    from PIL import Image

    regen = request.config.getoption("--regen-refs")

    def check(name, rgba, max_mean=2.0, max_bad_fraction=0.01):
        path = REFERENCE_DIR / f"{name}.png"
        if regen or not path.exists():
            if not regen and os.environ.get("CI"):
                pytest.fail(f"reference image {path} is missing (run pytest --regen-refs and commit it)")
            REFERENCE_DIR.mkdir(parents=True, exist_ok=True)
            Image.fromarray(np.asarray(rgba, np.uint8), "RGBA").save(path)
            if regen:
                return
        ref = np.asarray(Image.open(path).convert("RGBA"), np.int16)
        got = np.asarray(rgba, np.int16)
        assert ref.shape == got.shape, f"{path}: reference is {ref.shape}, render is {got.shape}"
        diff = np.abs(ref - got)
        mean = float(diff.mean())
        bad = float((diff.max(axis=2) > 32).mean())
        if mean > max_mean or bad > max_bad_fraction:
            out = REPO / "out" / "test-failures"
            out.mkdir(parents=True, exist_ok=True)
            Image.fromarray(np.asarray(rgba, np.uint8), "RGBA").save(out / f"{name}.png")
            pytest.fail(
                f"{name}: differs from {path}: mean |diff| {mean:.2f} (max {max_mean}), "
                f"{bad:.2%} pixels off by > 32 (max {max_bad_fraction:.2%}); render saved to {out}"
            )

    return check


@pytest.fixture
def make_viewer(xvfb_display):
    """`make_viewer(scene, w, h, **kw)`: an in-process Viewer with validation on (no hot reload, quiet), closed after
    the test, which fails on any validation error (leaks included)."""
    from engine.viewer import Viewer  # GLFW is loaded by window tests only

    made = []

    def make(scene, width=160, height=90, **kw):
        kw.setdefault("validation", VALIDATE)
        kw.setdefault("hot_reload", False)
        kw.setdefault("quiet", True)
        kw.setdefault("render_scale", 1.0)  # a fixed size: dynamic resolution has its own tests
        v = Viewer(scene, width, height, **kw)
        made.append(v)
        return v

    yield make
    errors = []
    for v in made:
        v.close()  # leaked Vulkan objects are reported here
        errors += v.validation_errors
    assert not errors, "Vulkan validation errors:\n" + "\n".join(errors[:10])


@pytest.fixture(scope="session")
def xvfb_display():
    """A private Xvfb server for window tests: DISPLAY is set to it for the session (and for subprocesses).

    Xvfb picks a free display number itself (-displayfd) and reports it once it accepts connections.
    Skipped, with the reason, when Xvfb is not installed."""
    import select
    import shutil
    import subprocess
    import tempfile

    exe = shutil.which("Xvfb")
    if exe is None:
        pytest.skip("Xvfb is not installed (apt-get install xvfb): window tests need an X display")
    read_fd, write_fd = os.pipe()
    log = tempfile.TemporaryFile()
    proc = subprocess.Popen(
        [exe, "-displayfd", str(write_fd), "-screen", "0", "1280x800x24", "-nolisten", "tcp"],
        pass_fds=(write_fd,),
        stdout=subprocess.DEVNULL,
        stderr=log,
    )
    os.close(write_fd)
    number = b""
    try:
        while not number.endswith(b"\n"):
            ready, _, _ = select.select([read_fd], [], [], 15.0)
            chunk = os.read(read_fd, 16) if ready else b""
            if not chunk:
                proc.kill()
                proc.wait()
                log.seek(0)
                err = log.read().decode(errors="replace").strip().splitlines()
                pytest.fail(f"Xvfb did not start: {err[-1] if err else 'no display number reported'}")
            number += chunk
    finally:
        os.close(read_fd)
    display = f":{int(number)}"
    old = os.environ.get("DISPLAY")
    os.environ["DISPLAY"] = display
    try:
        yield display
    finally:
        if old is None:
            os.environ.pop("DISPLAY", None)
        else:
            os.environ["DISPLAY"] = old
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        log.close()
