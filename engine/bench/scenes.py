"""Generated scenes for `hybrid bench`: a noisy terrain scattered with displaced spheres and boxes.

`generated_mesh(n)` makes about `n` triangles (exact count in the result), all numpy and deterministic for a seed:
~60% of the triangles are a height-field terrain (sum of random plane waves, an fBm-like noise), ~40% are lumpy
spheres (subdivided icospheres with a radial displacement of their own) of log-uniform sizes resting on the terrain,
plus a few hundred boxes. Triangle sizes, overlaps and empty space vary the way a real scene's do, unlike one big
tessellated sphere.

`build_mesh(kind, n)` makes the meshes of the build benchmark (config.BUILD_KINDS): "generated" is the mesh above,
"spheres" a field of many separate subdivided icospheres (5120 triangles each) scattered in a box, "scan" one closed
lumpy surface of nearly uniform triangles, the way a scanned object is tessellated.

`generated_scene(n)` wraps it as an `engine.Scene` with smooth normals, a few materials, a low sun and a camera
looking across the terrain, ready for the Renderer (the G-buffer rays of the trace benchmark).
"""

from __future__ import annotations

import numpy as np

from ..errors import ConfigError
from ..scene import Camera, DirectionalLight, Material, Scene, SubMesh
from .config import BUILD_KINDS

TERRAIN_SIZE = 200.0  # the terrain spans [-100, 100] in x and z
TERRAIN_HEIGHT = 6.0  # amplitude of its noise (metres)
SUN_DIRECTION = (0.55, -0.55, 0.35)


def _waves(rng, count, base_freq, falloff=0.6):
    """Random plane waves (k vectors in xz, amplitudes, phases) for a sum-of-sines noise."""
    freq = base_freq * (1.9 ** np.arange(count)) * rng.uniform(0.8, 1.2, count)
    ang = rng.uniform(0, 2 * np.pi, count)
    k = np.stack([np.cos(ang) * freq, np.sin(ang) * freq], 1)
    amp = falloff ** np.arange(count)
    return k, amp / amp.sum(), rng.uniform(0, 2 * np.pi, count)


def terrain_height(x, z, waves):
    k, amp, phase = waves
    h = np.zeros(np.broadcast(x, z).shape)
    for i in range(len(amp)):
        h += amp[i] * np.sin(k[i, 0] * x + k[i, 1] * z + phase[i])
    return h * TERRAIN_HEIGHT


def _terrain(grid, waves):
    t = np.linspace(-TERRAIN_SIZE / 2, TERRAIN_SIZE / 2, grid + 1)
    x, z = np.meshgrid(t, t, indexing="xy")
    y = terrain_height(x, z, waves)
    v = np.stack([x, y, z], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(grid), np.arange(grid), indexing="xy")
    a = (j * (grid + 1) + i).reshape(-1)
    b, c, d = a + 1, a + grid + 2, a + grid + 1
    f = np.concatenate([np.stack([a, d, c], 1), np.stack([a, c, b], 1)])  # counter-clockwise seen from +y
    return v, f


def _icosphere(subdiv):
    import trimesh  # heavy to import: loaded only when a generated scene is made

    s = trimesh.creation.icosphere(subdivisions=subdiv)
    return np.asarray(s.vertices, np.float64), np.asarray(s.faces, np.int64)


def _lumpy_spheres(rng, count, subdiv, waves):
    """`count` displaced unit icospheres scaled and placed on the terrain; one batched numpy pass."""
    sv, sf = _icosphere(subdiv)
    if count == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    radius = np.exp(rng.uniform(np.log(0.4), np.log(4.0), count))
    lim = TERRAIN_SIZE / 2 * 0.9
    cx, cz = rng.uniform(-lim, lim, count), rng.uniform(-lim, lim, count)
    cy = terrain_height(cx, cz, waves) + radius * rng.uniform(0.3, 0.9, count)
    # radial displacement: 4 random 3D waves per sphere, amplitude 12% of the radius
    k = rng.normal(size=(count, 4, 3)) * rng.uniform(1.5, 4.0, (count, 4, 1))
    ph = rng.uniform(0, 2 * np.pi, (count, 4))
    disp = 1.0 + 0.12 * np.sin(np.einsum("vc,skc->svk", sv, k) + ph[:, None, :]).mean(axis=2)
    v = sv[None] * (disp * radius[:, None])[..., None] + np.stack([cx, cy, cz], 1)[:, None, :]
    f = sf[None] + (np.arange(count) * len(sv))[:, None, None]
    return v.reshape(-1, 3), f.reshape(-1, 3)


