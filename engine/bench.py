"""`hybrid bench [build|trace|frame|all]`: the benchmark suite (issue 6; issue 3 item 5).

    build  BVH build at 100k, 1M and 4M generated triangles: ms, ms per million, SAH cost, bytes per triangle.
    trace  Mrays/s of our Tracer (GPU timestamps and wall clock, upload + readback included) on three ray sets:
           coherent shadow rays from a rendered G-buffer towards the scene's first light, incoherent AO rays
           (cosine hemisphere, tmax = 10% of the scene diagonal) and closest hits of random rays; on a generated
           scene of >= 1M triangles and on the default scene. The peers run the SAME rays in the same process:
           embreex (trimesh's ray engine, one thread, as trimesh calls it) and Open3D's RaycastingScene (all
           cores). Ratios ours / peer, and how often the answers agree (hit or miss).
    frame  A full frame per pass (GPU ms from Frame.timings) at 640x360 on a CPU device (lavapipe) or 1920x1080 on a
           GPU, plus the wall time of Renderer.render() and the host (Python) time of a Renderer.submit().

Every figure is a median over `reps` runs after `warmup` runs. Output: a table on stdout, a progress bar on stderr,
JSON (machine, date, command, every figure) and a PNG plot. The Python entry point is `run_bench(BenchConfig(...))`.
"""
from __future__ import annotations

import abc

import datetime as _dt
import json
import os
import platform
import statistics
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from .errors import ConfigError, EngineError

REPO = Path(__file__).resolve().parent.parent
DEFAULT_SCENE = REPO / "scenes" / "default.toml"
SECTIONS = ("build", "trace", "frame")
ENGINES = ("ours", "embreex", "open3d")
PEERS = ("embreex", "open3d")
RAYSETS = ("shadow", "ao", "random")
RAYSET_TITLES = {"shadow": "shadow rays (occluded, G-buffer)", "ao": "AO rays (occluded, G-buffer)",
                 "random": "random rays (closest hit)"}
ORIGIN_OFFSET = 1e-4     # G-buffer ray origins: p + n * ORIGIN_OFFSET * scene diagonal
AO_RADIUS = 0.1          # AO ray length: fraction of the scene diagonal


# ---------------------------------------------------------------------------------------------------------------
# configuration


@dataclass
class BenchConfig:
    sections: tuple = SECTIONS
    quick: bool = False
    size: tuple | None = None                  # (w, h); None: 640x360 on a CPU device, 1920x1080 on a GPU
    device: str | None = None
    validation: bool = False
    build_sizes: tuple = (100_000, 1_000_000, 4_000_000)
    build_reps: int = 3                        # sizes above 2M triangles get one run less (at least one)
    generated_tris: int = 1_200_000            # the trace benchmark's generated scene
    mid_tris: int = 300_000                    # frame "generated-300k": the size the issue-6 shadow target names
    real_scene: str | None = str(DEFAULT_SCENE)
    frame_scenes: tuple = ("real", "target", "mid", "generated")  # target: the issue-6 frame (1 light, 1 AO ray
    #                                                                   per pixel); mid: generated, mid_tris, 1 AO ray
    peers: tuple = PEERS
    reps: int = 7
    warmup: int = 1
    frame_reps: int = 5
    frame_warmup: int = 2
    random_rays: int | None = None             # None: as many as the G-buffer has pixels
    thread_probe: bool = True                  # lavapipe only: re-run the default scene's rays with LP_NUM_THREADS
    seed: int = 1

    @classmethod
    def for_cli(cls, section: str = "all", quick: bool = False, size=None, device=None) -> "BenchConfig":
        sections = SECTIONS if section == "all" else (section,)
        if section not in SECTIONS + ("all",):
            raise ConfigError(f"bench: unknown section {section!r} (known: {', '.join(SECTIONS)}, all)")
        cfg = cls(sections=sections, quick=quick, size=size, device=device)
        if quick:
            cfg.build_sizes = (100_000, 1_000_000)
            cfg.build_reps = 2
            cfg.generated_tris = 1_000_000
            cfg.reps = 3
            cfg.frame_reps = 3
            cfg.frame_warmup = 1
            cfg.thread_probe = False
        return cfg


# ---------------------------------------------------------------------------------------------------------------
# progress bar and small helpers


class Progress:
    """`[#####.....] 5/10 trace: AO rays (open3d)` on stderr: redrawn in place on a terminal, one line per step
    otherwise."""

    def __init__(self, total: int, stream=None, width: int = 24, enabled: bool = True):
        self.total, self.done, self.width = max(total, 1), 0, width
        self.stream = sys.stderr if stream is None else stream
        self.enabled = enabled
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.t0 = time.perf_counter()

    def step(self, label: str):
        """Announce the step about to run (the bar shows the steps finished before it)."""
        if not self.enabled:
            return
        filled = int(round(self.width * self.done / self.total))
        line = (f"[{'#' * filled}{'.' * (self.width - filled)}] {self.done + 1}/{self.total} {label} "
                f"({time.perf_counter() - self.t0:.0f} s)")
        if self.tty:
            self.stream.write("\r\x1b[2K" + line)
        else:
            self.stream.write(line + "\n")
        self.stream.flush()

    def advance(self):
        self.done += 1

    def finish(self):
        if not self.enabled:
            return
        line = f"[{'#' * self.width}] {self.total}/{self.total} done in {time.perf_counter() - self.t0:.0f} s"
        self.stream.write(("\r\x1b[2K" if self.tty else "") + line + "\n")
        self.stream.flush()


def _median(values):
    return float(statistics.median(values)) if values else float("nan")


def _timed(fn, reps, warmup):
    """Run fn() warmup + reps times; the median wall seconds of the timed runs, every wall time, the last result."""
    out = None
    for _ in range(warmup):
        out = fn()
    walls = []
    for _ in range(max(reps, 1)):
        t0 = time.perf_counter()
        out = fn()
        walls.append(time.perf_counter() - t0)
    return _median(walls), walls, out


def _scene_diag(scene_or_bounds) -> float:
    b = np.asarray(getattr(scene_or_bounds, "bounds", scene_or_bounds), np.float64)
    return float(np.linalg.norm(b[1] - b[0])) or 1.0


# ---------------------------------------------------------------------------------------------------------------
# machine information


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _version(module: str) -> str | None:
    try:
        from importlib.metadata import version
        return version(module)
    except Exception:
        return None


def device_details(ctx) -> dict:
    """Name, type, API and driver of a Context's physical device (driver name/info through Vulkan 1.2 properties)."""
    import vulkan as vk
    info = dict(ctx.device_info)
    info.pop("rank", None)
    props = ctx.properties
    info.update(vendor_id=hex(props.vendorID), device_id=hex(props.deviceID), driver_version=int(props.driverVersion),
                timestamp_period_ns=ctx.timestamp_period_ns)
    try:
        drv = vk.VkPhysicalDeviceDriverProperties()
        vk.vkGetPhysicalDeviceProperties2(ctx.physical, vk.VkPhysicalDeviceProperties2(pNext=drv))
        info["driver"] = vk.ffi.string(drv.driverName).decode()
        info["driver_info"] = vk.ffi.string(drv.driverInfo).decode()
    except Exception:  # an older driver without VkPhysicalDeviceDriverProperties
        pass
    return info


def _cpu_busy_seconds() -> float | None:
    """Busy CPU seconds of the whole machine so far (all cores), from /proc/stat."""
    try:
        fields = Path("/proc/stat").read_text().splitlines()[0].split()[1:]
        user, nice, system, idle, iowait, irq, softirq, steal = (int(x) for x in fields[:8])
        return (user + nice + system + irq + softirq) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


