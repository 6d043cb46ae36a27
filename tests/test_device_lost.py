"""A lost or hung device, for real: $HYBRID_FAULT_INJECTION puts a shader ahead of a submission (engine/vk/faults.py)
that writes to unmapped GPU memory (`device-lost`: GPUs only) or loops forever (`hang`: any device, lavapipe too).
The driver answers VK_ERROR_DEVICE_LOST or the GPU timeout fires; every call then says so in one line, close()
returns, and a new device in the same process renders the same image as before. Hangs run in a subprocess, so that
the endless shader (on lavapipe, a spinning thread) ends with it."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading

import numpy as np
import pytest
import trimesh

import engine
from engine import ConfigError, Device, Renderer, Scene, Tracer, VulkanError
from engine.vk import context, faults
from tests.conftest import REPO


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


def lose_and_recover(kind: str) -> dict:
    """Render, arm the fault, render: what each call then says, whether close() returned, and whether a new device
    renders the image of before. Run in a subprocess (`python -c`), which it leaves with os._exit (a hung device's
    work may still run: engine.vk.context.any_hung)."""
    scene = sphere_scene()
    mesh = trimesh.creation.icosphere(subdivisions=2)
    with Device() as dev, Renderer(64, 48, device=dev) as r:
        before = r.render(scene).color.copy()
    os.environ.update({faults.ENV: f"{kind}:1000000", "HYBRID_GPU_TIMEOUT": "3"})  # armed below, after set-up
    dev = Device()
    del os.environ[faults.ENV], os.environ["HYBRID_GPU_TIMEOUT"]
    r = Renderer(64, 48, device=dev)
    t = Tracer(mesh.vertices, mesh.faces, device=dev)
    r.render(scene)
    faults.arm(dev.context)
    said = {}
    calls = {
        "the frame": lambda: r.render(scene),
        "render": lambda: r.render(scene),
        "render_many": lambda: next(r.render_many(scene, [scene.camera])),
        "Tracer.occluded": lambda: t.occluded(np.zeros((4, 3)), np.ones((4, 3))),
        "new Renderer": lambda: Renderer(16, 16, device=dev),
    }
    for what, call in calls.items():
        try:
            call()
            said[what] = None
        except (VulkanError, ConfigError) as exc:
            said[what] = str(exc)
    closed = all(closes_within(obj) for obj in (t, r, dev))
    with Device() as dev, Renderer(64, 48, device=dev) as r:
        same = bool(np.array_equal(before, r.render(scene).color))
    print(json.dumps({"said": said, "closed": closed, "same": same}), flush=True)
    os._exit(0)


def in_subprocess(args: list, fault: str | None = None) -> subprocess.CompletedProcess:
    env = dict(os.environ, **{faults.ENV: fault, "HYBRID_GPU_TIMEOUT": "3"}) if fault else None
    return subprocess.run([sys.executable, *args], cwd=REPO, env=env, capture_output=True, text=True, timeout=180)


def render_cli(fault: str, out) -> list[str]:
    """`hybrid render` with the fault: its exit status must be 1; the lines it printed on stderr."""
    run = in_subprocess(["-m", "engine", "render", "default", "--size", "64x48", "-o", str(out)], fault)
    assert run.returncode == 1, run.stderr
    return run.stderr.strip().splitlines()


def check_recovery(kind: str, first: str):
    run = in_subprocess(["-c", f"from tests.test_device_lost import lose_and_recover; lose_and_recover({kind!r})"])
    assert run.returncode == 0, run.stderr[-2000:]
    out = json.loads(run.stdout.strip().splitlines()[-1])
    said = out["said"]
    assert said["the frame"] is not None and first in said["the frame"], said
    for what, message in said.items():
        assert message is not None and "lost" in message and "\n" not in message, (what, message)
    assert out["closed"], "close() did not return on the lost device"
    assert out["same"], "a new device renders another image"


def test_a_hung_device_is_a_clear_error_and_a_new_device_recovers():
    check_recovery("hang", "did not finish its work within 3 s (HYBRID_GPU_TIMEOUT)")


def test_the_cli_reports_a_hung_device_in_one_line_and_writes_nothing(tmp_path):
    assert render_cli("hang:3", tmp_path / "hung.png") == [
        "error: the GPU did not finish its work within 3 s (HYBRID_GPU_TIMEOUT): the device is treated as lost; "
        "close this object and create a new one"
    ]
    assert list(tmp_path.iterdir()) == []


def test_a_bad_setting_is_named(monkeypatch):
    monkeypatch.setenv(faults.ENV, "device-lost:0")
    with pytest.raises(ConfigError, match=r"HYBRID_FAULT_INJECTION='device-lost:0': expected"):
        Device()
    monkeypatch.setenv(faults.ENV, "crash")
    with pytest.raises(ConfigError, match="HYBRID_FAULT_INJECTION='crash': expected one of device-lost, hang"):
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


def test_every_call_after_a_device_loss_is_a_clear_error_and_a_new_device_recovers(on_gpu):
    check_recovery("device-lost", "lost")


def test_the_cli_reports_a_lost_device_in_one_line_and_writes_nothing(on_gpu, tmp_path):
    lines = render_cli("device-lost:3", tmp_path / "lost.png")
    assert len(lines) == 1 and ("device was lost" in lines[0] or "treated as lost" in lines[0]), lines
    assert list(tmp_path.iterdir()) == []


def test_a_device_that_does_not_finish_in_time_is_treated_as_lost(monkeypatch):
    """The GPU timeout, on any device: with a limit no frame can meet, the wait gives up with a one-line error, the
    device counts as lost, and close() returns (without waiting for the work, as for a hung GPU)."""
    monkeypatch.setattr(context, "_HUNG", threading.Event())  # (this process's own flag stays clear: any_hung)
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
