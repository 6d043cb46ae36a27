"""The cheap re-submit path (Renderer._prepare_steady, Context.submit's cached VkSubmitInfo) behaves exactly as the
full path: the same frame block bit for bit, the same command buffers, changes to the camera, lights and settings
picked up on the next frame, and invalid settings still rejected. No timings are asserted here."""

import numpy as np
import pytest
import trimesh

from engine import Camera, ConfigError, DirectionalLight, PointLight, Scene
from engine.settings import check_settings

CAM_A = Camera.look_at((2.5, 2.0, 3.0), (0, 0.3, 0))
CAM_B = Camera.look_at((-2.0, 2.5, 3.0), (0, 0.3, 0))


def scene_with_lights():
    box = trimesh.creation.box(extents=(0.6, 0.6, 0.6))
    box.apply_translation((0, 0.3, 0))
    ground = trimesh.creation.box(extents=(4, 0.05, 4))
    ground.apply_translation((0, -0.025, 0))
    lights = [DirectionalLight((-0.4, -1.0, -0.3), intensity=2.0), PointLight((1.0, 2.0, 1.0), intensity=6.0)]
    return Scene.from_trimesh(trimesh.util.concatenate([box, ground]), lights=lights, camera=CAM_A)


def ubo_bytes(r):
    return bytes(r.frame_block.buffer.view(np.uint8))


def test_steady_frames_write_what_the_full_path_writes(make_renderer, monkeypatch):
    """A renderer with the steady path and one without it, fed the same calls, hold the same frame block and
    submit the same recorded command buffers (by their position in the recording order) after every call."""
    fast, full = make_renderer(32, 24), make_renderer(32, 24)
    scene_fast, scene_full = scene_with_lights(), scene_with_lights()
    calls = [
        (None, {}),
        (None, {}),
        (None, {}),  # static: steady from the second frame on
        (CAM_B, {}),
        (CAM_B, {}),
        (CAM_B, {}),  # the camera moved, then static again
        (CAM_B, {"ao": False}),
        (CAM_B, {"ao": False}),  # another setting: another command buffer
        (CAM_A, {"ao": False, "shadows": "soft"}),
        (CAM_A, {"ao": False, "shadows": "soft"}),
        (None, {}),
        (None, {}),
        (CAM_B, {}),
        (CAM_A, {}),
        (CAM_B, {}),
        (CAM_B, {}),  # moving every frame, then still
        (CAM_A.replace(fov_y=40.0), {}),
        (CAM_A.replace(near=0.2), {}),
        (CAM_A.replace(near=0.2), {}),
    ]
    taken = []
    for name in ("_prepare_steady", "_prepare_moved"):
        method = getattr(fast, name)
        monkeypatch.setattr(fast, name, lambda *a, _m=method, _n=name: taken.append(_n) or _m(*a))
    for i, (cam, settings) in enumerate(calls):
        for r, scene in ((fast, scene_fast), (full, scene_full)):
            if r is full:
                r._steady = None  # every call of `full` takes the full path
            cfg = r.submit(scene, cam, wait=True, **settings)
            assert cfg == check_settings(dict(settings)), i
        assert ubo_bytes(fast) == ubo_bytes(full), f"call {i}: frame blocks differ"
        keys_fast, keys_full = list(fast._commands), list(full._commands)
        assert keys_fast == keys_full, i
    assert taken.count("_prepare_steady") == 8 and taken.count("_prepare_moved") == 7, taken
    assert not fast.validation_errors


def test_same_camera_same_pixels_other_camera_other_pixels(make_renderer):
    r = make_renderer(48, 32)
    scene = scene_with_lights()
    settings = dict(shadows="hard", ao=False)
    a = r.render(scene, CAM_A, **settings)
    b = r.render(scene, CAM_A, **settings)
    assert r._steady is not None and r.frame_block.settled  # b took the steady path
    assert np.array_equal(a.color, b.color)
    c = r.render(scene, CAM_B, **settings)
    assert not np.array_equal(b.color, c.color)
    d = r.render(scene, CAM_B, **settings)
    assert np.array_equal(c.color, d.color)