class OtherLoad:
    """How much CPU other processes used while the bench ran: machine busy time minus this process's own (and its
    children's). On a shared 2-core machine this says how much the figures were disturbed."""

    def __init__(self):
        self.t0, self.busy0, self.own0 = time.perf_counter(), _cpu_busy_seconds(), self._own()

    @staticmethod
    def _own():
        t = os.times()
        return t.user + t.system + t.children_user + t.children_system

    def result(self) -> dict:
        wall = time.perf_counter() - self.t0
        busy = _cpu_busy_seconds()
        if busy is None or self.busy0 is None:
            return {"wall_s": wall}
        others = max(0.0, (busy - self.busy0) - (self._own() - self.own0))
        return {"wall_s": round(wall, 1), "own_cpu_s": round(self._own() - self.own0, 1),
                "others_cpu_s": round(others, 1), "others_mean_cores": round(others / wall, 2) if wall else None}


def machine_info() -> dict:
    try:
        mem = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2 ** 30
    except (ValueError, OSError, AttributeError):
        mem = None
    try:
        load = os.getloadavg()
    except OSError:
        load = None
    return {
        "cpu": _cpu_model(),
        "cores": os.cpu_count(),
        "memory_gib": round(mem, 1) if mem else None,
        "load_average": [round(x, 2) for x in load] if load else None,
        "os": platform.platform(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "embreex": _version("embreex"),
        "open3d": _version("open3d"),
        "trimesh": _version("trimesh"),
        "env": {k: os.environ[k] for k in ("LP_NUM_THREADS", "HYBRID_DEVICE", "OMP_NUM_THREADS") if k in os.environ},
    }


# ---------------------------------------------------------------------------------------------------------------
# ray sets


@dataclass
class RaySet:
    name: str
    kind: str                 # "occluded" or "intersect"
    origins: np.ndarray       # (N, 3) float32, contiguous
    directions: np.ndarray    # (N, 3) float32, contiguous
    tmax: float               # one tmax for all rays (what Open3D's test_occlusions takes)
    note: str = ""

    def __len__(self):
        return len(self.origins)


def cosine_hemisphere(n, rng):
    """Cosine-weighted directions around unit normals n (N, 3) (the basis of sampling.glsl, Duff et al. 2017)."""
    n = np.asarray(n, np.float64)
    u1, u2 = rng.random(len(n)), rng.random(len(n))
    r, phi = np.sqrt(u1), 2 * np.pi * u2
    s = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (s + n[:, 2])
    c = n[:, 0] * n[:, 1] * a
    t = np.stack([1 + s * n[:, 0] ** 2 * a, s * c, -s * n[:, 0]], 1)
    b = np.stack([c, s + n[:, 1] ** 2 * a, -n[:, 1]], 1)
    d = t * (r * np.cos(phi))[:, None] + b * (r * np.sin(phi))[:, None] + n * np.sqrt(np.maximum(0, 1 - u1))[:, None]
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _f32(a):
    return np.ascontiguousarray(a, dtype=np.float32)


def _shadow_rays(scene, frame):
    """Per covered pixel of `frame`: origin (p + n * ORIGIN_OFFSET * diagonal), unit normal, direction to the
    scene's first light, and the common tmax, a description, and which pixels have the light above their horizon
    (the ones the shadow pass traces)."""
    from .scene import DirectionalLight

    cover = np.isfinite(frame.aov["depth"])
    p = frame.aov["position"][cover].astype(np.float64)
    n = frame.aov["normal"][cover].astype(np.float64)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
    o = p + n * (ORIGIN_OFFSET * _scene_diag(scene))
    light = scene.lights[0]
    if isinstance(light, DirectionalLight):
        d = np.broadcast_to(-np.asarray(light.direction, np.float64), o.shape)
        tmax, what = float("inf"), f"towards the sun {type(light).__name__}"
    else:
        d = np.asarray(light.position, np.float64) - o
        tmax, what = 0.999, f"to the centre of a {type(light).__name__}"
    up = np.einsum("ij,ij->i", d, n) > 0
    return o, n, d, tmax, what, up


def gbuffer_raysets(scene, frame, rng) -> list[RaySet]:
    """Shadow rays towards the scene's first light and one AO ray per covered pixel of a rendered G-buffer.

    Origins: p + n * 1e-4 * diagonal. Shadow rays whose light direction is below the surface's horizon are dropped,
    as the shadow pass skips them. A directional light: unit directions and tmax = inf; a point-like light: the
    direction is the vector to the light (not unit) and tmax = 0.999, so one tmax serves all rays."""
    o, n, d, tmax, what, up = _shadow_rays(scene, frame)
    diag = _scene_diag(scene)
    pixels = len(o)
    shadow = RaySet("shadow", "occluded", _f32(o[up]), _f32(d[up]), tmax,
                    f"{int(up.sum())} of {pixels} covered pixels (light above the horizon), {what}")
    ao = RaySet("ao", "occluded", _f32(o), _f32(cosine_hemisphere(n, rng)), AO_RADIUS * diag,
                f"1 cosine-hemisphere ray per covered pixel ({pixels}), tmax = {AO_RADIUS:g} x diagonal")
    return [shadow, ao]


def random_rayset(scene, count, rng) -> RaySet:
    """Closest-hit rays between two uniform random points of the scene's bounding box (incoherent, crossing it)."""
    lo, hi = (np.asarray(b, np.float64) for b in scene.bounds)
    ext = np.maximum(hi - lo, 1e-3 * _scene_diag(scene))
    a = lo + rng.random((count, 3)) * ext
    b = lo + rng.random((count, 3)) * ext
    d = b - a
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-30)
    return RaySet("random", "intersect", _f32(a), _f32(d), float("inf"),
                  f"{count} rays between random points of the bounding box, unit directions, tmax = inf")


# ---------------------------------------------------------------------------------------------------------------
# engines: ours and the peers behind one interface


class Engine(abc.ABC):
    name = ""
    label = ""
    threads = None

    @abc.abstractmethod
    def occluded(self, rs: RaySet) -> np.ndarray:
        """(N,) bool: any hit within [0, tmax]."""

    @abc.abstractmethod
    def intersect(self, rs: RaySet) -> tuple[np.ndarray, np.ndarray]:
        """(t with +inf on a miss, prim with -1 on a miss)"""

    def query(self, rs: RaySet):
        return self.occluded(rs) if rs.kind == "occluded" else self.intersect(rs)

    def close(self):
        pass


class OursEngine(Engine):
    """engine.Tracer on a Vulkan context of its own, as a user of the batch API makes it.

    Its own context on purpose: on lavapipe (Mesa 22.3) a compute-only command buffer submitted on a context that
    has rendered before gets its TOP_OF_PIPE timestamp resolved only at the next flush, after the dispatch, so
    `last_gpu_ms` reads ~0 there (measured: 0.03 ms for a 250 ms query). `queue_ms` (vkQueueSubmit + fence wait,
    timed on the host) is kept as a cross-check of the timestamps."""

    name, label = "ours", "ours (Vulkan compute)"

    def __init__(self, vertices, faces, device=None, validation=False):
        from .rt import Tracer
        self.tracer = Tracer(vertices, faces, device=device, validation=validation)
        self.stats = dict(self.tracer.stats)
        self.threads = os.environ.get("LP_NUM_THREADS")
        self.last_gpu_ms = 0.0
        self.last_queue_ms = 0.0
        ctx = self.tracer.ctx
        submit = ctx.submit

        def timed_submit(*a, **k):
            t0 = time.perf_counter()
            try:
                return submit(*a, **k)
            finally:
                self.last_queue_ms += (time.perf_counter() - t0) * 1e3
        ctx.submit = timed_submit   # instance attribute: only this engine's context is timed

    def occluded(self, rs):
        self.last_queue_ms = 0.0
        out = self.tracer.occluded(rs.origins, rs.directions, rs.tmax)
        self.last_gpu_ms = self.tracer.last_gpu_ms
        return out

    def intersect(self, rs):
        self.last_queue_ms = 0.0
        h = self.tracer.intersect(rs.origins, rs.directions, rs.tmax)
        self.last_gpu_ms = self.tracer.last_gpu_ms
        return h.t, h.prim

    @property
    def validation_errors(self):
        return list(self.tracer.validation_errors)

    def close(self):
        self.tracer.close()


