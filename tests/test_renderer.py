"""Renderer behaviour a user relies on: uploads once, settings and size errors, devices, timings."""

import os
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from engine import Camera, ConfigError, Renderer, Scene, VulkanError
from engine.vk import choose_device


def small_scene():
    return Scene.from_trimesh(trimesh.creation.box(extents=(1, 1, 1)), camera=Camera.look_at((2, 2, 3), (0, 0, 0)))


def test_same_scene_uploads_once_and_frames_repeat(make_renderer):
    r = make_renderer(48, 32)
    scene = small_scene()
    a = r.render(scene, shadows="off", ao=False)
    b = r.render(scene, shadows="off", ao=False)
    assert r.uploads == 1
    assert np.array_equal(a.color, b.color)
    other = small_scene()
    r.render(other, shadows="off", ao=False)
    assert r.uploads == 2


def test_frame_fields_and_timings(make_renderer):
    f = make_renderer(40, 30).render(small_scene())
    assert f.color.shape == (30, 40, 4) and f.color.dtype == np.uint8
    for name, shape in [
        ("position", (30, 40, 3)),
        ("normal", (30, 40, 3)),
        ("albedo", (30, 40, 3)),
        ("depth", (30, 40)),
        ("ao", (30, 40)),
    ]:
        assert f.aov[name].shape == shape and f.aov[name].dtype == np.float32, name
    assert f.aov["shadow"].shape[:2] == (30, 40)
    assert {"gbuffer", "lighting"} <= set(f.timings)
    assert all(v >= 0 for v in f.timings.values())


def test_save_png(make_renderer, tmp_path):
    from PIL import Image

    f = make_renderer(40, 30).render(small_scene())
    f.save(tmp_path / "x.png")
    f.save(tmp_path / "d.png", aov="depth")
    assert Image.open(tmp_path / "x.png").size == (40, 30)
    assert Image.open(tmp_path / "d.png").size == (40, 30)


@pytest.mark.parametrize(
    "kw, word",
    [
        (dict(shadows="sometimes"), "shadows"),
        (dict(ao="yes"), "ao"),
        (dict(ao_samples=0), "ao_samples"),
        (dict(ao_radius=-1.0), "ao_radius"),
        (dict(exposure=float("nan")), "exposure"),
        (dict(shadow_sampels=4), "shadow_sampels"),
        (dict(exposure=1e300), "exposure"),
        (dict(ambient=[[1, 2], [3]]), "ambient"),
        (dict(ambient={"r": 1}), "ambient"),
        (dict(ambient=["a", "b", "c"]), "ambient"),
    ],
)
def test_bad_settings_name_the_field(make_renderer, kw, word):
    r = make_renderer(16, 16)
    with pytest.raises(ConfigError, match=word):
        r.render(small_scene(), **kw)


def test_settings_accept_numpy_numbers_and_name_the_scene_for_its_own(make_renderer):
    r = make_renderer(16, 16)
    assert r.render(small_scene(), exposure=np.float32(2), ao_samples=np.int64(2)).settings["exposure"] == 2.0
    scene = small_scene()
    scene.settings = {"shadows": "blurry"}
    with pytest.raises(ConfigError, match=r"\[settings\]: setting shadows='blurry'") as err:
        r.render(scene)
    assert str(err.value).startswith(scene.name)
    assert r.render(scene, shadows="hard").settings["shadows"] == "hard"  # a keyword wins over the scene's


def test_render_arguments_are_checked(make_renderer, tmp_path):
    r = make_renderer(16, 16)
    with pytest.raises(ConfigError, match="scene must be an engine.Scene"):
        r.render(None)
    with pytest.raises(ConfigError, match="camera must be an engine.Camera"):
        r.render(small_scene(), "cam")
    f = r.render(small_scene())
    (tmp_path / "d.png").mkdir()
    for path, word in (
        (tmp_path / "x.gif", "ending in .png"),
        (tmp_path / "no" / "x.png", "no folder"),
        (tmp_path / "d.png", "is a folder, not an image"),
    ):
        with pytest.raises(ConfigError, match=word):
            f.save(path)


