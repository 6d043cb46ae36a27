"""Image regression against committed references in tests/reference/ (regenerate: pytest --regen-refs).

References are lavapipe renders; on another device the comparison is skipped (rasterization and float
rounding differ between drivers)."""

import pytest

from engine import Scene
from conftest import REPO


@pytest.fixture(scope="module")
def default_scene():
    return Scene.load(REPO / "scenes" / "default.toml")


def on_lavapipe(r):
    if "llvmpipe" not in r.device_name:
        pytest.skip(f"reference images are lavapipe renders; this device is {r.device_name}")


def test_default_scene_plain_lighting(make_renderer, image_regression, default_scene):
    r = make_renderer(192, 108)
    on_lavapipe(r)
    f = r.render(default_scene, shadows="off", ao=False)
    image_regression("default_plain", f.color)


def test_default_scene_shadows_and_ao(make_renderer, image_regression, default_scene):
    r = make_renderer(192, 108)
    on_lavapipe(r)
    f = r.render(default_scene, shadows="hard", ao=True, ao_samples=4)
    image_regression("default_shadows_ao", f.color)


def test_default_scene_normals_view(make_renderer, image_regression, default_scene):
    r = make_renderer(192, 108)
    on_lavapipe(r)
    f = r.render(default_scene, shadows="off", ao=False, view="normal")
    image_regression("default_normals", f.color)