class EmbreexEngine(Engine):
    """embreex as trimesh's RayMeshIntersector drives it: one rtcIntersect1/rtcOccluded1 per ray, one thread."""

    name, label, threads = "embreex", "embreex (Embree, 1 thread)", 1

    def __init__(self, vertices, faces):
        from embreex import mesh_construction, rtcore_scene
        self.scene = rtcore_scene.EmbreeScene()
        mesh_construction.TriangleMesh(self.scene, np.ascontiguousarray(vertices, np.float32),
                                       np.ascontiguousarray(faces, np.int32))
        one = np.zeros((1, 3), np.float32)
        self.scene.run(one, one + np.float32(1.0))   # commits the scene: the BVH build

    def _dists(self, rs):
        return None if not np.isfinite(rs.tmax) else np.full(len(rs), rs.tmax, np.float32)

    def occluded(self, rs):
        return self.scene.run(rs.origins, rs.directions, dists=self._dists(rs), query="OCCLUDED") != -1

    def intersect(self, rs):
        r = self.scene.run(rs.origins, rs.directions, dists=self._dists(rs), output=1)
        prim = r["primID"].astype(np.int64)
        return np.where(prim >= 0, r["tfar"], np.inf).astype(np.float32), prim


class Open3DEngine(Engine):
    """Open3D's RaycastingScene (Embree inside, all cores): test_occlusions and cast_rays."""

    name = "open3d"

    def __init__(self, vertices, faces):
        import open3d as o3d
        self.o3d = o3d
        self.threads = os.cpu_count()
        self.label = f"Open3D (Embree, {self.threads} threads)"
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(vertices, np.float32)),
                                 o3d.core.Tensor(np.ascontiguousarray(faces, np.uint32)))
        self.scene.test_occlusions(o3d.core.Tensor(np.array([[0, 0, 0, 1, 0, 0]], np.float32)))   # commits

    def _rays(self, rs):
        return self.o3d.core.Tensor(np.concatenate([rs.origins, rs.directions], axis=1))

    def occluded(self, rs):
        return self.scene.test_occlusions(self._rays(rs), tnear=0.0, tfar=rs.tmax).numpy().astype(bool)

    def intersect(self, rs):
        ans = self.scene.cast_rays(self._rays(rs))
        t = ans["t_hit"].numpy()
        prim = ans["primitive_ids"].numpy().astype(np.int64)
        hit = np.isfinite(t) & (t <= rs.tmax)
        return np.where(hit, t, np.inf).astype(np.float32), np.where(hit, prim, -1)


def make_peer(name, vertices, faces):
    """A peer engine, or (None, reason) when its package is missing or does not load."""
    try:
        cls = {"embreex": EmbreexEngine, "open3d": Open3DEngine}[name]
    except KeyError:
        raise ConfigError(f"bench: unknown peer {name!r} (known: {', '.join(PEERS)})") from None
    try:
        return cls(vertices, faces), None
    except ImportError as exc:
        return None, f"not installed or not loadable: {exc}"


def agreement(kind, ours, peer, diag) -> dict:
    """How often a peer's answer equals ours: hit/miss, and for closest hits the distance and the triangle."""
    if kind == "occluded":
        return {"hit_miss": float(np.mean(np.asarray(ours) == np.asarray(peer))),
                "ours_hit_fraction": float(np.mean(ours)), "peer_hit_fraction": float(np.mean(peer))}
    (t0, p0), (t1, p1) = ours, peer
    h0, h1 = p0 >= 0, p1 >= 0
    both = h0 & h1
    out = {"hit_miss": float(np.mean(h0 == h1)), "ours_hit_fraction": float(h0.mean()),
           "peer_hit_fraction": float(h1.mean())}
    if both.any():
        close = np.abs(t0[both] - t1[both]) <= 1e-4 * np.maximum(np.abs(t1[both]), 1.0) + 1e-6 * diag
        out["t_close"] = float(close.mean())
        out["same_prim"] = float(np.mean(p0[both] == p1[both]))
    return out


# ---------------------------------------------------------------------------------------------------------------
# the runner