@pytest.mark.parametrize("size", [(0, 10), (10, -5), (1.5, 10), (100000, 10)])
def test_bad_size(size):
    with pytest.raises(ConfigError, match="size"):
        Renderer(*size)


def test_device_selection():
    devs = [{"index": 0, "name": "llvmpipe", "rank": 3}, {"index": 1, "name": "NVIDIA H100", "rank": 0}]
    assert choose_device(devs) == 1  # discrete before CPU
    assert choose_device(devs, "llvm") == 0  # name substring
    assert choose_device(devs, 0) == 0  # index
    with pytest.raises(ConfigError, match="device='radeon'"):
        choose_device(devs, "radeon")
    with pytest.raises(ConfigError, match="no such device index"):
        choose_device(devs, 7)
    with pytest.raises(VulkanError, match="no Vulkan device"):
        choose_device([])


def test_bad_device_argument():
    with pytest.raises(ConfigError, match="no device name contains"):
        Renderer(8, 8, device="no-such-gpu")


def test_no_vulkan_driver_is_a_clear_error(tmp_path):
    env = dict(os.environ, VK_DRIVER_FILES=str(tmp_path / "none.json"), VK_ICD_FILENAMES=str(tmp_path / "none.json"))
    res = subprocess.run([sys.executable, "-m", "engine", "info"], capture_output=True, text=True, env=env, timeout=60)
    assert res.returncode == 1
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Vulkan" in lines[0], res.stderr


def test_ray_passes_are_specialized_to_the_scenes_bvh(make_renderer):
    """The shadow and AO pipelines take the scene's BVH depth and node layout (SceneBVH.spec) when the scene
    changes, and a frame of a deeper scene afterwards matches another renderer's with the same history."""
    from engine.gpu.bvh import CPU_STACK_REGS
    from engine.vk.device import is_cpu, work_shares

    r = make_renderer(48, 32)
    r.render(small_scene())
    depth = r.bvh_stats["depth"]
    for p in (r.shadows, r.ao):
        spec = p.values
        # a single-level BVH's spec plus its walk said to be single-level (BVH_INSTANCED false); no alpha-tested
        # materials, no textures
        assert spec == {
            "BVH_INSTANCED": False,
            **r._scene_bvh.spec(r.ctx, postpone=p.postpone_leaves),
            "WORK_SHARES": work_shares(r.ctx),
            "ALPHA_TEST": False,
            "TEXTURE_ARRAYS": 1,
        }
        if is_cpu(r.ctx):
            regs = spec["BVH_STACK_REGS"]
            assert regs == min(CPU_STACK_REGS, max(1, depth - 1)) and spec["BVH_COMPRESSED"]
            assert spec["BVH_STACK_RETRY"] == (depth - 1 > regs)
            assert spec["BVH_IMAGE_FETCH"]  # image loads (the BVH's storage texel buffer views) on CPU devices
        else:
            assert not spec["BVH_IMAGE_FETCH"]
    rng = np.random.default_rng(2)
    soup = trimesh.Trimesh(rng.uniform(-1, 1, (6000, 3)), np.arange(6000).reshape(2000, 3), process=False)
    deep = Scene.from_trimesh(soup, camera=Camera.look_at((2, 2, 3), (0, 0, 0)))
    a = r.render(deep)
    assert r.shadows.values == {
        "BVH_INSTANCED": False,
        **r._scene_bvh.spec(r.ctx, postpone=r.shadows.postpone_leaves),
        "WORK_SHARES": work_shares(r.ctx),
        "ALPHA_TEST": False,
        "TEXTURE_ARRAYS": 1,
    }
    fresh = make_renderer(48, 32)
    fresh.render(small_scene())  # the same frame history (AO samples follow the frame count)
    b = fresh.render(deep)
    assert np.array_equal(a.aov["shadow"], b.aov["shadow"]) and np.array_equal(a.aov["ao"], b.aov["ao"])


