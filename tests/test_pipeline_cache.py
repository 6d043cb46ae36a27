"""The on-disk pipeline cache (engine/vk/pipeline_cache.py): saved privately and atomically, loaded only when it is
ours and intact, and pipelines made on first use, once."""

import os
import stat

import numpy as np
import pytest

from engine.vk import pipeline_cache as pc


@pytest.fixture
def cache_home(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.delenv(pc.ENV, raising=False)
    return tmp_path / "hybrid" / "pipelines"


def test_written_private_whatever_the_umask(cache_home):
    old = os.umask(0)
    try:
        pc.write_private(cache_home / "k.bin", b"payload")
    finally:
        os.umask(old)
    assert stat.S_IMODE(cache_home.stat().st_mode) == 0o700
    assert stat.S_IMODE((cache_home / "k.bin").stat().st_mode) == 0o600
    assert pc.read_trusted(cache_home / "k.bin") == b"payload"
    assert not [p for p in cache_home.iterdir() if p.name.startswith(".pc-")]  # no temporary left behind


def test_damaged_shared_foreign_or_odd_files_are_ignored(cache_home):
    path = cache_home / "k.bin"
    pc.write_private(path, b"x" * 100)
    raw = bytearray(path.read_bytes())
    raw[-1] ^= 1  # one bit flipped in the payload
    path.write_bytes(bytes(raw))
    assert pc.read_trusted(path) == b""
    path.write_bytes(raw[: len(pc.MAGIC) + 10])  # truncated
    assert pc.read_trusted(path) == b""
    path.write_bytes(b"\x7fELF" + bytes(200))  # not ours at all
    assert pc.read_trusted(path) == b""

    pc.write_private(path, b"good")
    path.chmod(0o664)  # writable by the group: anyone there could have planted it
    assert pc.read_trusted(path) == b""
    path.chmod(0o600)
    if os.getuid() == 0:  # owned by another user
        os.chown(path, 12345, -1)
        assert pc.read_trusted(path) == b""
        os.chown(path, 0, -1)
    assert pc.read_trusted(path) == b"good"

    link = cache_home / "link.bin"
    link.symlink_to(path)  # a link is not followed
    assert pc.read_trusted(link) == b""
    fifo = cache_home / "fifo.bin"
    os.mkfifo(fifo)  # a FIFO neither blocks nor is read
    assert pc.read_trusted(fifo) == b""


def test_context_round_trips_its_cache(cache_home, monkeypatch):
    from engine.vk import Context

    monkeypatch.setattr(pc, "HEADER_BYTES", 0)  # save even a header-only cache (lavapipe keeps no entries)
    with Context() as ctx:
        path = ctx.pipeline_cache.path
        assert path is not None and path.parent == cache_home
    saved = pc.read_trusted(path)
    assert len(saved) >= 16  # the driver's header at least
    with Context() as ctx:
        assert ctx.pipeline_cache.loaded == saved  # handed to the driver, which took it
    path.write_bytes(b"garbage" * 10)  # a damaged file: the device still opens, with an empty cache
    with Context() as ctx:
        assert ctx.pipeline_cache.loaded == b""


def test_disabled_by_the_environment(cache_home, monkeypatch):
    from engine.vk import Context

    monkeypatch.setenv(pc.ENV, "0")
    with Context() as ctx:
        assert ctx.pipeline_cache.path is None
    assert not cache_home.exists()


def test_a_pass_compiles_once_and_renderers_on_a_device_share_it(make_renderer, monkeypatch):
    """Pipelines are made on first use: a pass re-specialized for the scene before its first frame is compiled
    once, not once per specialization; a second Renderer on the same engine.Device compiles nothing."""
    from collections import Counter

    from engine import Device, Scene, scene_path
    from engine.vk import pipelines
    from conftest import VALIDATE

    made = Counter()
    real = pipelines.ComputePipeline._create

    def counting(self, *source):
        made[self.name] += 1
        return real(self, *source)

    monkeypatch.setattr(pipelines.ComputePipeline, "_create", counting)
    scene = Scene.load(scene_path("sphere"))
    with Device(validation=VALIDATE) as dev:
        r = make_renderer(32, 24, device=dev)
        assert not made  # nothing compiled before there is work
        frame = r.render(scene)
        assert frame.color.shape == (24, 32, 4) and frame.color[..., 3].min() == 255
        assert {"shadows", "ao", "lighting"} <= set(made)
        assert max(made.values()) == 1, made  # each compiled once, with the constants it runs with
        before = sum(made.values())
        r.render(Scene.load(scene_path("sphere")))  # another scene of the same kind: nothing compiled again
        again = make_renderer(32, 24, device=dev).render(scene)  # another Renderer on the device: nothing either
        assert sum(made.values()) == before
        assert np.array_equal(again.color, frame.color)
        assert not dev.validation_errors