class Bench:
    """Runs the sections of a BenchConfig; `results` is what goes to the JSON."""

    def __init__(self, cfg: BenchConfig, progress: Progress | None = None):
        self.cfg = cfg
        self.progress = progress
        self.results: dict = {}
        self._renderer = None
        self._scenes: dict = {}
        self.validation_errors: list[str] = []
        self.tracer_validation_errors: list[str] = []

    # ---- plumbing ----------------------------------------------------------------------------------------------
    def _step(self, label, fn, *args):
        if self.progress is not None:
            self.progress.step(label)
        try:
            return fn(*args)
        finally:
            if self.progress is not None:
                self.progress.advance()

    def plan(self) -> int:
        """How many progress steps the configured run takes."""
        cfg, n = self.cfg, 0
        if "build" in cfg.sections:
            n += len(cfg.build_sizes)
        if "trace" in cfg.sections:
            per_scene = 2 + len(cfg.peers) + len(RAYSETS) * (2 + len(cfg.peers))
            n += per_scene * (1 + (cfg.real_scene is not None)) + self._probe_wanted()
        if "frame" in cfg.sections:
            n += 2 * len(self._frame_scene_keys())
        return n

    def _frame_scene_keys(self):
        return [k for k in self.cfg.frame_scenes if k in ("generated", "mid") or self.cfg.real_scene is not None]

    def device_choice(self):
        from .vk import choose_device, describe_devices
        devices = describe_devices()
        return devices[choose_device(devices, self.cfg.device)]

    def size(self) -> tuple[int, int]:
        if self.cfg.size is not None:
            return tuple(self.cfg.size)
        return (640, 360) if self.device_choice()["type"] == "CPU" else (1920, 1080)

    def renderer(self):
        if self._renderer is None:
            from .renderer import Renderer
            w, h = self.size()
            self._renderer = Renderer(w, h, device=self.cfg.device, validation=self.cfg.validation)
        return self._renderer

    def scene(self, key):
        if key not in self._scenes:
            if key in ("generated", "mid"):
                from .bench_scenes import generated_scene
                tris = self.cfg.generated_tris if key == "generated" else self.cfg.mid_tris
                self._scenes[key] = generated_scene(tris, seed=self.cfg.seed)
            elif key == "real":
                from .scene import Scene
                self._scenes[key] = Scene.load(self.cfg.real_scene)
            else:
                raise ConfigError(f"bench: unknown scene {key!r}")
        return self._scenes[key]

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self.validation_errors += list(self._renderer.validation_errors)
            self._renderer = None

    # ---- sections ----------------------------------------------------------------------------------------------
    def run(self) -> dict:
        cfg = self.cfg
        self.results["meta"] = {
            "date": _dt.datetime.now().astimezone().isoformat(timespec="seconds"),
            "command": " ".join(["hybrid"] + sys.argv[1:]) if Path(sys.argv[0]).name in ("hybrid", "__main__.py")
            else " ".join(sys.argv),
            "config": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(cfg).items()},
            "machine": machine_info(),
        }
        other = OtherLoad()
        try:
            if "build" in cfg.sections:
                self.results["build"] = self.run_build()
            if "trace" in cfg.sections or "frame" in cfg.sections:
                self.results["meta"]["device"] = device_details(self.renderer().ctx)
                self.results["meta"]["size"] = list(self.size())
            if "trace" in cfg.sections:
                self.results["trace"] = self.run_trace()
            if "frame" in cfg.sections:
                self.results["frame"] = self.run_frame()
        finally:
            self.close()
        self.results["meta"]["validation_errors"] = (self.validation_errors + self.tracer_validation_errors)[:20]
        self.results["meta"]["load_average_end"] = machine_info()["load_average"]
        self.results["meta"]["other_processes"] = other.result()
        self.results["targets"] = evaluate_targets(self.results)
        return self.results

    def run_build(self) -> list[dict]:
        from .bench_scenes import generated_mesh
        from .bvh import build_bvh
        out = []
        for n in self.cfg.build_sizes:
            reps = max(1, self.cfg.build_reps - (1 if n > 2_000_000 else 0))

            def one(n=n, reps=reps):
                v, f = generated_mesh(n, seed=self.cfg.seed)
                runs, runs1, stats = [], [], None
                for _ in range(reps):  # all cores (the default, which the targets are judged on), then one
                    for threads, into in ((None, runs), (1, runs1)):
                        t0 = time.perf_counter()
                        bvh = build_bvh(v, f, threads=threads)
                        into.append((time.perf_counter() - t0) * 1e3)
                        if threads is None:
                            stats = dict(bvh.stats)
                        del bvh
                ms = _median(runs)
                tris = int(len(f))
                return {"triangles": tris, "requested": n, "ms": ms, "runs_ms": runs,
                        "threads": stats["threads"], "ms_1thread": _median(runs1), "runs_ms_1thread": runs1,
                        "ms_per_million": ms / (tris / 1e6), "s_per_million": ms / 1e3 / (tris / 1e6),
                        "sah_cost": stats.get("sah_cost"), "bytes": stats.get("bytes"),
                        "bytes_per_triangle": stats["bytes"] / tris if stats.get("bytes") else None,
                        "nodes": stats.get("nodes"), "leaves": stats.get("leaves"), "depth": stats.get("depth"),
                        "stats": stats}
            out.append(self._step(f"build: BVH of {n / 1e6:g}M triangles x{reps}", one))
        return out

    def run_trace(self) -> dict:
        keys = ["generated"] + (["real"] if self.cfg.real_scene is not None else [])
        out = {"scenes": [self._trace_scene(k) for k in keys]}
        if self._probe_wanted():
            out["lavapipe_threads"] = self._step("trace (default): lavapipe threads, LP_NUM_THREADS = "
                                                 + ", ".join(map(str, self._probe_threads())), self._thread_probe)
        return out

    def _probe_wanted(self) -> bool:
        cfg = self.cfg
        return bool(cfg.thread_probe and "trace" in cfg.sections and
                    "llvmpipe" in self.device_choice()["name"].lower())

    def _probe_threads(self):
        cores = os.cpu_count() or 1
        return sorted({1, cores, 2 * cores})

    def _thread_probe(self) -> list[dict]:
        """The last trace scene's ray sets again, in child processes with LP_NUM_THREADS set: how our tracer scales
        with lavapipe's worker threads (lavapipe reads the variable once, when the driver loads)."""
        import subprocess
        import tempfile
        scene, sets = self._probe_input
        out = []
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "rays.npz"
            arrays = {"vertices": np.asarray(scene.positions, np.float32), "faces": np.asarray(scene.indices)}
            for rs in sets:
                arrays[f"{rs.name}_o"], arrays[f"{rs.name}_d"] = rs.origins, rs.directions
                arrays[f"{rs.name}_meta"] = np.array([rs.kind, repr(rs.tmax)])
            np.savez(path, **arrays)
            for threads in self._probe_threads():
                env = dict(os.environ, LP_NUM_THREADS=str(threads))
                cmd = [sys.executable, "-m", "engine.bench", "--probe", str(path), str(self.cfg.reps),
                       str(self.cfg.warmup)] + ([str(self.cfg.device)] if self.cfg.device is not None else [])
                proc = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=str(REPO), timeout=600)
                if proc.returncode != 0:
                    out.append({"threads": threads, "error": (proc.stderr.strip().splitlines() or ["?"])[-1]})
                    continue
                out.append({"threads": threads, "scene": "default" if scene is self._scenes.get("real")
                            else "generated", **json.loads(proc.stdout.strip().splitlines()[-1])})
        return out

    def _trace_scene(self, key) -> dict:
        cfg = self.cfg
        tag = "generated" if key == "generated" else "default"

        def prepare():
            scene = self.scene(key)
            frame = self.renderer().render(scene)
            rng = np.random.default_rng(cfg.seed)
            sets = gbuffer_raysets(scene, frame, rng)
            count = cfg.random_rays or self.renderer().width * self.renderer().height
            sets.append(random_rayset(scene, count, rng))
            return scene, frame, sets
        scene, frame, sets = self._step(f"trace ({tag}): scene, G-buffer, rays", prepare)
        diag = _scene_diag(scene)
        v = np.asarray(scene.positions, np.float32)
        f = np.asarray(scene.indices, np.int64)
        res = {"scene": tag, "name": scene.name, "triangles": scene.triangle_count, "diagonal": diag,
               "gbuffer_size": [self.renderer().width, self.renderer().height],
               "frame_timings_ms": dict(frame.timings), "setup_ms": {}, "engines": {}, "raysets": []}
        engines: dict = {}
        try:
            def build_ours():
                t0 = time.perf_counter()
                e = OursEngine(v, f, device=cfg.device, validation=cfg.validation)
                res["setup_ms"]["ours"] = (time.perf_counter() - t0) * 1e3
                res["bvh_stats"] = e.stats
                return e
            engines["ours"] = self._step(f"trace ({tag}): our BVH build + upload", build_ours)
            res["engines"]["ours"] = {"label": engines["ours"].label, "threads": engines["ours"].threads}
            for name in cfg.peers:
                def build_peer(name=name):
                    t0 = time.perf_counter()
                    e, why = make_peer(name, v, f)
                    if e is not None:
                        res["setup_ms"][name] = (time.perf_counter() - t0) * 1e3
                    return e, why
                e, why = self._step(f"trace ({tag}): {name} scene build", build_peer)
                if e is None:
                    res["engines"][name] = {"skipped": why}
                else:
                    engines[name] = e
                    res["engines"][name] = {"label": e.label, "threads": e.threads}
            for rs in sets:
                res["raysets"].append(self._trace_rayset(tag, rs, engines, diag))
            self._probe_input = (scene, sets)
        finally:
            for e in engines.values():
                if isinstance(e, OursEngine):
                    e.close()   # leaks show up at close, as validation errors
                    self.tracer_validation_errors += e.validation_errors
                else:
                    e.close()
        return res

    def _trace_rayset(self, tag, rs: RaySet, engines, diag) -> dict:
        cfg = self.cfg
        out = {"name": rs.name, "kind": rs.kind, "title": RAYSET_TITLES[rs.name], "rays": len(rs),
               "tmax": rs.tmax if np.isfinite(rs.tmax) else "inf", "note": rs.note, "results": {}, "agreement": {},
               "ratio": {}}
        answers, gpu, queue, walls = {}, {}, {}, {}
        names = [name for name in ("ours",) + tuple(cfg.peers) if name in engines]

        def once(name):
            t0 = time.perf_counter()
            answers[name] = engines[name].query(rs)
            wall = time.perf_counter() - t0
            if name == "ours":
                gpu[name].append(engines[name].last_gpu_ms)
                queue[name].append(engines[name].last_queue_ms)
            return wall

        for name in names:   # warm-up runs, one engine after the other
            gpu[name], queue[name], walls[name] = [], [], []
            self._step(f"trace ({tag}): {RAYSET_TITLES[rs.name]} ({name}, warm-up)",
                       lambda name=name: [once(name) for _ in range(cfg.warmup)])
            gpu[name].clear()
            queue[name].clear()

        def timed():
            # the timed runs interleaved (ours, peer, peer, ours, ...): this machine's speed drifts by 10-30% over
            # seconds (a shared host), and interleaving gives every engine the same conditions, so ratios hold
            for _ in range(max(cfg.reps, 1)):
                for name in names:
                    walls[name].append(once(name))
        self._step(f"trace ({tag}): {RAYSET_TITLES[rs.name]} (timed runs, interleaved)", timed)
        n = len(rs)
        for name in names:
            wall = _median(walls[name])
            r = {"wall_ms": wall * 1e3, "runs_wall_ms": [w * 1e3 for w in walls[name]],
                 "mrays_wall": n / wall / 1e6 if wall > 0 else None}
            if name == "ours":
                g, q = _median(gpu[name]), _median(queue[name])
                r.update(gpu_ms=g, runs_gpu_ms=gpu[name], mrays_gpu=n / (g * 1e-3) / 1e6 if g > 0 else None,
                         queue_ms=q, runs_queue_ms=queue[name], host_ms=wall * 1e3 - g,
                         gpu_fraction_of_wall=g / (wall * 1e3),
                         # timestamps cover the dispatch only; submit + wait adds ~0.1-1 ms, no more
                         timestamps_plausible=bool(0.5 * q - 1.0 <= g <= 1.05 * q + 0.05))
            out["results"][name] = r
        ours = out["results"].get("ours")
        for name in cfg.peers:
            if name in out["results"] and ours:
                peer = out["results"][name]
                out["ratio"][name] = {"gpu": ours["mrays_gpu"] / peer["mrays_wall"] if ours.get("mrays_gpu") else None,
                                      "wall": ours["mrays_wall"] / peer["mrays_wall"]}
                out["agreement"][name] = agreement(rs.kind, answers["ours"], answers[name], diag)
        return out

    def run_frame(self) -> list[dict]:
        out = []
        for key in self._frame_scene_keys():
            tag = {"generated": "generated", "real": "default", "target": "default-1light",
                   "mid": f"generated-{self.cfg.mid_tris // 1000}k"}[key]
            settings = {"ao_samples": 1} if key in ("target", "mid") else {}
            scene = self._step(f"frame ({tag}): load scene", self._frame_scene, key)
            out.append(self._step(f"frame ({tag}): render x{self.cfg.frame_reps}", self._frame, tag, scene,
                                  settings))
        return out

    def _frame_scene(self, key):
        if key != "target":
            return self.scene(key)
        if "target" not in self._scenes:   # the default scene with its first light only (a shallow copy)
            import copy
            s = copy.copy(self.scene("real"))
            s.lights = list(s.lights[:1])
            self._scenes["target"] = s
        return self._scenes["target"]

    def _frame(self, tag, scene, settings=None) -> dict:
        cfg, r = self.cfg, self.renderer()
        settings = dict(settings or {})
        for _ in range(cfg.frame_warmup):
            r.render(scene, **settings)
        walls, timings = [], []
        for _ in range(max(cfg.frame_reps, 1)):
            t0 = time.perf_counter()
            fr = r.render(scene, **settings)
            walls.append((time.perf_counter() - t0) * 1e3)
            timings.append(fr.timings)
        passes = list(timings[-1])
        per_pass = {p: _median([t.get(p, 0.0) for t in timings]) for p in passes}

        totals = [sum(t.values()) for t in timings]
        # The viewer's steady state: frames submitted back to back without readback, so the GPU never idles between
        # them (after an idle gap a GPU drops its clocks: on an H200 render() frames, each followed by a readback to
        # numpy, ran every pass about 2x slower). GPU ms per pass of the last of each run of 4 frames.
        # warm-up: runs of 4 until half a second has passed (a GPU that idled while the host loaded the scene ramps
        # its clocks back up only under sustained load; 4 frames of a 300k-triangle scene were not enough)
        warm_until, warmed = time.perf_counter() + 0.5, 0
        while warmed < 4 or time.perf_counter() < warm_until:
            for _ in range(4):
                r.submit(scene, wait=False, **settings)
            r.ctx.wait_idle()
            warmed += 4
        steady = []
        for _ in range(max(cfg.frame_reps, 1)):
            for _ in range(4):
                r.submit(scene, wait=False, **settings)
            r.ctx.wait_idle()
            steady.append(r.last_timings())
        steady_passes = {p: _median([t.get(p, 0.0) for t in steady]) for p in steady[-1]}
        steady_totals = [sum(t.values()) for t in steady]
        # The viewer's path: submit() without readback or waiting; the host (Python + vkQueueSubmit) time per frame.
        r.submit(scene, wait=False, **settings)
        r.ctx.wait_idle()
        host, host_cpu, sub_gpu = [], [], []
        for _ in range(max(cfg.frame_reps, 1) * 2):
            c0, t0 = time.thread_time(), time.perf_counter()
            r.submit(scene, wait=False, **settings)
            host.append((time.perf_counter() - t0) * 1e3)
            host_cpu.append((time.thread_time() - c0) * 1e3)
            r.ctx.wait_idle()
            sub_gpu.append(sum(r.last_timings().values()))
        lights = len(scene.lights)
        # the rays the shadow pass traces for the first light: covered pixels with the light above their horizon
        # (the bench's shadow ray set); counted last, since host work between the runs above lets a GPU's clocks
        # drop
        shadow_rays = int(_shadow_rays(scene, fr)[-1].sum()) if lights == 1 else 0

        def grays(ms):  # the shadow pass's rays per second (one light's rays; a frame of several lights traces more)
            return shadow_rays / (ms * 1e-3) / 1e9 if lights == 1 and ms and ms > 0 else None

        return {"shadow_rays": shadow_rays, "shadow_pass_grays": grays(per_pass.get("shadows")),
                "viewer_shadow_pass_grays": grays(steady_passes.get("shadows")),
                "scene": tag, "name": scene.name, "triangles": scene.triangle_count, "size": [r.width, r.height],
                "lights": lights, "settings": dict(fr.settings), "passes_ms": per_pass,
                "gpu_total_ms": _median(totals), "runs_gpu_total_ms": totals,
                "viewer_passes_ms": steady_passes, "viewer_gpu_total_ms": _median(steady_totals),
                "runs_viewer_gpu_total_ms": steady_totals,
                "render_wall_ms": _median(walls), "runs_render_wall_ms": walls,
                "submit_host_ms": _median(host), "submit_host_cpu_ms": _median(host_cpu),
                "submit_gpu_total_ms": _median(sub_gpu)}


