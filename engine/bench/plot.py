"""A bench's results as one PNG (drawn with pillow): Mrays/s per ray set and engine for each trace scene, GPU ms per
pass of each frame, and seconds per million triangles of the BVH builds against the issue goals."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from ..files import atomic_write
from ..settings import DEFAULT_SETTINGS, ao_samples
from .config import PEERS


ENGINE_COLORS = {
    "ours GPU": (46, 117, 182),
    "ours wall": (143, 187, 227),
    "embreex": (230, 126, 34),
    "open3d": (68, 160, 80),
    "mitsuba": (142, 68, 173),
    "mitsuba_device": (195, 155, 211),
}
PASS_COLORS = [
    (46, 117, 182),
    (230, 126, 34),
    (68, 160, 80),
    (192, 57, 43),
    (142, 68, 173),
    (127, 140, 141),
    (241, 196, 15),
    (22, 160, 133),
]


def _font(size, bold=False):
    for name in (
        ("DejaVuSans-Bold.ttf" if bold else "DejaVuSans.ttf"),
        "/usr/share/fonts/truetype/dejavu/" + ("DejaVuSans-Bold.ttf" if bold else "DejaVuSans.ttf"),
    ):
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
    lx, ly = x0, y0 + 34
    for s in series:  # legend under the title, wrapped at the panel's width
        step = 34 + draw.textlength(s, font=f_small)
        if lx > x0 and lx + step - 20 > x1:
            lx, ly = x0, ly + 22
        draw.rectangle([lx, ly, lx + 14, ly + 14], fill=colors[s])
        draw.text((lx + 20, ly + 7), s, fill=(0, 0, 0), font=f_small, anchor="lm")
        lx += step
    extra = ly - (y0 + 34)
    top, bottom, left = y0 + 92 + extra, y1 - 50, x0 + 64
    draw.text((x0, y0 + 62 + extra), unit, fill=(80, 80, 80), font=f_small)
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
                if s in vals:  # measured as nothing: say so
                    draw.text(
                        (gx + si * bw + bw / 2, bottom - 3), "n/a", fill=(120, 120, 120), font=f_small, anchor="md"
                    )
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
                    draw.text((x + w / 2, y + rh / 2 - 1), f"{v:.1f}", fill=(255, 255, 255), font=f_small, anchor="mm")
            x += w
        total = totals[ri] if totals else sum(d.values())
        draw.text((x + 6, y + rh / 2 - 1), f"{total:.1f} ms", fill=(0, 0, 0), font=f_small, anchor="lm")


def plot(results: dict, path):
    """A PNG: Mrays/s per ray set and engine for each trace scene, the per-pass frame breakdown, BVH build."""
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
    d.text(
        (30, 56),
        f"{meta.get('date', '')[:10]}   {m.get('cpu', '')} ({m.get('cores')} cores)   device: "
        f"{dev.get('name', '-')} {dev.get('driver_info', '')}"
        + (
            f"   other processes: {meta['other_processes']['others_mean_cores']} cores on average"
            if meta.get("other_processes", {}).get("others_mean_cores") is not None
            else ""
        ),
        fill=(60, 60, 60),
        font=fonts[2],
    )
    y = 90
    for sc, h in zip(scenes, heights):
        eng = sc["engines"]
        names = {
            "ours GPU": "ours (GPU timestamps)",
            "ours wall": "ours (wall clock, upload + readback)",
            "embreex": f"embreex ({eng.get('embreex', {}).get('threads') or 1} thread, wall)",
            "open3d": f"Open3D ({eng.get('open3d', {}).get('threads') or '?'} threads, wall)",
            "mitsuba": "Mitsuba, numpy (wall)",
            "mitsuba_device": "Mitsuba, resident (wall)",
        }
        for p in ("mitsuba", "mitsuba_device"):
            if "label" in eng.get(p, {}):  # the label's third word: the variant
                names[p] = names[p].replace("Mitsuba", "Mitsuba " + eng[p]["label"].split()[2])
        groups = []
        for rs in sc["raysets"]:
            r = rs["results"]
            vals = {
                names["ours GPU"]: r.get("ours", {}).get("mrays_gpu"),
                names["ours wall"]: r.get("ours", {}).get("mrays_wall"),
            }
            for p in PEERS:
                if p in r:
                    vals[names[p]] = r[p]["mrays_wall"]
            groups.append((f"{rs['title']}\n{rs['rays']:,} rays", vals))
        series = [
            names[k]
            for k in ("ours GPU", "ours wall") + PEERS
            if k in ("ours GPU", "ours wall") or "label" in eng.get(k, {})
        ]
        colors = {names[k]: ENGINE_COLORS[k] for k in names}
        _bar_panel(
            d,
            (30, y, W - 30, y + h),
            f"Trace throughput, {sc['scene']} scene ({sc['triangles']:,} triangles), same rays for every engine",
            groups,
            series,
            colors,
            "Mrays/s (higher is better)",
            fonts,
        )
        y += h + 30
    if frames:
        h = heights[len(scenes)]
        rows = [
            (
                f"{fr['scene']} ({fr['triangles']:,} tris)\n{fr['size'][0]}x{fr['size'][1]}, {fr['lights']} light"
                f"{'s' if fr['lights'] != 1 else ''}, AO {ao_samples({**DEFAULT_SETTINGS, **fr['settings']})} spp",
                fr["passes_ms"],
            )
            for fr in frames
        ]
        _stack_panel(
            d,
            (30, y, W - 30, y + h),
            "Frame: GPU ms per pass (median of each pass; total: median of frame totals)",
            rows,
            fonts,
            totals=[fr["gpu_total_ms"] for fr in frames],
        )
        y += h + 30
    if builds:
        h = heights[-1]
        groups = [
            (
                f"{b.get('kind', 'generated')} {b['triangles'] / 1e6:.2g}M\nSAH {b['sah_cost']:.0f}, "
                f"{b['bytes_per_triangle']:.0f} B/tri",
                {"s per M triangles": b["s_per_million"]},
            )
            for b in builds
        ]
        _bar_panel(
            d,
            (30, y, W - 30, y + h),
            "BVH build: seconds per million triangles (goal: <= 1.0 issues 3 and 19, <= 0.5 issue 6)",
            groups,
            ["s per M triangles"],
            {"s per M triangles": (46, 117, 182)},
            "s / M triangles (lower is better)",
            fonts,
            hlines=[(1.0, "issues 3, 19 goal 1.0"), (0.5, "issue 6 goal 0.5")],
        )
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, lambda f: img.save(f, format="PNG"), "plot")
    return path