def test_odd_sizes_render_and_read_back_cleanly(make_renderer):
    """An odd pixel count (37 x 23): the readback's parts stay aligned to their texel sizes (no validation error,
    which the fixture turns into a failure) and every AOV comes back whole; a resize to another odd size too."""
    r = make_renderer(37, 23)
    f = r.render(small_scene())
    assert f.color.shape == (23, 37, 4) and f.aov["shadow"].shape[:2] == (23, 37)
    assert np.isfinite(f.aov["depth"]).mean() > 0.02 and (f.color[..., :3] > 0).any()
    assert r.ctx.validation_errors == []
    r.resize(41, 19)
    g = r.render(small_scene())
    assert g.color.shape == (19, 41, 4) and np.isfinite(g.aov["depth"]).mean() > 0.02
    assert r.ctx.validation_errors == []


def test_work_shares_do_not_change_the_frame(make_renderer, monkeypatch):
    """The shadow, AO and denoise passes shade their 8x8 tiles in the order of shares.glsl (WORK_SHARES, the worker
    threads of a CPU device): any share count gives the same masks, bit for bit, with a partial last row of
    tiles."""
    from pathlib import Path

    from engine.vk import device

    scene = Scene.load(Path(__file__).resolve().parents[1] / "scenes" / "default.toml")
    settings = dict(shadows="hard", ao=True, ao_samples=2)
    frames = []
    for shares in (1, 2, 3, 7):
        monkeypatch.setattr(device, "work_shares", lambda ctx, n=shares: n)
        r = make_renderer(76, 44)
        assert r.shadows.values["WORK_SHARES"] == shares and r.ao.values["WORK_SHARES"] == shares
        assert r.denoise.values["WORK_SHARES"] == shares
        frames.append(r.render(scene, **settings))
    for f in frames[1:]:
        assert np.array_equal(f.aov["shadow"], frames[0].aov["shadow"])
        assert np.array_equal(f.aov["ao"], frames[0].aov["ao"])
    assert (frames[0].aov["shadow"] == 0).mean() > 0.01 and (frames[0].aov["ao"] < 0.99).mean() > 0.01


def test_a_failed_specialization_keeps_the_old_pipeline_and_its_spec(make_renderer, monkeypatch):
    """If re-creating a ray pass's pipeline fails, the pass keeps the old pipeline and the spec that describes it,
    so the next scene upload tries again instead of tracing with constants that do not match the buffers."""
    from engine.errors import ShaderError

    r = make_renderer(32, 24)
    r.render(small_scene())
    before, handle, values = dict(r.shadows.pipeline.spec), r.shadows.pipeline.handle, dict(r.shadows.values)

    def fail(*a, **k):
        raise ShaderError("shadow.comp: pipeline creation failed (test)")

    monkeypatch.setattr(r.shadows.pipeline, "rebuild", fail)
    with pytest.raises(ShaderError, match="test"):
        r.shadows.specialize(BVH_STACK_REGS=values["BVH_STACK_REGS"] + 1)
    assert r.shadows.pipeline.spec == before and r.shadows.pipeline.handle == handle
    assert r.shadows.values == values


def test_closed_or_foreign_context_is_a_clear_error():
    from engine.vk import Context

    ctx = Context()
    ctx.close()
    with pytest.raises(ConfigError, match="Renderer: the Vulkan context is closed"):
        Renderer(8, 8, context=ctx)
    with pytest.raises(ConfigError, match="context must be an engine.vk.Context"):
        Renderer(8, 8, context="gpu")


def test_shared_context_closed_under_a_renderer_is_a_clear_error():
    """Its owner closes a shared context first: render() says so and close() is harmless (it used to abort the
    process inside the Vulkan loader)."""
    from engine.vk import Context

    ctx = Context()
    r = Renderer(16, 16, context=ctx)
    assert r.render(small_scene()).color.shape == (16, 16, 4)
    ctx.close()
    with pytest.raises(ConfigError, match="Renderer.render\\(\\): the Vulkan context is closed"):
        r.render(small_scene())
    r.close()


def test_validation_environment_flag_is_checked(monkeypatch):
    monkeypatch.setenv("HYBRID_VALIDATION", "maybe")
    with pytest.raises(ConfigError, match="HYBRID_VALIDATION='maybe'"):
        Renderer(8, 8)