# ---------------------------------------------------------------------------------------------------------------
# targets (issues 3 and 6)


def _target(issue, what, measured, target, unit, higher_is_better, note=""):
    if measured is None:
        return {"issue": issue, "target": what, "measured": None, "unit": unit, "status": "not measured", "note": note}
    ok = measured >= target if higher_is_better else measured <= target
    # margin > 1: better than the goal by that factor; < 1: the goal needs 1 / margin times better
    margin = measured / target if higher_is_better else target / measured if measured else float("inf")
    by = f"{margin:.2f}x margin" if ok else f"needs {1 / margin:.2f}x"
    return {"issue": issue, "target": what, "goal": target, "measured": measured, "unit": unit,
            "status": "pass" if ok else "miss", "margin": margin, "summary": f"{'pass' if ok else 'miss'} ({by})",
            "note": note}


def evaluate_targets(results: dict) -> list[dict]:
    out = []
    for b in results.get("build", []):
        if b["triangles"] >= 900_000:
            m = f"{b['triangles'] / 1e6:.1f}M triangles"
            out.append(_target(3, f"BVH build <= 1.0 s per million triangles ({m})", b["s_per_million"], 1.0, "s/M",
                               False))
            out.append(_target(6, f"BVH build <= 0.5 s per million triangles ({m})", b["s_per_million"], 0.5, "s/M",
                               False))
    device = results.get("meta", {}).get("device", {})
    cpu_device = device.get("type") == "CPU"
    for sc in results.get("trace", {}).get("scenes", []):
        for rs in sc["raysets"]:
            if rs["kind"] != "occluded" or "open3d" not in rs["ratio"]:
                continue
            ratio = rs["ratio"]["open3d"]
            for basis in ("wall", "gpu"):
                where = f"{sc['scene']} scene, {rs['name']} rays, {'wall clock' if basis == 'wall' else 'GPU time'}"
                out.append(_target(3, f"occlusion >= 0.5x Open3D ({where})", ratio[basis], 0.5, "x", True))
                if cpu_device:
                    out.append(_target(6, f"lavapipe occlusion >= 1.0x Open3D ({where})", ratio[basis], 1.0, "x", True))
    gpu_device = device and not cpu_device
    size = results.get("meta", {}).get("size")
    big = [sc for sc in results.get("trace", {}).get("scenes", []) if sc["triangles"] >= 300_000]
    note_gpu = "" if gpu_device else ("needs a GPU; this run's device is a CPU" if device else
                                      "needs a GPU and the trace/frame sections")
    shadow = ao = None
    if gpu_device and big and size == [1920, 1080]:
        rs = {r["name"]: r for r in big[0]["raysets"]}
        shadow = rs["shadow"]["results"]["ours"].get("mrays_gpu")
        ao = rs["ao"]["results"]["ours"].get("mrays_gpu")
    out.append(_target(6, f"GPU: 1920x1080 shadow rays >= 4 Grays/s, batch Tracer ({big[0]['scene'] if big else '-'} "
                          f"scene, {big[0]['triangles'] if big else 0:,} triangles)",
                       shadow / 1e3 if shadow else None, 4.0, "Grays/s", True, note_gpu))
    # the same target met by the renderer's own shadow pass (G-buffer in, light mask out; frames back to back) on the
    # smallest frame scene of >= 300k triangles
    passes = sorted((fr for fr in results.get("frame", []) if fr["triangles"] >= 300_000
                     and fr.get("viewer_shadow_pass_grays")), key=lambda fr: fr["triangles"])
    pass_grays = passes[0]["viewer_shadow_pass_grays"] if gpu_device and passes and size == [1920, 1080] else None
    where = f"{passes[0]['scene']}, {passes[0]['triangles']:,} triangles" if passes else ">= 300k triangles"
    out.append(_target(6, f"GPU: 1920x1080 shadow rays >= 4 Grays/s, the renderer's shadow pass ({where})",
                       pass_grays, 4.0, "Grays/s", True,
                       note_gpu or "rays traced / shadow pass GPU ms, frames back to back"))
    out.append(_target(6, "GPU: 1920x1080 AO rays >= 1.5 Grays/s", ao / 1e3 if ao else None, 1.5, "Grays/s", True,
                       note_gpu))
    frame_ms = None
    for fr in results.get("frame", []):
        if gpu_device and fr["size"] == [1920, 1080] and fr["scene"] == "default-1light":
            frame_ms = fr.get("viewer_gpu_total_ms", fr["gpu_total_ms"])
    out.append(_target(6, "GPU: full 1920x1080 frame <= 2 ms GPU (1 light, hard shadows, 1 AO ray, denoise)",
                       frame_ms, 2.0, "ms", False, note_gpu or "frames back to back, no readback (the viewer's)"))
    for fr in results.get("frame", []):
        if fr["scene"] == "default":
            out.append(_target(6, "host (Python) CPU time per frame <= 0.3 ms (Renderer.submit, static scene)",
                               fr["submit_host_cpu_ms"], 0.3, "ms", False,
                               "submit() without readback; a viewer adds swapchain acquire/present"))
    return out


