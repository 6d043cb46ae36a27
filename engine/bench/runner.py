"""Runs the sections of a BenchConfig: BVH builds, trace throughput of ours and the peers on the same rays, and frames
per pass; `Bench.run()` returns the results dict that becomes the JSON."""

from __future__ import annotations

import copy
import datetime as _dt
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from ..bvh import build_bvh
from ..errors import ConfigError
from ..passes.interface import AOVS
from ..renderer import Renderer
from ..scene import Camera, Scene
from ..vk import choose_device, describe_devices
from ..vk.device_info import device_details
from ..vk.sync import create_fence, destroy_fence, reset_fences, wait_fences
from .config import DATASET_AOVS, HYBRID_EFFECTS, RAYSET_TITLES, RAYSETS, REPO, BenchConfig
from .engines import OursEngine
from .frontends import ENGINES as FRONTEND_ENGINES
from .frontends import QUERIES as FRONTEND_QUERIES
from .frontends import run_frontends
from .machine import OtherLoad, machine_info
from .peers import agreement, make_peer
from .progress import Progress
from .rays import RaySet, first_light_rays, gbuffer_raysets, random_rayset, scattered_rayset, scene_diag
from .scenes import build_mesh, generated_scene
from .start import run_start
from .targets import evaluate_targets
from .timing import median
from .transfer import CopyPeer

