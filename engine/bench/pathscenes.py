"""Scenes for the path tracer's benchmark and its validation against Mitsuba 3 (tools/mitsuba_path.py): a Cornell
box lit by an emissive quad under its ceiling, with a diffuse, a rough-metal and a smooth-metal sphere; and an
interior lit by bounced light for the real-time GI (tests/test_gi.py, tools/make_hybrid_quality.py). Each object
is a (positions, faces, normals, uvs) primitive placed in world space with its glTF material."""

from __future__ import annotations

import numpy as np

from ..scene import Camera, DirectionalLight, Material, Scene
from ..scene import primitives


def quad(corners) -> tuple:
    """A quad of 4 corners (counter-clockwise seen from its front): positions, faces, normals, uvs."""
    p = np.asarray(corners, np.float64)
    n = np.cross(p[1] - p[0], p[2] - p[0])
    n = np.tile(n / np.linalg.norm(n), (4, 1))
    uv = np.array([[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]])
    return p, np.array([[0, 1, 2], [0, 2, 3]]), n, uv


def moved(prim, offset) -> tuple:
    p, f, n, uv = prim
    return p + np.asarray(offset, np.float64), f, n, uv


def cornell_objects(light_radiance: float = 12.0, spheres: bool = True) -> list:
    """[(primitive, material)]: the box (2 units wide, floor at y = 0, open towards +z), its 0.5 x 0.5 ceiling
    light and three spheres."""
    white, red, green = (0.73, 0.73, 0.73), (0.63, 0.065, 0.05), (0.14, 0.45, 0.091)
    objs = [
        (quad([(-1, 0, 1), (1, 0, 1), (1, 0, -1), (-1, 0, -1)]), Material("floor", white)),
        (quad([(-1, 2, -1), (1, 2, -1), (1, 2, 1), (-1, 2, 1)]), Material("ceiling", white)),
        (quad([(-1, 0, -1), (1, 0, -1), (1, 2, -1), (-1, 2, -1)]), Material("back", white)),
        (quad([(-1, 0, 1), (-1, 0, -1), (-1, 2, -1), (-1, 2, 1)]), Material("left", red)),
        (quad([(1, 0, -1), (1, 0, 1), (1, 2, 1), (1, 2, -1)]), Material("right", green)),
        (
            quad([(-0.25, 1.98, -0.25), (0.25, 1.98, -0.25), (0.25, 1.98, 0.25), (-0.25, 1.98, 0.25)]),
            Material("light", (0.0, 0.0, 0.0), emissive=(light_radiance,) * 3),
        ),
    ]
    if spheres:
        objs += [
            (moved(primitives.sphere(0.35, 64, 32), (-0.5, 0.35, -0.3)), Material("clay", (0.8, 0.5, 0.3))),
            (
                moved(primitives.sphere(0.3, 64, 32), (0.5, 0.3, 0.2)),
                Material("rough metal", (0.95, 0.64, 0.54), metallic=1.0, roughness=0.4),
            ),
            (
                moved(primitives.sphere(0.25, 64, 32), (0.1, 0.25, -0.55)),
                Material("smooth metal", (0.9, 0.9, 0.9), metallic=1.0, roughness=0.05),
            ),
        ]
    return objs


CORNELL_CAMERA = ((0.0, 1.0, 3.9), (0.0, 1.0, 0.0), 37.0)


def scene_of(objects, camera=CORNELL_CAMERA, lights=(), name="path scene") -> Scene:
    """One mesh of `objects` ([(primitive, material)]), with `lights` and the camera (eye, target, fov_y)."""
    positions, faces, normals, uvs, mats, offset = [], [], [], [], [], 0
    for k, ((p, f, n, uv), _m) in enumerate(objects):
        positions.append(p)
        faces.append(np.asarray(f) + offset)
        normals.append(n)
        uvs.append(uv)
        mats.append(np.full(len(p), k, np.uint32))
        offset += len(p)
    eye, target, fov = camera
    return Scene(
        np.concatenate(positions),
        np.concatenate(faces),
        normals=np.concatenate(normals),
        uvs=np.concatenate(uvs),
        vertex_material=np.concatenate(mats),
        materials=[m for _, m in objects],
        lights=list(lights),
        camera=Camera.look_at(eye, target, (0.0, 1.0, 0.0), fov),
        name=name,
    )


def cornell_box() -> Scene:
    return scene_of(cornell_objects(), name="cornell box")


def interior_room() -> Scene:
    """A closed 2 x 2 x 2 room (white, a red and a green wall) with a 0.6 x 0.6 hole in its ceiling that the sun
    shines through onto the floor; the camera inside, against the front wall. All but the sun's patch is lit by
    bounced light (render it with ambient 0: no environment reaches inside)."""
    white, red, green = (0.75, 0.75, 0.75), (0.7, 0.12, 0.1), (0.15, 0.6, 0.15)

    def ceiling(x0, x1, z0, z1):
        return quad([(x0, 2, z0), (x1, 2, z0), (x1, 2, z1), (x0, 2, z1)])

    objs = [
        (quad([(-1, 0, 1), (1, 0, 1), (1, 0, -1), (-1, 0, -1)]), Material("floor", white)),
        (quad([(-1, 0, -1), (1, 0, -1), (1, 2, -1), (-1, 2, -1)]), Material("back", white)),
        (quad([(-1, 0, 1), (-1, 0, -1), (-1, 2, -1), (-1, 2, 1)]), Material("left", red)),
        (quad([(1, 0, -1), (1, 0, 1), (1, 2, 1), (1, 2, -1)]), Material("right", green)),
        (quad([(1, 0, 1), (-1, 0, 1), (-1, 2, 1), (1, 2, 1)]), Material("front", white)),
        (ceiling(-1, 1, -1, -0.3), Material("ceiling", white)),
        (ceiling(-1, 1, 0.3, 1), Material("ceiling", white)),
        (ceiling(-1, -0.3, -0.3, 0.3), Material("ceiling", white)),
        (ceiling(0.3, 1, -0.3, 0.3), Material("ceiling", white)),
    ]
    sun = DirectionalLight((0.15, -1.0, -0.3), intensity=3.0)
    return scene_of(objs, ((0.0, 1.0, 0.95), (0.0, 0.8, -1.0), 75.0), [sun], name="interior")