# ---------------------------------------------------------------------------------------------------------------
# terminal tables


def _fmt(v, spec=".2f", none="-"):
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return none
    return format(v, spec)


def _table(rows, header, align=None) -> str:
    cols = len(header)
    width = [max(len(str(r[i])) for r in [header] + rows) for i in range(cols)]
    align = align or ["<"] + [">"] * (cols - 1)
    line = lambda r: "  ".join(f"{str(c):{a}{w}}" for c, a, w in zip(r, align, width))  # noqa: E731
    return "\n".join([line(header), "  ".join("-" * w for w in width)] + [line(r) for r in rows])


def format_report(results: dict) -> str:
    meta = results.get("meta", {})
    m, dev = meta.get("machine", {}), meta.get("device", {})
    parts = [f"hybrid bench - {meta.get('date', '')}",
             f"machine: {m.get('cpu')} ({m.get('cores')} cores), device: {dev.get('name', '-')} "
             f"({dev.get('type', '-')}, {dev.get('driver_info', dev.get('driver', '-'))})"
             + (f", env {m['env']}" if m.get("env") else "")]
    o = meta.get("other_processes", {})
    if "others_cpu_s" in o:
        parts.append(f"run: {o['wall_s']} s wall, this process {o['own_cpu_s']} CPU s; other processes used "
                     f"{o['others_cpu_s']} CPU s (on average {o['others_mean_cores']} of {m.get('cores')} cores)")
    if results.get("build"):
        rows = [[f"{b['triangles']:,}", _fmt(b["ms"], ".0f"), _fmt(b["ms_per_million"], ".0f"),
                 _fmt(b.get("ms_1thread"), ".0f"), _fmt(b["sah_cost"], ".1f"), _fmt(b["bytes_per_triangle"], ".1f"),
                 f"{b['nodes']:,}", b["depth"]]
                for b in results["build"]]
        threads = results["build"][0].get("threads", "?")
        parts += ["", f"BVH build (generated meshes; median of runs; {threads} threads, and 1 for comparison)",
                  _table(rows, ["triangles", "build ms", "ms / M tris", "1 thread ms", "SAH cost", "bytes / tri",
                                "nodes", "depth"])]
    for sc in results.get("trace", {}).get("scenes", []):
        setup = ", ".join(f"{k} {v:.0f} ms" for k, v in sc["setup_ms"].items())
        skipped = ", ".join(f"{k}: {v['skipped']}" for k, v in sc["engines"].items() if "skipped" in v)
        parts += ["", f"Trace throughput, Mrays/s: {sc['scene']} scene ({sc['triangles']:,} triangles), "
                      f"G-buffer {sc['gbuffer_size'][0]}x{sc['gbuffer_size'][1]}; setup (BVH build): {setup}"
                  + (f"; skipped {skipped}" if skipped else "")]
        rows = []
        for rs in sc["raysets"]:
            res = rs["results"]
            o = res.get("ours", {})
            row = [rs["title"], f"{rs['rays']:,}", _fmt(o.get("mrays_gpu")), _fmt(o.get("mrays_wall")),
                   _fmt(o.get("gpu_fraction_of_wall"), ".0%")]
            for p in PEERS:
                pr = res.get(p)
                row.append(_fmt(pr["mrays_wall"]) if pr else "-")
            for p in PEERS:
                ra = rs["ratio"].get(p)
                row.append(f"{_fmt(ra['gpu'])} / {_fmt(ra['wall'])}" if ra else "-")
            agree = [f"{p} {rs['agreement'][p]['hit_miss']:.2%}" for p in PEERS if p in rs["agreement"]]
            row.append(", ".join(agree) or "-")
            rows.append(row)
        parts.append(_table(rows, ["ray set", "rays", "ours GPU", "ours wall", "GPU/wall", "embreex 1T",
                                   "open3d", "x embreex (GPU/wall)", "x open3d (GPU/wall)", "hit/miss agree"]))
        bad = [rs["name"] for rs in sc["raysets"]
               if rs["results"].get("ours", {}).get("timestamps_plausible") is False]
        if bad:
            parts.append(f"warning: GPU timestamps disagree with the submit+wait time for {', '.join(bad)}; "
                         "see queue_ms in the JSON")
    probe = results.get("trace", {}).get("lavapipe_threads")
    if probe:
        rows = []
        for p in probe:
            if "error" in p:
                rows.append([p["threads"], p["error"], "", ""])
                continue
            rows.append([p["threads"]] + [f"{_fmt(p[n]['mrays_gpu'])} / {_fmt(p[n]['mrays_wall'])}" if n in p
                                          else "-" for n in RAYSETS])
        parts += ["", f"Our tracer vs lavapipe worker threads ({probe[0].get('scene', '')} scene, same rays; "
                      "Mrays/s GPU / wall)", _table(rows, ["LP_NUM_THREADS"] + [f"{n} rays" for n in RAYSETS])]
    for fr in results.get("frame", []):
        viewer = fr.get("viewer_passes_ms", {})
        rows = [[k, _fmt(v, ".2f"), _fmt(viewer.get(k), ".2f")] for k, v in fr["passes_ms"].items()]
        if fr.get("shadow_pass_grays"):
            rows.append([f"shadow pass Grays/s ({fr['shadow_rays']:,} rays)", _fmt(fr["shadow_pass_grays"], ".3f"),
                         _fmt(fr.get("viewer_shadow_pass_grays"), ".3f")])
        rows += [["total GPU", _fmt(fr["gpu_total_ms"], ".2f"), _fmt(fr.get("viewer_gpu_total_ms"), ".2f")],
                 ["render() wall (incl. readback to numpy)", _fmt(fr["render_wall_ms"], ".2f")],
                 ["submit() host wall / CPU (viewer path)",
                  f"{_fmt(fr['submit_host_ms'], '.3f')} / {_fmt(fr['submit_host_cpu_ms'], '.3f')}"]]
        rows = [row + [""] * (3 - len(row)) for row in rows]
        s = fr["settings"]
        parts += ["", f"Frame: {fr['scene']} scene ({fr['triangles']:,} triangles) {fr['size'][0]}x{fr['size'][1]}, "
                      f"{fr['lights']} light(s), shadows {s.get('shadows')}, AO {s.get('ao_samples')} spp "
                      f"(median of runs)", _table(rows, ["pass", "render() ms", "back to back ms"])]
    if results.get("targets"):
        rows = [[f"#{t['issue']}", t["target"], _fmt(t["measured"], ".3g") + (f" {t['unit']}" if t["measured"]
                 is not None else ""), t.get("summary", t["status"])
                 + (f"; {t['note']}" if t.get("note") else "")] for t in results["targets"]]
        parts += ["", "Targets", _table(rows, ["issue", "target", "measured", "status"], ["<", "<", ">", "<"])]
    return "\n".join(parts)