def test_submit_without_wait_then_render_matches(make_renderer):
    """The viewer's path (wait=False with a fence) renders the same image as render() does."""
    import vulkan as vk

    r = make_renderer(48, 32)
    scene = scene_with_lights()
    ref = r.render(scene, CAM_A, ao=False)
    fence = vk.vkCreateFence(r.ctx.device, vk.VkFenceCreateInfo(), None)
    try:
        for _ in range(3):
            r.submit(scene, CAM_A, wait=False, fence=fence, ao=False)
            vk.vkWaitForFences(r.ctx.device, 1, [fence], vk.VK_TRUE, 0xFFFFFFFFFFFFFFFF)
            vk.vkResetFences(r.ctx.device, 1, [fence])
    finally:
        r.ctx.wait_idle()
        vk.vkDestroyFence(r.ctx.device, fence, None)
    again = r.render(scene, CAM_A, ao=False)
    assert np.array_equal(ref.color, again.color)


def test_light_and_settings_changes_are_picked_up(make_renderer):
    r = make_renderer(48, 32)
    scene = scene_with_lights()
    base = r.render(scene, ao=False)
    r.render(scene, ao=False)
    scene.lights[1].intensity = 40.0  # an attribute assigned in place
    brighter = r.render(scene, ao=False)
    assert brighter.color[..., :3].astype(int).sum() > base.color[..., :3].astype(int).sum()
    scene.lights.pop()  # the list changed in place
    one = r.render(scene, ao=False)
    assert one.aov["shadow"].shape[2] == 1
    scene.settings["exposure"] = -2.0  # (EV) the scene's own settings dict, mutated
    darker = r.render(scene, ao=False)
    assert darker.color[..., :3].astype(int).sum() < one.color[..., :3].astype(int).sum()
    assert darker.settings["exposure"] == -2.0
    amb = [0.2, 0.2, 0.2]
    f1 = r.render(scene, ao=False, ambient=amb)
    r.render(scene, ao=False, ambient=amb)
    amb[:] = [1.0, 1.0, 1.0]  # the same list object, new values
    f2 = r.render(scene, ao=False, ambient=amb)
    assert f2.settings["ambient"] == (1.0, 1.0, 1.0) and f1.settings["ambient"] == (0.2, 0.2, 0.2)


def test_invalid_settings_still_rejected_after_steady_frames(make_renderer):
    r = make_renderer(32, 24)
    scene = scene_with_lights()
    r.render(scene, ao=True)
    r.render(scene, ao=True)
    with pytest.raises(ConfigError):
        r.render(scene, ao=1)  # equal to True, but not a bool
    with pytest.raises(ConfigError):
        r.render(scene, ao_samples=4.0)
    r.render(scene, ao=True)


def test_returned_settings_are_a_copy(make_renderer):
    r = make_renderer(32, 24)
    scene = scene_with_lights()
    r.render(scene, ao=False)
    cfg = r.submit(scene, ao=False)
    cfg["exposure"] = 99.0
    assert r.submit(scene, ao=False)["exposure"] == -1.0


def test_submit_info_cache(make_renderer):
    """One VkSubmitInfo per (command buffer, semaphores); freeing a command buffer drops its entries."""
    import vulkan as vk

    r = make_renderer(32, 24)
    ctx = r.ctx
    cmd = ctx.allocate_command_buffer()
    vk.vkBeginCommandBuffer(cmd, vk.VkCommandBufferBeginInfo())
    vk.vkEndCommandBuffer(cmd)
    sem = vk.vkCreateSemaphore(ctx.device, vk.VkSemaphoreCreateInfo(), None)
    try:
        ctx.submit(cmd)
        ctx.submit(cmd)
        plain = [k for k in ctx._submit_infos if k[0] == cmd]
        assert len(plain) == 1
        ctx.submit(cmd, signal_semaphores=[sem])
        ctx.submit(cmd, wait_semaphores=[sem], wait_stages=[vk.VK_PIPELINE_STAGE_ALL_COMMANDS_BIT])
        assert len([k for k in ctx._submit_infos if k[0] == cmd]) == 3
        with pytest.raises(ValueError):
            ctx.submit(cmd, wait_semaphores=[sem], wait_stages=[])
        ctx.free_command_buffer(cmd)
        assert not [k for k in ctx._submit_infos if k[0] == cmd]
    finally:
        ctx.wait_idle()
        vk.vkDestroySemaphore(ctx.device, sem, None)
    assert not r.validation_errors
