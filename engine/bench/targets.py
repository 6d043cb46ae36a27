"""The goals of issues 3, 6, 16, 19, 31, 34 and 35 judged on a bench's results: pass / miss with the margin, or not
measured."""

from __future__ import annotations


def _target(issue, what, measured, target, unit, higher_is_better, note=""):
    if measured is None:
        return {"issue": issue, "target": what, "measured": None, "unit": unit, "status": "not measured", "note": note}
    ok = measured >= target if higher_is_better else measured <= target
    # margin > 1: better than the goal by that factor; < 1: the goal needs 1 / margin times better
    margin = measured / target if higher_is_better else target / measured if measured else float("inf")
    by = f"{margin:.2f}x margin" if ok else f"needs {1 / margin:.2f}x"
    return {
        "issue": issue,
        "target": what,
        "goal": target,
        "measured": measured,
        "unit": unit,
        "status": "pass" if ok else "miss",
        "margin": margin,
        "summary": f"{'pass' if ok else 'miss'} ({by})",
        "note": note,
    }


def evaluate_targets(results: dict) -> list[dict]:
    out = []
    for b in results.get("build", []):  # (#19: every size measured; #3 and #6: the large meshes)
        kind = b.get("kind", "generated")
        m = f"{kind}, {b['triangles'] / 1e6:.1f}M triangles"
        if kind == "generated" and b["triangles"] >= 900_000:
            out.append(
                _target(3, f"BVH build <= 1.0 s per million triangles ({m})", b["s_per_million"], 1.0, "s/M", False)
            )
            out.append(
                _target(6, f"BVH build <= 0.5 s per million triangles ({m})", b["s_per_million"], 0.5, "s/M", False)
            )
        out.append(
            _target(
                19,
                f"BVH build <= 1.0 s per million triangles on every mesh kind ({m})",
                b["s_per_million"],
                1.0,
                "s/M",
                False,
            )
        )
    device = results.get("meta", {}).get("device", {})
    cpu_device = device.get("type") == "CPU"
    for sc in results.get("trace", {}).get("scenes", []):
        for rs in sc["raysets"]:
            if rs["kind"] != "occluded" or "open3d" not in rs["ratio"] or rs["name"] == "scattered":
                continue  # (issues 3 and 6 name the G-buffer's ray sets)
            ratio = rs["ratio"]["open3d"]
            for basis in ("wall", "gpu"):
                where = f"{sc['scene']} scene, {rs['name']} rays, {'wall clock' if basis == 'wall' else 'GPU time'}"
                out.append(_target(3, f"occlusion >= 0.5x Open3D ({where})", ratio[basis], 0.5, "x", True))
                if cpu_device:
                    out.append(_target(6, f"lavapipe occlusion >= 1.0x Open3D ({where})", ratio[basis], 1.0, "x", True))
    gpu_device = device and not cpu_device
    size = results.get("meta", {}).get("size")
    big = [sc for sc in results.get("trace", {}).get("scenes", []) if sc["triangles"] >= 300_000]
    note_gpu = (
        ""
        if gpu_device
        else ("needs a GPU; this run's device is a CPU" if device else "needs a GPU and the trace/frame sections")
    )
    shadow = ao = None
    if gpu_device and big and size == [1920, 1080]:
        rs = {r["name"]: r for r in big[0]["raysets"]}
        shadow = rs["shadow"]["results"]["ours"].get("mrays_gpu")
        ao = rs["ao"]["results"]["ours"].get("mrays_gpu")
    out.append(
        _target(
            6,
            f"GPU: 1920x1080 shadow rays >= 4 Grays/s, batch Tracer ({big[0]['scene'] if big else '-'} "
            f"scene, {big[0]['triangles'] if big else 0:,} triangles)",
            shadow / 1e3 if shadow else None,
            4.0,
            "Grays/s",
            True,
            note_gpu,
        )
    )
    # the same target met by the renderer's own shadow pass (G-buffer in, light mask out; frames back to back) on the
    # smallest frame scene of >= 300k triangles
    passes = sorted(
        (fr for fr in results.get("frame", []) if fr["triangles"] >= 300_000 and fr.get("viewer_shadow_pass_grays")),
        key=lambda fr: fr["triangles"],
    )
    pass_grays = passes[0]["viewer_shadow_pass_grays"] if gpu_device and passes and size == [1920, 1080] else None
    where = f"{passes[0]['scene']}, {passes[0]['triangles']:,} triangles" if passes else ">= 300k triangles"
    out.append(
        _target(
            6,
            f"GPU: 1920x1080 shadow rays >= 4 Grays/s, the renderer's shadow pass ({where})",
            pass_grays,
            4.0,
            "Grays/s",
            True,
            note_gpu or "rays traced / shadow pass GPU ms, frames back to back",
        )
    )
    out.append(
        _target(6, "GPU: 1920x1080 AO rays >= 1.5 Grays/s", ao / 1e3 if ao else None, 1.5, "Grays/s", True, note_gpu)
    )
    frame_ms = None
    for fr in results.get("frame", []):
        if gpu_device and fr["size"] == [1920, 1080] and fr["scene"] == "default-1light":
            frame_ms = fr.get("viewer_gpu_total_ms", fr["gpu_total_ms"])
    out.append(
        _target(
            6,
            "GPU: full 1920x1080 frame <= 2 ms GPU (1 light, hard shadows, 1 AO ray, denoise)",
            frame_ms,
            2.0,
            "ms",
            False,
            note_gpu or "frames back to back, no readback (the viewer's)",
        )
    )
    frames = {fr["scene"]: fr for fr in results.get("frame", [])}
    pinhole = frames.get("default")
    for tag, lens in (("default-opencv-distorted", "OpenCV-distorted"), ("default-fisheye", "fisheye")):
        fr = frames.get(tag)
        ratio = None
        if gpu_device and fr and pinhole and fr["size"] == [1920, 1080]:
            ratio = fr.get("viewer_gpu_total_ms", fr["gpu_total_ms"]) / pinhole.get(
                "viewer_gpu_total_ms", pinhole["gpu_total_ms"]
            )
        out.append(
            _target(
                34,
                f"GPU: 1920x1080 {lens} camera frame <= 1.5x the pinhole's (default scene, traced primary rays)",
                ratio,
                1.5,
                "x",
                False,
                note_gpu or "frames back to back, no readback (the viewer's)",
            )
        )
    for fr in results.get("frame", []):
        ds = fr.get("dataset")
        if not ds:
            continue
        what = f"{fr['size'][0]}x{fr['size'][1]}, {fr['scene']}, {' + '.join(ds['aovs'])}"
        if gpu_device and fr["size"] == [1920, 1080]:
            out.append(
                _target(
                    16, f"GPU: render_many >= 150 frames/s to numpy ({what})", ds["many_fps"], 150.0, "frames/s", True
                )
            )
            out.append(
                _target(
                    16,
                    f"GPU: one render() with those AOVs <= 12 ms wall ({what})",
                    ds["render_wall_ms"],
                    12.0,
                    "ms",
                    False,
                )
            )
        if cpu_device:
            out.append(
                _target(
                    16,
                    f"lavapipe: render_many wall <= 1.15x the frame's GPU time ({what})",
                    ds["many_wall_over_gpu"],
                    1.15,
                    "x",
                    False,
                )
            )
        out.append(
            _target(
                16,
                f"bytes read back per frame = the AOVs' bytes ({what})",
                ds["readback_bytes"],
                ds["aov_bytes"],
                "bytes",
                False,
                "each part aligned to 16 bytes",
            )
        )
    for fr in results.get("frame", []):
        if fr["scene"] == "default":
            out.append(
                _target(
                    6,
                    "host (Python) CPU time per frame <= 0.3 ms (Renderer.submit, static scene)",
                    fr["submit_host_cpu_ms"],
                    0.3,
                    "ms",
                    False,
                    "submit() without readback; a viewer adds swapchain acquire/present",
                )
            )
    out += _frontend_targets(results.get("trace", {}).get("frontends"), cpu_device)
    st = results.get("start")
    if st:
        out.append(_target(31, "import engine <= 0.3 s", st["import_s"], 0.3, "s", False))
        out.append(
            _target(31, "second `hybrid render default --size 64x64` <= 1.5 s wall", st["render_s"], 1.5, "s", False)
        )
    return out


def _frontend_targets(fe, cpu_device: bool) -> list[dict]:
    """Issue 35: on a CPU-only machine the default ("auto") front ends >= 1.0x Open3D's wall clock; everywhere
    RaycastingScene on the Vulkan kernels >= 0.8x the wall clock of the Tracer's matching call."""
    if not fe:
        return []
    out = []
    for q, res in fe["queries"].items():
        for name, who in (("scene_auto", "RaycastingScene"), ("trimesh_auto", "RayMeshIntersector")):
            if cpu_device and name in res:
                what = f"CPU-only machine: {who} (auto: {fe['engines'][name].get('backend')}) {q} >= 1.0x Open3D"
                out.append(_target(35, f"{what}, wall clock", res[name].get("x_open3d"), 1.0, "x", True))
        if "x_tracer" in res.get("scene_vulkan", {}):
            what = f"RaycastingScene (vulkan) {q} >= 0.8x the Tracer's wall clock"
            out.append(_target(35, what, res["scene_vulkan"]["x_tracer"], 0.8, "x", True))
    return out