# ---------------------------------------------------------------------------------------------------------------
# plot (pillow)


ENGINE_COLORS = {"ours GPU": (46, 117, 182), "ours wall": (143, 187, 227), "embreex": (230, 126, 34),
                 "open3d": (68, 160, 80)}
PASS_COLORS = [(46, 117, 182), (230, 126, 34), (68, 160, 80), (192, 57, 43), (142, 68, 173), (127, 140, 141),
               (241, 196, 15), (22, 160, 133)]


def _font(size, bold=False):
    from PIL import ImageFont
    for name in (("DejaVuSans-Bold.ttf" if bold else "DejaVuSans.ttf"),
                 "/usr/share/fonts/truetype/dejavu/" + ("DejaVuSans-Bold.ttf" if bold else "DejaVuSans.ttf")):
        try:
            return ImageFont.truetype(name, size)
        except OSError:
            pass
    try:
        return ImageFont.load_default(size=size)
    except TypeError:
        return ImageFont.load_default()


def _nice_max(v):
    if v <= 0:
        return 1.0
    e = 10 ** np.floor(np.log10(v))
    for m in (1, 1.5, 2, 2.5, 3, 4, 5, 6, 8, 10):
        if m * e >= v:
            return m * e
    return 10 * e


def _bar_panel(draw, box, title, groups, series, colors, unit, fonts, hlines=()):
    """Grouped vertical bars. groups: [(label, {series: value})]; hlines: [(value, label)] goal lines."""
    x0, y0, x1, y1 = box
    f_title, f_label, f_small = fonts
    draw.text((x0, y0), title, fill=(0, 0, 0), font=f_title)
    lx = x0
    for s in series:   # legend under the title
        draw.rectangle([lx, y0 + 34, lx + 14, y0 + 48], fill=colors[s])
        draw.text((lx + 20, y0 + 41), s, fill=(0, 0, 0), font=f_small, anchor="lm")
        lx += 34 + draw.textlength(s, font=f_small)
    top, bottom, left = y0 + 92, y1 - 50, x0 + 64
    draw.text((x0, y0 + 62), unit, fill=(80, 80, 80), font=f_small)
    values = [v for _, vals in groups for v in vals.values() if v] + [v for v, _ in hlines]
    vmax = _nice_max(max(values + [1e-9]) * 1.12)
    for i in range(6):
        val = vmax * i / 5
        y = bottom - (bottom - top) * i / 5
        draw.line([(left, y), (x1, y)], fill=(225, 225, 225))
        draw.text((left - 8, y), f"{val:g}", fill=(80, 80, 80), font=f_small, anchor="rm")
    gw = (x1 - left) / max(len(groups), 1)
    for gi, (label, vals) in enumerate(groups):
        bw = min(70, (gw - 30) / max(len(series), 1))
        gx = left + gi * gw + (gw - bw * len(series)) / 2
        for si, s in enumerate(series):
            v = vals.get(s)
            if not v:
                if s in vals:   # measured as nothing: say so
                    draw.text((gx + si * bw + bw / 2, bottom - 3), "n/a", fill=(120, 120, 120), font=f_small,
                              anchor="md")
                continue
            bx = gx + si * bw
            by = bottom - (bottom - top) * v / vmax
            draw.rectangle([bx + 2, by, bx + bw - 2, bottom], fill=colors[s])
            draw.text((bx + bw / 2, by - 3), f"{v:.3g}", fill=(0, 0, 0), font=f_small, anchor="md")
        for li, text in enumerate(label.split("\n")):
            draw.text((left + gi * gw + gw / 2, bottom + 8 + li * 19), text, fill=(0, 0, 0), font=f_label, anchor="ma")
    for v, text in hlines:
        y = bottom - (bottom - top) * v / vmax
        for xx in range(int(left), int(x1), 14):
            draw.line([(xx, y), (min(xx + 8, x1), y)], fill=(192, 57, 43), width=2)
        draw.text((x1 - 4, y - 3), text, fill=(192, 57, 43), font=f_small, anchor="rd")
    draw.line([(left, bottom), (x1, bottom)], fill=(0, 0, 0))


def _stack_panel(draw, box, title, rows, fonts, totals=None):
    """Horizontal stacked bars of GPU ms per pass. rows: [(label, {pass: ms})]."""
    x0, y0, x1, y1 = box
    f_title, f_label, f_small = fonts
    draw.text((x0, y0), title, fill=(0, 0, 0), font=f_title)
    passes = []
    for _, d in rows:
        passes += [p for p in d if p not in passes]
    colors = {p: PASS_COLORS[i % len(PASS_COLORS)] for i, p in enumerate(passes)}
    lx = x0 + 250
    for p in passes:
        draw.rectangle([lx, y0 + 34, lx + 14, y0 + 48], fill=colors[p])
        draw.text((lx + 20, y0 + 41), p, fill=(0, 0, 0), font=f_small, anchor="lm")
        lx += 30 + draw.textlength(p, font=f_small)
    left, right = x0 + 250, x1 - 110
    vmax = _nice_max(max([sum(d.values()) for _, d in rows] + [1e-9]))
    top = y0 + 66
    rh = min(56, (y1 - top - 30) / max(len(rows), 1))
    for i in range(6):
        x = left + (right - left) * i / 5
        draw.line([(x, top), (x, top + rh * len(rows))], fill=(225, 225, 225))
        draw.text((x, top + rh * len(rows) + 6), f"{vmax * i / 5:g}", fill=(80, 80, 80), font=f_small, anchor="ma")
    draw.text((right + 30, top + rh * len(rows) + 6), "GPU ms", fill=(80, 80, 80), font=f_small)
    for ri, (label, d) in enumerate(rows):
        y = top + ri * rh
        for li, text in enumerate(label.split("\n")):
            draw.text((x0, y + 6 + li * 18), text, fill=(0, 0, 0), font=f_label)
        x = left
        for p in passes:
            v = d.get(p, 0.0)
            w = (right - left) * v / vmax
            if w > 0:
                draw.rectangle([x, y + 6, x + w, y + rh - 8], fill=colors[p])
                if w > 44:
                    draw.text((x + w / 2, y + rh / 2 - 1), f"{v:.1f}", fill=(255, 255, 255), font=f_small,
                              anchor="mm")
            x += w
        total = totals[ri] if totals else sum(d.values())
        draw.text((x + 6, y + rh / 2 - 1), f"{total:.1f} ms", fill=(0, 0, 0), font=f_small, anchor="lm")


