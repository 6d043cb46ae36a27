import numpy as np
import trimesh

import engine
from engine.rt.reference import reference_intersect

m = trimesh.creation.icosphere(4)
with engine.Tracer(m.vertices, m.faces) as t:
    rng = np.random.default_rng(0)
    o = rng.uniform(-2, 2, (20000, 3)).astype(np.float32)
    d = (-o + rng.normal(0, 0.3, o.shape)).astype(np.float32)
    h = t.intersect(o, d)
    tr, pr, _, _ = reference_intersect(m.vertices, m.faces, o[:2000], d[:2000])
    print("device", t.ctx.device_info, "hit agree", ((h.prim[:2000] >= 0) == (pr >= 0)).mean())
s = engine.Scene.load("scenes/default.toml")
with engine.Renderer(1920, 1080) as r:
    for _ in range(4):
        f = r.render(s)
    print(
        "1080p default timings",
        {k: round(v, 3) for k, v in f.timings.items()},
        "total",
        round(sum(f.timings.values()), 3),
    )
    print("bvh", r.bvh_stats)
