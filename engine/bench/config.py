"""What `hybrid bench` runs: the sections, engines and ray sets it knows, and BenchConfig (sizes, repetitions)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ..data import SCENES_DIR
from ..errors import ConfigError

REPO = Path(__file__).resolve().parents[2]  # the folder holding the engine package (the probe's working folder)
DEFAULT_SCENE = SCENES_DIR / "default.toml"
SECTIONS = ("build", "trace", "frame", "start")
PEERS = ("embreex", "open3d", "mitsuba", "mitsuba_device")
ENGINES = ("ours",) + PEERS
RAYSETS = ("shadow", "ao", "random", "scattered")
RAYSET_TITLES = {
    "shadow": "shadow rays (occluded, G-buffer)",
    "ao": "AO rays (occluded, G-buffer)",
    "random": "random rays (closest hit)",
    "scattered": "shadow rays (occluded, random surface points, random order)",
}


#: The mesh kinds of the build section (engine/bench/scenes.py build_mesh): the generated scene's mesh (terrain,
#: lumpy spheres, boxes), a field of separate subdivided spheres, one scan-like closed surface.
BUILD_KINDS = ("generated", "spheres", "scan")


#: The AOVs of the dataset figures (the headless-data target of issue 16).
DATASET_AOVS = ("color", "depth", "normal", "object_id")

#: The settings of the frame with every real-time effect on (issue 33's 1080p frame).
HYBRID_EFFECTS = {"reflections": True, "gi": True, "transparency": True, "taa": True}


@dataclass
class BenchConfig:
    sections: tuple = SECTIONS
    quick: bool = False
    size: tuple | None = None  # (w, h); None: 640x360 on a CPU device, 1920x1080 on a GPU
    device: str | None = None
    validation: bool = False
    build_sizes: tuple = (100_000, 1_000_000, 4_000_000)
    build_kinds: tuple = BUILD_KINDS  # every kind is built at every size
    build_reps: int = 3  # sizes above 2M triangles get one run less (at least one)
    generated_tris: int = 1_200_000  # the trace benchmark's generated scene
    mid_tris: int = 300_000  # frame "generated-300k": the size the issue-6 shadow target names
    real_scene: str | None = str(DEFAULT_SCENE)
    # the frame section's scenes; target: the issue-6 frame (1 light, 1 AO ray per pixel); reflect, gi: the real one
    # with reflections, with diffuse GI on; hybrid: with HYBRID_EFFECTS; distorted, fisheye: the real one through
    # traced lens cameras; mid: generated, mid_tris, 1 AO ray
    frame_scenes: tuple = ("real", "reflect", "gi", "hybrid", "distorted", "fisheye", "target", "mid", "generated")
    peers: tuple = PEERS
    reps: int = 7
    warmup: int = 1
    frame_reps: int = 5
    dataset_frames: int = 200  # render_many's frames in the frame section's dataset figures
    frame_warmup: int = 2
    start_reps: int = 5  # fresh processes per start-up figure (after one warm-up each)
    random_rays: int | None = None  # None: as many as the G-buffer has pixels
    thread_probe: bool = True  # lavapipe only: re-run the default scene's rays with LP_NUM_THREADS
    frontends: bool = True  # the trace section's front ends (engine/bench/frontends.py) on an icosphere
    frontend_subdivisions: int = 6  # 81,920 triangles (issue 35's sphere)
    frontend_points: int = 50_000  # points of the distance queries (the rays: random_rays, else 230,400)
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
            cfg.dataset_frames = 40
            cfg.frame_warmup = 1
            cfg.start_reps = 3
            cfg.thread_probe = False
            cfg.frontend_points = 20_000
        return cfg