def plot(results: dict, path):
    """A PNG: Mrays/s per ray set and engine for each trace scene, the per-pass frame breakdown, BVH build."""
    from PIL import Image, ImageDraw
    scenes = results.get("trace", {}).get("scenes", [])
    frames = results.get("frame", [])
    builds = results.get("build", [])
    W = 1400
    heights = [430] * len(scenes) + ([110 + 60 * len(frames)] if frames else []) + ([360] if builds else [])
    H = 90 + sum(heights) + 30 * len(heights)
    img = Image.new("RGB", (W, H), "white")
    d = ImageDraw.Draw(img)
    fonts = (_font(22, True), _font(16), _font(14))
    meta = results.get("meta", {})
    dev, m = meta.get("device", {}), meta.get("machine", {})
    d.text((30, 18), "hybrid bench", fill=(0, 0, 0), font=_font(28, True))
    d.text((30, 56), f"{meta.get('date', '')[:10]}   {m.get('cpu', '')} ({m.get('cores')} cores)   device: "
                     f"{dev.get('name', '-')} {dev.get('driver_info', '')}"
                     + (f"   other processes: {meta['other_processes']['others_mean_cores']} cores on average"
                        if meta.get("other_processes", {}).get("others_mean_cores") is not None else ""),
           fill=(60, 60, 60), font=fonts[2])
    y = 90
    for sc, h in zip(scenes, heights):
        eng = sc["engines"]
        names = {"ours GPU": "ours (GPU timestamps)", "ours wall": "ours (wall clock, upload + readback)",
                 "embreex": f"embreex ({eng.get('embreex', {}).get('threads') or 1} thread, wall)",
                 "open3d": f"Open3D ({eng.get('open3d', {}).get('threads') or '?'} threads, wall)"}
        groups = []
        for rs in sc["raysets"]:
            r = rs["results"]
            vals = {names["ours GPU"]: r.get("ours", {}).get("mrays_gpu"),
                    names["ours wall"]: r.get("ours", {}).get("mrays_wall")}
            for p in PEERS:
                if p in r:
                    vals[names[p]] = r[p]["mrays_wall"]
            groups.append((f"{rs['title']}\n{rs['rays']:,} rays", vals))
        series = [names[k] for k in ("ours GPU", "ours wall") + PEERS if k in ("ours GPU", "ours wall") or k in eng]
        colors = {names[k]: ENGINE_COLORS[k] for k in names}
        _bar_panel(d, (30, y, W - 30, y + h), f"Trace throughput, {sc['scene']} scene ({sc['triangles']:,} "
                   f"triangles), same rays for every engine", groups, series, colors, "Mrays/s (higher is better)",
                   fonts)
        y += h + 30
    if frames:
        h = heights[len(scenes)]
        rows = [(f"{fr['scene']} ({fr['triangles']:,} tris)\n{fr['size'][0]}x{fr['size'][1]}, {fr['lights']} light"
                 f"{'s' if fr['lights'] != 1 else ''}, AO {fr['settings'].get('ao_samples')} spp", fr["passes_ms"]) for fr in frames]
        _stack_panel(d, (30, y, W - 30, y + h), "Frame: GPU ms per pass (median of each pass; total: median of "
                     "frame totals)", rows, fonts, totals=[fr["gpu_total_ms"] for fr in frames])
        y += h + 30
    if builds:
        h = heights[-1]
        groups = [(f"{b['triangles'] / 1e6:.2g}M triangles\nSAH {b['sah_cost']:.0f}, {b['bytes_per_triangle']:.0f} B/tri",
                   {"s per M triangles": b["s_per_million"]}) for b in builds]
        _bar_panel(d, (30, y, W - 30, y + h), "BVH build: seconds per million triangles (goal: <= 1.0 issue 3, "
                   "<= 0.5 issue 6)", groups, ["s per M triangles"], {"s per M triangles": (46, 117, 182)},
                   "s / M triangles (lower is better)", fonts,
                   hlines=[(1.0, "issue 3 goal 1.0"), (0.5, "issue 6 goal 0.5")])
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    img.save(path)
    return path


# ---------------------------------------------------------------------------------------------------------------
# entry points


def check_output_paths(json_path=None, plot_path=None):
    """Before a run: the JSON and plot paths can be written (their folders are made), the plot is a .png."""
    for what, path in (("--json", json_path), ("--plot", plot_path)):
        if path is None:
            continue
        p = Path(path)
        if what == "--plot" and p.suffix.lower() != ".png":
            raise ConfigError(f"{what} {p}: the plot is a PNG: give a path ending in .png")
        if p.is_dir():
            raise ConfigError(f"{what} {p}: is a folder, not a file")
        try:
            p.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ConfigError(f"{what} {p}: cannot make its folder: {exc.strerror or exc}") from None
        if not os.access(p.parent, os.W_OK) or (p.exists() and not os.access(p, os.W_OK)):
            raise ConfigError(f"{what} {p}: not writable")


def write_outputs(results: dict, json_path=None, plot_path=None):
    """Write the JSON and the plot; a failure (a full disk) is one clear error."""
    try:
        if json_path is not None:
            Path(json_path).write_text(json.dumps(results, indent=1, default=_json_default) + "\n")
        if plot_path is not None:
            plot(results, plot_path)
    except (OSError, ValueError) as exc:
        raise EngineError(f"cannot write the results ({json_path}, {plot_path}): {exc}") from None


def run_bench(cfg: BenchConfig, json_path=None, plot_path=None, progress: bool = True, stream=None) -> dict:
    """Run the configured sections; write JSON and the plot when paths are given; return the results dict."""
    check_output_paths(json_path, plot_path)
    bench = Bench(cfg)
    bench.progress = Progress(bench.plan(), stream=stream, enabled=progress)
    results = bench.run()
    bench.progress.finish()
    write_outputs(results, json_path, plot_path)
    return results


def _json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def add_arguments(p):
    """The `hybrid bench` arguments (engine/cli.py adds the subparser)."""
    p.add_argument("section", nargs="?", default="all", choices=SECTIONS + ("all",),
                   help="what to run (default all)")
    p.add_argument("--quick", action="store_true",
                   help="smaller and fewer runs (no 4M build; ~1 minute on 2 cores, the full run ~2)")
    p.add_argument("--json", default="bench-out/bench.json", help="JSON results (default bench-out/bench.json)")
    p.add_argument("--plot", default="bench-out/bench.png", help="PNG plot (default bench-out/bench.png)")
    p.add_argument("--device", default=None, help="Vulkan device index or name substring")
    p.add_argument("--size", default=None,
                   help="frame and G-buffer size WxH (default 640x360 on a CPU device, 1920x1080 on a GPU)")


def run_cli(args) -> int:
    from .settings import parse_size
    size = parse_size(args.size) if args.size else None
    cfg = BenchConfig.for_cli(args.section, quick=args.quick, size=size, device=args.device)
    check_output_paths(args.json, args.plot)   # before minutes of work
    if args.device is not None:                # a device that does not exist fails now, whatever the section
        from .vk import choose_device, describe_devices
        choose_device(describe_devices(), args.device)
    results = run_bench(cfg)                   # the files are written below, after the report
    print(format_report(results))              # on the terminal first: a failed write below loses nothing
    write_outputs(results, args.json, args.plot)
    print(f"\nJSON: {args.json}   plot: {args.plot}")
    errors = results["meta"].get("validation_errors") or []
    if errors:
        print(f"error: {len(errors)} validation errors; first: {errors[0]}", file=sys.stderr)
        return 1
    return 0


def _probe_main(path, reps, warmup, device=None) -> dict:
    """Child process of the lavapipe thread probe: our Mrays/s (GPU timestamps and wall) on saved ray sets."""
    data = np.load(path)
    eng = OursEngine(data["vertices"], data["faces"].astype(np.int64), device=device)
    try:
        out = {}
        for name in RAYSETS:
            if f"{name}_o" not in data:
                continue
            kind, tmax = (str(x) for x in data[f"{name}_meta"])
            rs = RaySet(name, kind, data[f"{name}_o"], data[f"{name}_d"], float(tmax))
            gpu = []

            def once():
                r = eng.query(rs)
                gpu.append(eng.last_gpu_ms)
                return r
            wall, _, _ = _timed(once, reps, warmup)
            g = _median(gpu[warmup:])
            out[name] = {"rays": len(rs), "gpu_ms": g, "wall_ms": wall * 1e3, "mrays_gpu": len(rs) / g / 1e3,
                         "mrays_wall": len(rs) / wall / 1e6}
        return out
    finally:
        eng.close()


if __name__ == "__main__":
    if len(sys.argv) >= 5 and sys.argv[1] == "--probe":
        print(json.dumps(_probe_main(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]),
                                     sys.argv[5] if len(sys.argv) > 5 else None)))