def _boxes(rng, count, waves):
    import trimesh  # heavy to import: loaded only when a generated scene is made

    b = trimesh.creation.box()
    bv, bf = np.asarray(b.vertices), np.asarray(b.faces)
    size = rng.uniform(0.3, 3.0, (count, 3)) * np.array([1.0, 2.0, 1.0])
    lim = TERRAIN_SIZE / 2 * 0.9
    cx, cz = rng.uniform(-lim, lim, count), rng.uniform(-lim, lim, count)
    cy = terrain_height(cx, cz, waves) + size[:, 1] * 0.4
    ang = rng.uniform(0, np.pi, count)
    c, s = np.cos(ang), np.sin(ang)
    p = bv[None] * size[:, None, :]
    x = p[..., 0] * c[:, None] - p[..., 2] * s[:, None]
    z = p[..., 0] * s[:, None] + p[..., 2] * c[:, None]
    v = np.stack([x + cx[:, None], p[..., 1] + cy[:, None], z + cz[:, None]], -1)
    f = bf[None] + (np.arange(count) * len(bv))[:, None, None]
    return v.reshape(-1, 3), f.reshape(-1, 3)


def generated_parts(n_tris: int, seed: int = 0):
    """[(name, vertices, faces)] of a scene of about `n_tris` triangles."""
    n_tris = max(int(n_tris), 1000)
    rng = np.random.default_rng(seed)
    waves = _waves(rng, 9, 2 * np.pi / 120.0)
    n_boxes = min(400, n_tris // 200)
    subdiv = 4 if n_tris >= 200_000 else 3  # 5120 or 1280 triangles per sphere
    per_sphere = 20 * 4**subdiv
    n_spheres = max(1, int(0.4 * n_tris) // per_sphere)
    rest = n_tris - n_spheres * per_sphere - 12 * n_boxes
    grid = max(4, int(round(np.sqrt(max(rest, 32) / 2))))
    tv, tf = _terrain(grid, waves)
    sv, sf = _lumpy_spheres(rng, n_spheres, subdiv, waves)
    bv, bf = _boxes(rng, n_boxes, waves)
    return [("terrain", tv, tf), ("spheres", sv, sf), ("boxes", bv, bf)]


def generated_mesh(n_tris: int, seed: int = 0):
    """(vertices (V, 3) float32, faces (T, 3) int64) of about `n_tris` triangles (see the module doc)."""
    vs, fs, base = [], [], 0
    for _, v, f in generated_parts(n_tris, seed):
        vs.append(v)
        fs.append(f + base)
        base += len(v)
    return np.concatenate(vs).astype(np.float32), np.concatenate(fs).astype(np.int64)


def sphere_field_mesh(n_tris: int, seed: int = 0):
    """About `n_tris` triangles as separate icospheres (5120 triangles each; 1280 below 200k triangles) of radii
    0.5-1.5, centred at random in a box sized so that they rarely touch; float32 vertices, int64 faces."""
    n_tris = max(int(n_tris), 1000)
    rng = np.random.default_rng(seed)
    subdiv = 4 if n_tris >= 200_000 else 3
    sv, sf = _icosphere(subdiv)
    count = max(1, int(round(n_tris / len(sf))))
    radius = rng.uniform(0.5, 1.5, count)
    side = 4.0 * count ** (1 / 3)  # about one sphere per 64 unit cubes
    centre = rng.uniform(0, side, (count, 3))
    v = sv[None] * radius[:, None, None] + centre[:, None, :]
    f = sf[None] + (np.arange(count) * len(sv))[:, None, None]
    return v.reshape(-1, 3).astype(np.float32), f.reshape(-1, 3).astype(np.int64)


def scan_mesh(n_tris: int, seed: int = 0):
    """About `n_tris` triangles on one closed lumpy surface: a cube's six faces gridded m x m, projected onto the
    unit sphere and displaced radially by a few random waves (triangles of nearly one size, like a scan's);
    float32 vertices, int64 faces."""
    m = max(2, int(round(np.sqrt(max(int(n_tris), 1000) / 12))))
    rng = np.random.default_rng(seed)
    t = np.linspace(-1.0, 1.0, m + 1)
    u, w = np.meshgrid(t, t, indexing="ij")
    one = np.ones_like(u)
    vs, fs = [], []
    i, j = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
    a = (i * (m + 1) + j).reshape(-1)
    quad = np.concatenate([np.stack([a, a + m + 1, a + m + 2], 1), np.stack([a, a + m + 2, a + 1], 1)])
    for axis in range(3):
        for sign in (1.0, -1.0):
            p = np.roll(np.stack([sign * one, u, w], -1), axis, axis=-1).reshape(-1, 3)
            face = quad if sign > 0 else quad[:, ::-1]  # outward winding on both sides
            fs.append(face + sum(len(x) for x in vs))
            vs.append(p)
    v = np.concatenate(vs)
    v /= np.linalg.norm(v, axis=1, keepdims=True)  # the seams' duplicate vertices land on the same points
    k = rng.normal(size=(6, 3)) * rng.uniform(2.0, 9.0, (6, 1))
    disp = 1.0 + 0.1 * np.sin(v @ k.T + rng.uniform(0, 2 * np.pi, 6)).mean(axis=1)
    return (v * disp[:, None]).astype(np.float32), np.concatenate(fs).astype(np.int64)


def build_mesh(kind: str, n_tris: int, seed: int = 0):
    """(vertices float32, faces int64) of about `n_tris` triangles of a BUILD_KINDS kind."""
    if kind == "generated":
        return generated_mesh(n_tris, seed)
    if kind == "spheres":
        return sphere_field_mesh(n_tris, seed)
    if kind == "scan":
        return scan_mesh(n_tris, seed)
    raise ConfigError(f"build_mesh: unknown mesh kind {kind!r} (known: {', '.join(BUILD_KINDS)})")


def vertex_normals(v, f):
    """Area-weighted smooth vertex normals (bincount, fast for millions of triangles)."""
    v = np.asarray(v, np.float64)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n = np.zeros_like(v)
    idx = f.reshape(-1)
    for c in range(3):
        n[:, c] = np.bincount(idx, np.repeat(fn[:, c], 3), minlength=len(v))
    length = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.where(length > 0, n / np.maximum(length, 1e-30), np.array([0.0, 1.0, 0.0]))
    return n


def generated_scene(n_tris: int = 1_200_000, seed: int = 0):
    """An `engine.Scene` of the generated mesh: three materials, a low sun, a camera across the terrain."""
    colors = {"terrain": (0.35, 0.45, 0.25), "spheres": (0.7, 0.55, 0.45), "boxes": (0.6, 0.6, 0.65)}
    vs, fs, ns, vm, subs, base, first_tri = [], [], [], [], [], 0, 0
    for m, (name, v, f) in enumerate(generated_parts(n_tris, seed)):
        vs.append(v)
        fs.append(f + base)
        ns.append(vertex_normals(v, f))
        vm.append(np.full(len(v), m, np.uint32))
        subs.append(SubMesh(name, base, len(v), first_tri, len(f), m))
        base += len(v)
        first_tri += len(f)
    materials = [Material(name, colors[name]) for name in colors]
    camera = Camera.look_at((-20.0, 28.0, 95.0), (5.0, 0.0, 10.0), fov_y=55.0)
    return Scene(
        np.concatenate(vs),
        np.concatenate(fs),
        normals=np.concatenate(ns),
        vertex_material=np.concatenate(vm),
        materials=materials,
        lights=[DirectionalLight(SUN_DIRECTION, intensity=3.0)],
        camera=camera,
        name=f"<generated {first_tri} triangles, seed {seed}>",
        submeshes=subs,
    )