CLOCK_WARMUP_S = 0.4  # seconds of back-to-back queries before a GPU engine's timed runs (see raise_clocks)


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
            n += len(cfg.build_sizes) * len(cfg.build_kinds)
        if "trace" in cfg.sections:
            per_scene = 2 + len(cfg.peers) + len(RAYSETS) * (2 + len(cfg.peers))
            n += per_scene * (1 + (cfg.real_scene is not None)) + self._probe_wanted()
            n += (len(FRONTEND_ENGINES) + len(FRONTEND_QUERIES)) * cfg.frontends
        if "frame" in cfg.sections:
            n += 2 * len(self._frame_scene_keys())
        if "start" in cfg.sections:
            n += 1
        return n

    def _frame_scene_keys(self):
        return [k for k in self.cfg.frame_scenes if k in ("generated", "mid") or self.cfg.real_scene is not None]

    def device_choice(self):
        devices = describe_devices()
        return devices[choose_device(devices, self.cfg.device)]

    def size(self) -> tuple[int, int]:
        if self.cfg.size is not None:
            return tuple(self.cfg.size)
        return (640, 360) if self.device_choice()["type"] == "CPU" else (1920, 1080)

    def renderer(self):
        if self._renderer is None:
            w, h = self.size()
            self._renderer = Renderer(w, h, device=self.cfg.device, validation=self.cfg.validation)
        return self._renderer

    def scene(self, key):
        if key not in self._scenes:
            if key in ("generated", "mid"):
                tris = self.cfg.generated_tris if key == "generated" else self.cfg.mid_tris
                self._scenes[key] = generated_scene(tris, seed=self.cfg.seed)
            elif key == "real":
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
            "command": " ".join(["hybrid"] + sys.argv[1:])
            if Path(sys.argv[0]).name in ("hybrid", "__main__.py")
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
            if "start" in cfg.sections:
                self.results["start"] = self._step("start-up (fresh processes)", run_start, cfg.start_reps, cfg.device)
        finally:
            self.close()
        self.results["meta"]["validation_errors"] = (self.validation_errors + self.tracer_validation_errors)[:20]
        self.results["meta"]["load_average_end"] = machine_info()["load_average"]
        self.results["meta"]["other_processes"] = other.result()
        self.results["targets"] = evaluate_targets(self.results)
        return self.results

    def run_build(self) -> list[dict]:
        """Every kind at every size, the kinds of one size one after the other (the same moment of the machine)."""
        out = []
        for n in self.cfg.build_sizes:
            reps = max(1, self.cfg.build_reps - (1 if n > 2_000_000 else 0))
            for kind in self.cfg.build_kinds:
                out.append(
                    self._step(f"build: BVH of {n / 1e6:g}M triangles, {kind} x{reps}", self._build_one, kind, n, reps)
                )
        return out

    def _build_one(self, kind, n, reps) -> dict:
        v, f = build_mesh(kind, n, seed=self.cfg.seed)
        # one untimed build first, as the trace's warm-up runs and benchmarks/ab_build.py do: the first build after
        # a mesh is made also grows the heap to its size (its time is kept as cold_ms)
        t0 = time.perf_counter()
        build_bvh(v, f)
        cold = (time.perf_counter() - t0) * 1e3
        runs, runs1, cpu, stats = [], [], [], None
        for _ in range(reps):  # all cores (the default, which the targets are judged on), then one
            for threads, into in ((None, runs), (1, runs1)):
                c0, t0 = time.process_time(), time.perf_counter()
                bvh = build_bvh(v, f, threads=threads)
                into.append((time.perf_counter() - t0) * 1e3)
                if threads is None:
                    cpu.append((time.process_time() - c0) * 1e3)
                    stats = dict(bvh.stats)
                del bvh
        ms = median(runs)
        tris = int(len(f))
        return {
            "kind": kind,
            "triangles": tris,
            "requested": n,
            "ms": ms,
            "runs_ms": runs,
            "cold_ms": cold,
            "cpu_ms": median(cpu),
            "runs_cpu_ms": cpu,
            "threads": stats["threads"],
            "ms_1thread": median(runs1),
            "runs_ms_1thread": runs1,
            "ms_per_million": ms / (tris / 1e6),
            "s_per_million": ms / 1e3 / (tris / 1e6),
            "sah_cost": stats.get("sah_cost"),
            "bytes": stats.get("bytes"),
            "bytes_per_triangle": stats["bytes"] / tris if stats.get("bytes") else None,
            "nodes": stats.get("nodes"),
            "leaves": stats.get("leaves"),
            "depth": stats.get("depth"),
            "stats": stats,
        }

    def run_trace(self) -> dict:
        keys = ["generated"] + (["real"] if self.cfg.real_scene is not None else [])
        out = {"scenes": [self._trace_scene(k) for k in keys]}
        if self.cfg.frontends:
            out["frontends"] = run_frontends(self.cfg, self._step)
            self.tracer_validation_errors += out["frontends"]["validation_errors"]
        if self._probe_wanted():
            out["lavapipe_threads"] = self._step(
                "trace (default): lavapipe threads, LP_NUM_THREADS = " + ", ".join(map(str, self._probe_threads())),
                self._thread_probe,
            )
        return out

    def _probe_wanted(self) -> bool:
        cfg = self.cfg
        return bool(cfg.thread_probe and "trace" in cfg.sections and "llvmpipe" in self.device_choice()["name"].lower())

    def _probe_threads(self):
        cores = os.cpu_count() or 1
        return sorted({1, cores, 2 * cores})

    def _thread_probe(self) -> list[dict]:
        """The last trace scene's ray sets again, in child processes with LP_NUM_THREADS set: how our tracer scales
        with lavapipe's worker threads (lavapipe reads the variable once, when the driver loads)."""
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
                cmd = [
                    sys.executable,
                    "-m",
                    "engine.bench.probe",
                    str(path),
                    str(self.cfg.reps),
                    str(self.cfg.warmup),
                ] + ([str(self.cfg.device)] if self.cfg.device is not None else [])
                proc = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=str(REPO), timeout=600)
                if proc.returncode != 0:
                    out.append({"threads": threads, "error": (proc.stderr.strip().splitlines() or ["?"])[-1]})
                    continue
                out.append(
                    {
                        "threads": threads,
                        "scene": "default" if scene is self._scenes.get("real") else "generated",
                        **json.loads(proc.stdout.strip().splitlines()[-1]),
                    }
                )
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
            sets.append(scattered_rayset(scene, len(sets[0]), rng))  # as many as the G-buffer's shadow rays
            return scene, frame, sets

        scene, frame, sets = self._step(f"trace ({tag}): scene, G-buffer, rays", prepare)
        diag = scene_diag(scene)
        v = np.asarray(scene.positions, np.float32)
        f = np.asarray(scene.indices, np.int64)
        res = {
            "scene": tag,
            "name": scene.name,
            "triangles": scene.triangle_count,
            "diagonal": diag,
            "gbuffer_size": [self.renderer().width, self.renderer().height],
            "frame_timings_ms": dict(frame.timings),
            "setup_ms": {},
            "engines": {},
            "raysets": [],
        }
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
                    e, why = make_peer(name, v, f, built=engines)
                    if e is not None:
                        res["setup_ms"][name] = (time.perf_counter() - t0) * 1e3
                    return e, why

                e, why = self._step(f"trace ({tag}): {name} scene build", build_peer)
                if e is None:
                    res["engines"][name] = {"skipped": why}
                else:
                    engines[name] = e
                    res["engines"][name] = {"label": e.label, "threads": e.threads}
                    if getattr(e, "tried", None):  # Mitsuba: the variants tried before the one it runs, and why
                        res["engines"][name]["tried"] = list(e.tried)
            # the plain copy of each ray set's bytes, on our Tracer's device: what the bus allows
            engines["copy"] = CopyPeer(engines["ours"].tracer.ctx, max(len(rs) for rs in sets))
            for rs in sets:
                res["raysets"].append(self._trace_rayset(tag, rs, engines, diag))
            self._probe_input = (scene, sets)
        finally:
            for e in engines.values():
                if isinstance(e, OursEngine):
                    e.close()  # leaks show up at close, as validation errors
                    self.tracer_validation_errors += e.validation_errors
                else:
                    e.close()
        return res

    def _trace_rayset(self, tag, rs: RaySet, engines, diag) -> dict:
        cfg = self.cfg
        out = {
            "name": rs.name,
            "kind": rs.kind,
            "title": RAYSET_TITLES[rs.name],
            "rays": len(rs),
            "tmax": rs.tmax if np.isfinite(rs.tmax) else "inf",
            "note": rs.note,
            "results": {},
            "agreement": {},
            "ratio": {},
        }
        answers, gpu, walls = {}, {}, {}
        names = [name for name in ("ours",) + tuple(cfg.peers) if name in engines]

        def once(name):
            t0 = time.perf_counter()
            answers[name] = engines[name].query(rs)
            wall = time.perf_counter() - t0
            if name == "ours":
                gpu[name].append(engines[name].last_gpu_ms)
            return wall

        for name in names:  # untimed preparation (a peer's kernel compile) and warm-up runs, one engine at a time
            gpu[name], walls[name] = [], []

            def warm(name=name):
                engines[name].prepare(rs)
                for _ in range(cfg.warmup):
                    once(name)

            self._step(f"trace ({tag}): {RAYSET_TITLES[rs.name]} ({name}, warm-up)", warm)
            gpu[name].clear()

        copy_walls: list = []
        clock_warmup: dict = {}

        def raise_clocks(name):
            """Before an engine's timed runs: on a GPU, its query again and again for CLOCK_WARMUP_S (a GPU that
            idled while a CPU peer ran or the host prepared rays has lowered its clocks and ramps them back up only
            under sustained load); on a CPU device one run."""
            t0 = time.perf_counter()
            runs = 0
            while runs < 1 or (engines[name].on_gpu and time.perf_counter() - t0 < CLOCK_WARMUP_S):
                once(name)
                runs += 1
            gpu[name].clear()
            clock_warmup[name] = {"runs": runs, "s": time.perf_counter() - t0}

        def timed():
            # each engine's repeats back to back after raise_clocks: ours first, the plain copy of the same bytes
            # right after it; then each peer's
            for name in names:
                if name == "ours" or engines[name].on_gpu:
                    raise_clocks(name)
                for _ in range(max(cfg.reps, 1)):
                    walls[name].append(once(name))
                if name == "ours" and "copy" in engines:
                    copy = engines["copy"]
                    copy.run(rs.origins, rs.directions, np.full(len(rs), rs.tmax, np.float32), rs.kind)
                    for _ in range(max(cfg.reps, 1)):
                        copy.run(rs.origins, rs.directions, np.full(len(rs), rs.tmax, np.float32), rs.kind)
                        copy_walls.append(copy.last_wall_ms / 1e3)

        self._step(f"trace ({tag}): {RAYSET_TITLES[rs.name]} (timed runs, ours back to back)", timed)
        n = len(rs)
        out["clock_warmup"] = clock_warmup
        for name in names:
            wall = median(walls[name])
            r = {
                "wall_ms": wall * 1e3,
                "runs_wall_ms": [w * 1e3 for w in walls[name]],
                "mrays_wall": n / wall / 1e6 if wall > 0 else None,
            }
            if name == "ours":
                g = median(gpu[name])
                r.update(
                    gpu_ms=g,
                    runs_gpu_ms=gpu[name],
                    mrays_gpu=n / (g * 1e-3) / 1e6 if g > 0 else None,
                    host_ms=wall * 1e3 - g,
                    gpu_fraction_of_wall=g / (wall * 1e3),
                    # the chunks' trace timestamps add up to no more than the query's wall clock
                    timestamps_plausible=bool(0 < g <= 1.05 * wall * 1e3 + 0.05),
                )
            out["results"][name] = r
        if copy_walls and out["results"].get("ours"):
            cw = median(copy_walls)
            out["results"]["copy"] = {
                "wall_ms": cw * 1e3,
                "runs_wall_ms": [w * 1e3 for w in copy_walls],
                "mrays_wall": n / cw / 1e6 if cw > 0 else None,
                "bytes": n * (28 + (4 if rs.kind == "occluded" else 16)),
            }
            out["ratio"]["copy"] = {"wall": cw / median(walls["ours"])}
        ours = out["results"].get("ours")
        for name in cfg.peers:
            if name in out["results"] and ours:
                peer = out["results"][name]
                out["ratio"][name] = {
                    "gpu": ours["mrays_gpu"] / peer["mrays_wall"] if ours.get("mrays_gpu") else None,
                    "wall": ours["mrays_wall"] / peer["mrays_wall"],
                }
                out["agreement"][name] = agreement(rs.kind, answers["ours"], engines[name].answer(answers[name]), diag)
        return out

    def run_frame(self) -> list[dict]:
        out = []
        for key in self._frame_scene_keys():
            tag = {
                "generated": "generated",
                "real": "default",
                "reflect": "default-reflections",
                "gi": "default-gi",
                "hybrid": "default-hybrid",
                "distorted": "default-opencv-distorted",
                "fisheye": "default-fisheye",
                "target": "default-1light",
                "mid": f"generated-{self.cfg.mid_tris // 1000}k",
            }[key]
            settings = {"ao_samples": 1} if key in ("target", "mid") else {}
            if key == "reflect":  # the default frame plus ray-traced reflections (engine/passes/reflections.py)
                settings = {"reflections": True}
            if key == "gi":  # the default frame plus diffuse global illumination (engine/passes/gi.py)
                settings = {"gi": True}
            if key == "hybrid":  # every real-time effect on (issue 33's frame)
                settings = dict(HYBRID_EFFECTS)
            scene = self._step(f"frame ({tag}): load scene", self._frame_scene, key)
            out.append(self._step(f"frame ({tag}): render x{self.cfg.frame_reps}", self._frame, tag, scene, settings))
        return out

    def _dataset(self, r, scene, settings) -> dict:
        """Headless data: render() of DATASET_AOVS alone, and render_many over an orbit of cameras (frame N+1 on the
        GPU while N is read back): wall ms per frame against the GPU ms per frame, and the bytes read back."""
        cfg = self.cfg
        n = cfg.dataset_frames
        center = scene.center
        eye = np.asarray(scene.camera.eye, float)
        radius = float(np.linalg.norm((eye - center)[[0, 2]])) or 1.0
        cams = [
            Camera.look_at(
                center + [radius * math.sin(a), eye[1] - center[1], radius * math.cos(a)],
                center,
                fov_y=scene.camera.fov_y,
            )
            for a in np.linspace(0, 2 * math.pi, n, endpoint=False)
        ]
        for _ in range(2):
            r.render(scene, cams[0], aovs=DATASET_AOVS, **settings)
        walls = []
        for _ in range(max(cfg.frame_reps, 1)):
            t0 = time.perf_counter()
            r.render(scene, cams[0], aovs=DATASET_AOVS, **settings)
            walls.append((time.perf_counter() - t0) * 1e3)
        list(r.render_many(scene, cams[:4], aovs=DATASET_AOVS, **settings))  # warm: both slots recorded
        gpu = []
        t0 = time.perf_counter()
        for frame in r.render_many(scene, cams, aovs=DATASET_AOVS, **settings):
            gpu.append(sum(frame.timings.values()))
        wall = (time.perf_counter() - t0) * 1e3 / n
        buf, offsets = r.targets.readback(r.ctx, DATASET_AOVS, 0)
        pixels = r.width * r.height
        aov_bytes = sum(AOVS[name].bytes * pixels for name in DATASET_AOVS)
        return {
            "aovs": list(DATASET_AOVS),
            "frames": n,
            "render_wall_ms": median(walls),
            "runs_render_wall_ms": walls,
            "many_wall_ms_per_frame": wall,
            "many_fps": 1e3 / wall,
            "many_gpu_ms_per_frame": median(gpu),
            "many_wall_over_gpu": wall / median(gpu) if median(gpu) else None,
            "readback_bytes": int(buf.size),
            "aov_bytes": int(aov_bytes),
        }

    def _frame_scene(self, key):
        if key in ("reflect", "gi", "hybrid"):
            return self.scene("real")
        if key in ("distorted", "fisheye") and key not in self._scenes:
            self._scenes[key] = lens_scene(self.scene("real"), key, self.size())
        if key in ("distorted", "fisheye"):
            return self._scenes[key]
        if key != "target":
            return self.scene(key)
        if "target" not in self._scenes:  # the default scene with its first light only (a shallow copy)
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
        per_pass = {p: median([t.get(p, 0.0) for t in timings]) for p in passes}

        totals = [sum(t.values()) for t in timings]
        # The viewer's steady state: frames submitted as the viewer does, without readback, each as soon as the one
        # before it finished (one recorded command buffer, so one frame in flight), so the GPU idles only for the
        # host's submit (after a longer gap a GPU drops its clocks, so render() frames, each followed by a readback
        # to numpy, run every pass slower). GPU ms per pass of the last of each run of 4 frames.
        # warm-up: runs of 4 until half a second has passed (a GPU that idled while the host loaded the scene ramps
        # its clocks back up only under sustained load, which a few frames of a large scene do not give)
        fence = create_fence(r.ctx)
        try:
            warm_until, warmed = time.perf_counter() + 0.5, 0
            while warmed < 4 or time.perf_counter() < warm_until:
                viewer_frames(r, scene, settings, fence, 4)
                warmed += 4
            steady = []
            for _ in range(max(cfg.frame_reps, 1)):
                viewer_frames(r, scene, settings, fence, 4)
                steady.append(r.last_timings())
        finally:
            destroy_fence(r.ctx, fence)
        steady_passes = {p: median([t.get(p, 0.0) for t in steady]) for p in steady[-1]}
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
        shadow_rays = int(first_light_rays(scene, fr)[-1].sum()) if lights == 1 else 0

        def grays(ms):  # the shadow pass's rays per second (one light's rays; a frame of several lights traces more)
            return shadow_rays / (ms * 1e-3) / 1e9 if lights == 1 and ms and ms > 0 else None

        dataset = self._dataset(r, scene, settings) if tag == "default-1light" else None
        return {
            "dataset": dataset,
            "shadow_rays": shadow_rays,
            "shadow_pass_grays": grays(per_pass.get("shadows")),
            "viewer_shadow_pass_grays": grays(steady_passes.get("shadows")),
            "scene": tag,
            "name": scene.name,
            "triangles": scene.triangle_count,
            "size": [r.width, r.height],
            "lights": lights,
            "settings": dict(fr.settings),
            "passes_ms": per_pass,
            "gpu_total_ms": median(totals),
            "runs_gpu_total_ms": totals,
            "viewer_passes_ms": steady_passes,
            "viewer_gpu_total_ms": median(steady_totals),
            "runs_viewer_gpu_total_ms": steady_totals,
            "render_wall_ms": median(walls),
            "runs_render_wall_ms": walls,
            "submit_host_ms": median(host),
            "submit_host_cpu_ms": median(host_cpu),
            "submit_gpu_total_ms": median(sub_gpu),
        }


def viewer_frames(r: Renderer, scene: Scene, settings: dict, fence, n: int) -> None:
    """`n` frames through submit() the way the viewer submits them: each after the one before it finished."""
    for _ in range(n):
        r.submit(scene, wait=False, fence=fence, **settings)
        wait_fences(r.ctx, [fence])
        reset_fences(r.ctx, [fence])


def lens_scene(scene: Scene, model: str, size) -> Scene:
    """A shallow copy of `scene` seen through a lens camera of the same pose and focal length (its primary rays
    traced, engine/passes/camera_rays.py): OpenCV's distortion with a wide-angle lens's coefficients, or OpenCV's
    fisheye model; the frame section sets it beside the rasterized pinhole to give the lens's cost."""
    w, h = size
    cam = scene.camera
    K, pose = cam.intrinsics(w, h), cam.pose
    s = copy.copy(scene)
    if model == "distorted":
        s.camera = Camera.from_opencv(K, (-0.28, 0.08, 1e-3, -1e-3, -0.01), w, h, pose=pose)
    else:
        s.camera = Camera.fisheye(K, (0.08, -0.02, 0.004, -0.0005), w, h, pose=pose)
    return s
