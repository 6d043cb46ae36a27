"""A bench's results as text tables for the terminal, and as JSON."""

from __future__ import annotations

import json

import numpy as np

from ..files import atomic_write_text
from ..settings import DEFAULT_SETTINGS, ao_samples
from .config import PEERS, RAYSETS

#: The peers' column names in the trace table.
PEER_SHORT = {"embreex": "embreex 1T", "open3d": "open3d", "mitsuba": "mitsuba", "mitsuba_device": "mitsuba dev"}


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


def _frontends_report(fe) -> list[str]:
    """The front ends' table: wall ms per query and engine, and its speed as a multiple of Open3D's."""
    if not fe:
        return []
    queries = list(fe["queries"])
    rows = []
    for name, info in fe["engines"].items():
        if "skipped" in info:
            rows.append([info["label"], f"skipped: {info['skipped']}"] + [""] * (len(queries) - 1))
            continue
        label = info["label"] + (f" ({info['backend']})" if info.get("backend") and "auto" in info["label"] else "")
        row = [label]
        for q in queries:
            r = fe["queries"][q].get(name)
            row.append(f"{_fmt(r['wall_ms'], '.1f')} ({_fmt(r['x_open3d'])}x)" if r else "-")
        rows.append(row)
    agree = "; ".join(
        f"{q}: " + ", ".join(f"{k} {v:.2%}" for k, v in fe["queries"][q]["agreement"].items())
        for q in queries
        if "agreement" in fe["queries"][q]
    )
    return [
        "",
        f"Front ends: {fe['mesh']} ({fe['triangles']:,} triangles), {fe['rays']:,} random rays, {fe['points']:,} "
        "points; wall ms, numpy in and out (x Open3D's speed)",
        _table(rows, ["engine"] + queries),
        f"RaycastingScene (auto) answers as Open3D: {agree or '-'}",
    ]


