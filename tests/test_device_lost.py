"""A lost device, for real: $HYBRID_FAULT_INJECTION puts a shader that writes to unmapped GPU memory ahead of a
submission (engine/vk/faults.py), the driver answers VK_ERROR_DEVICE_LOST, and every call then says so in one line,
closes without hanging, and a new device renders the same image as before. The loss itself needs a GPU (run through
the `device` tool: docs/architecture.md, "Device loss"); on a CPU device the suite checks the refusal."""

from __future__ import annotations

import os
import subprocess
import sys
import threading

import numpy as np
import pytest
import trimesh

import engine
from engine import ConfigError, Device, Renderer, Scene, Tracer, VulkanError
from engine.vk import faults
from tests.conftest import REPO, VALIDATE


def sphere_scene():
    return Scene.from_trimesh(
        trimesh.creation.icosphere(subdivisions=2), camera=engine.Camera.look_at((0, 0.5, 3), (0, 0, 0))
    )


def gpu_present() -> bool:
    with Device() as dev:
        return dev.context.device_info["type"] != "CPU"


def closes_within(obj, seconds=30.0) -> bool:
    th = threading.Thread(target=obj.close, daemon=True)
    th.start()
    th.join(seconds)
    return not th.is_alive()


def test_a_bad_setting_is_named(monkeypatch):
    monkeypatch.setenv(faults.ENV, "device-lost:0")
    with pytest.raises(ConfigError, match=r"HYBRID_FAULT_INJECTION='device-lost:0': expected"):
        Device()
    monkeypatch.setenv(faults.ENV, "hang")
    with pytest.raises(ConfigError, match="HYBRID_FAULT_INJECTION='hang'"):
        Device()


def test_a_cpu_device_is_refused_not_crashed(monkeypatch):
    """On lavapipe the shader would run in this process: the write to unmapped memory would be a SIGSEGV."""
    if gpu_present():
        pytest.skip("a GPU is present: the loss itself is tested below")
    monkeypatch.setenv(faults.ENV, "device-lost")
    with pytest.raises(ConfigError, match="is a CPU device, where the faulting shader would crash this process"):
        Device()


def test_arming_a_device_made_without_fault_injection_is_refused(shared_device):
    with pytest.raises(ConfigError, match="fault injection is not enabled on this device"):
        faults.arm(shared_device.context)


@pytest.fixture
def on_gpu():
    if not gpu_present():
        pytest.skip("device loss is injected on GPUs only (this device is a CPU; run it through the device tool)")


def test_every_call_after_a_device_loss_is_a_clear_error_and_a_new_device_recovers(on_gpu, monkeypatch):
    scene = sphere_scene()
    mesh = trimesh.creation.icosphere(subdivisions=2)
    with Device(validation=VALIDATE) as dev, Renderer(64, 48, device=dev) as r:
        before = r.render(scene).color.copy()

    # a driver reports the fault as VK_ERROR_DEVICE_LOST, or (the H100 here) the queue stalls: the GPU timeout
    monkeypatch.setenv(faults.ENV, "device-lost:1000000")  # enabled; armed below, after the set-up's uploads
    monkeypatch.setenv("HYBRID_GPU_TIMEOUT", "10")
    dev = Device(validation=VALIDATE)
    monkeypatch.delenv(faults.ENV)
    monkeypatch.delenv("HYBRID_GPU_TIMEOUT")
    r = Renderer(64, 48, device=dev)
    t = Tracer(mesh.vertices, mesh.faces, device=dev)
    r.render(scene)
    faults.arm(dev.context)
    with pytest.raises(VulkanError, match="device was lost|did not finish its work within 10 s") as lost:
        r.render(scene)
    assert "\n" not in str(lost.value)
    calls = {
        "render": lambda: r.render(scene),
        "render_many": lambda: next(r.render_many(scene, [scene.camera])),
        "Tracer.occluded": lambda: t.occluded(np.zeros((4, 3)), np.ones((4, 3))),
        "Tracer.intersect": lambda: t.intersect(np.zeros((4, 3)), np.ones((4, 3))),
        "new Renderer": lambda: Renderer(16, 16, device=dev),
    }
    for what, call in calls.items():
        with pytest.raises((VulkanError, ConfigError), match="lost") as info:
            call()
        assert "\n" not in str(info.value), what
    assert closes_within(t) and closes_within(r) and closes_within(dev), "close() hung on the lost device"

    with Device(validation=VALIDATE) as dev, Renderer(64, 48, device=dev) as r:
        after = r.render(scene).color
    assert np.array_equal(before, after), "the new device renders another image"


def test_the_cli_reports_a_lost_device_in_one_line_and_writes_nothing(on_gpu, tmp_path):
    out = tmp_path / "lost.png"
    env = dict(os.environ, **{faults.ENV: "device-lost:3", "HYBRID_GPU_TIMEOUT": "10"})
    run = subprocess.run(
        [sys.executable, "-m", "engine", "render", "default", "--size", "64x48", "-o", str(out)],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode != 0
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and ("device was lost" in lines[0] or "treated as lost" in lines[0]), run.stderr
    assert list(tmp_path.iterdir()) == []


def test_a_device_that_does_not_finish_in_time_is_treated_as_lost(monkeypatch):
    """The GPU timeout, on any device: with a limit no frame can meet, the wait gives up with a one-line error, the
    device counts as lost, and close() returns (without waiting for the work, as for a hung GPU)."""
    monkeypatch.setenv("HYBRID_GPU_TIMEOUT", "1e-9")
    dev = Device()  # (without validation: closing while the device may still run the frame is what is tested)
    monkeypatch.delenv("HYBRID_GPU_TIMEOUT")
    with pytest.raises(VulkanError, match=r"did not finish its work within 1e-09 s \(HYBRID_GPU_TIMEOUT\)"):
        Renderer(64, 48, device=dev).render(sphere_scene())  # (the set-up's uploads wait too)
    with pytest.raises(VulkanError, match="lost"):
        Tracer(np.eye(3), np.array([[0, 1, 2]]), device=dev)
    assert closes_within(dev)


@pytest.mark.parametrize("value", ["-1", "soon", "inf"])
def test_a_bad_gpu_timeout_is_named(monkeypatch, value):
    monkeypatch.setenv("HYBRID_GPU_TIMEOUT", value)
    with pytest.raises(ConfigError, match=f"HYBRID_GPU_TIMEOUT={value!r}: expected seconds >= 0"):
        Device()