def format_report(results: dict) -> str:
    meta = results.get("meta", {})
    m, dev = meta.get("machine", {}), meta.get("device", {})
    parts = [
        f"hybrid bench - {meta.get('date', '')}",
        f"machine: {m.get('cpu')} ({m.get('cores')} cores), device: {dev.get('name', '-')} "
        f"({dev.get('type', '-')}, {dev.get('driver_info', dev.get('driver', '-'))})"
        + (f", env {m['env']}" if m.get("env") else ""),
    ]
    o = meta.get("other_processes", {})
    if "others_cpu_s" in o:
        parts.append(
            f"run: {o['wall_s']} s wall, this process {o['own_cpu_s']} CPU s; other processes used "
            f"{o['others_cpu_s']} CPU s (on average {o['others_mean_cores']} of {m.get('cores')} cores)"
        )
    if results.get("build"):
        rows = [
            [
                b.get("kind", "generated"),
                f"{b['triangles']:,}",
                _fmt(b["ms"], ".0f"),
                _fmt(b["ms_per_million"], ".0f"),
                _fmt(b.get("cpu_ms"), ".0f"),
                _fmt(b.get("ms_1thread"), ".0f"),
                _fmt(b["sah_cost"], ".1f"),
                _fmt(b["bytes_per_triangle"], ".1f"),
                f"{b['nodes']:,}",
                b["depth"],
            ]
            for b in results["build"]
        ]
        threads = results["build"][0].get("threads", "?")
        parts += [
            "",
            f"BVH build (generated meshes of each kind; median of runs; {threads} threads, and 1 for "
            "comparison; CPU ms: this process, all threads)",
            _table(
                rows,
                [
                    "mesh",
                    "triangles",
                    "build ms",
                    "ms / M tris",
                    "CPU ms",
                    "1 thread ms",
                    "SAH cost",
                    "bytes / tri",
                    "nodes",
                    "depth",
                ],
            ),
        ]
    for sc in results.get("trace", {}).get("scenes", []):
        setup = ", ".join(f"{k} {v:.0f} ms" for k, v in sc["setup_ms"].items())
        skipped = ", ".join(f"{k}: {v['skipped']}" for k, v in sc["engines"].items() if "skipped" in v)
        parts += [
            "",
            f"Trace throughput, Mrays/s: {sc['scene']} scene ({sc['triangles']:,} triangles), "
            f"G-buffer {sc['gbuffer_size'][0]}x{sc['gbuffer_size'][1]}; setup (BVH build): {setup}"
            + (f"; skipped {skipped}" if skipped else ""),
        ]
        ran = [p for p in PEERS if p in sc["engines"] and "skipped" not in sc["engines"][p]]
        rows = []
        for rs in sc["raysets"]:
            res = rs["results"]
            o = res.get("ours", {})
            row = [
                rs["title"],
                f"{rs['rays']:,}",
                _fmt(o.get("mrays_gpu")),
                _fmt(o.get("mrays_wall")),
                _fmt(o.get("gpu_fraction_of_wall"), ".0%"),
            ]
            for p in ("copy",) + tuple(ran):
                pr = res.get(p)
                row.append(_fmt(pr["mrays_wall"]) if pr else "-")
            row.append(_fmt(rs["ratio"].get("copy", {}).get("wall")))
            for p in ran:
                ra = rs["ratio"].get(p)
                row.append(f"{_fmt(ra['gpu'])} / {_fmt(ra['wall'])}" if ra else "-")
            agree = [f"{PEER_SHORT[p]} {rs['agreement'][p]['hit_miss']:.2%}" for p in ran if p in rs["agreement"]]
            row.append(", ".join(agree) or "-")
            rows.append(row)
        parts.append(
            _table(
                rows,
                ["ray set", "rays", "ours GPU", "ours wall", "GPU/wall", "plain copy"]
                + [PEER_SHORT[p] for p in ran]
                + ["x copy (wall)"]
                + [f"x {PEER_SHORT[p]} (GPU/wall)" for p in ran]
                + ["hit/miss agree"],
            )
        )
        if ran:
            parts.append("peers: " + "; ".join(f"{PEER_SHORT[p]} = {sc['engines'][p]['label']}" for p in ran))
        parts.append(
            "(ours wall: numpy to numpy, streamed; plain copy: the same bytes host -> device -> host, in rays/s)"
        )
        bad = [rs["name"] for rs in sc["raysets"] if rs["results"].get("ours", {}).get("timestamps_plausible") is False]
        if bad:
            parts.append(f"warning: GPU timestamps add up to more than the wall clock for {', '.join(bad)}")
    parts += _frontends_report(results.get("trace", {}).get("frontends"))
    probe = results.get("trace", {}).get("lavapipe_threads")
    if probe:
        rows = []
        for p in probe:
            if "error" in p:
                rows.append([p["threads"], p["error"], "", ""])
                continue
            rows.append(
                [p["threads"]]
                + [f"{_fmt(p[n]['mrays_gpu'])} / {_fmt(p[n]['mrays_wall'])}" if n in p else "-" for n in RAYSETS]
            )
        parts += [
            "",
            f"Our tracer vs lavapipe worker threads ({probe[0].get('scene', '')} scene, same rays; Mrays/s GPU / wall)",
            _table(rows, ["LP_NUM_THREADS"] + [f"{n} rays" for n in RAYSETS]),
        ]
    for fr in results.get("frame", []):
        viewer = fr.get("viewer_passes_ms", {})
        rows = [[k, _fmt(v, ".2f"), _fmt(viewer.get(k), ".2f")] for k, v in fr["passes_ms"].items()]
        if fr.get("shadow_pass_grays"):
            rows.append(
                [
                    f"shadow pass Grays/s ({fr['shadow_rays']:,} rays)",
                    _fmt(fr["shadow_pass_grays"], ".3f"),
                    _fmt(fr.get("viewer_shadow_pass_grays"), ".3f"),
                ]
            )
        rows += [
            ["total GPU", _fmt(fr["gpu_total_ms"], ".2f"), _fmt(fr.get("viewer_gpu_total_ms"), ".2f")],
            ["render() wall (incl. readback to numpy)", _fmt(fr["render_wall_ms"], ".2f")],
            [
                "submit() host wall / CPU (viewer path)",
                f"{_fmt(fr['submit_host_ms'], '.3f')} / {_fmt(fr['submit_host_cpu_ms'], '.3f')}",
            ],
        ]
        ds = fr.get("dataset")
        if ds:
            what = " + ".join(ds["aovs"])
            rows += [
                [f"render() wall, {what} only", _fmt(ds["render_wall_ms"], ".2f")],
                [
                    f"render_many wall ms / frame ({ds['frames']} frames; frames/s)",
                    f"{_fmt(ds['many_wall_ms_per_frame'], '.2f')} ({_fmt(ds['many_fps'], '.0f')}/s)",
                ],
                [
                    "render_many GPU ms / frame; wall / GPU",
                    f"{_fmt(ds['many_gpu_ms_per_frame'], '.2f')}; {_fmt(ds['many_wall_over_gpu'], '.2f')}x",
                ],
                ["bytes read back / frame (the AOVs' bytes)", f"{ds['readback_bytes']:,} ({ds['aov_bytes']:,})"],
            ]
        rows = [row + [""] * (3 - len(row)) for row in rows]
        s = fr["settings"]
        parts += [
            "",
            f"Frame: {fr['scene']} scene ({fr['triangles']:,} triangles) {fr['size'][0]}x{fr['size'][1]}, "
            f"{fr['lights']} light(s), shadows {s.get('shadows')}, AO {ao_samples({**DEFAULT_SETTINGS, **s})} spp "
            f"(median of runs)",
            _table(rows, ["pass", "render() ms", "back to back ms"]),
        ]
    st = results.get("start")
    if st:
        rows = [
            ["import engine", _fmt(st["import_s"], ".2f"), " ".join(_fmt(v, ".2f") for v in st["import_runs_s"])],
            [st["render_command"], _fmt(st["render_s"], ".2f"), " ".join(_fmt(v, ".2f") for v in st["render_runs_s"])],
        ]
        parts += ["", "Start-up (fresh processes after one warm-up each; wall s)", _table(rows, ["", "median", "runs"])]
    if results.get("targets"):
        rows = [
            [
                f"#{t['issue']}",
                t["target"],
                _fmt(t["measured"], ".3g") + (f" {t['unit']}" if t["measured"] is not None else ""),
                t.get("summary", t["status"]) + (f"; {t['note']}" if t.get("note") else ""),
            ]
            for t in results["targets"]
        ]
        parts += ["", "Targets", _table(rows, ["issue", "target", "measured", "status"], ["<", "<", ">", "<"])]
    return "\n".join(parts)


def _json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def write_json(results: dict, path):
    atomic_write_text(path, json.dumps(results, indent=1, default=_json_default) + "\n", "benchmark JSON")
