"""The environment's GPU tables, made on the host in numpy: one float32 array that
shaders/glsl/include/environment.glsl reads (a storage buffer), and the same sampling in numpy (`sample`, `pdf`) that
the tests compare the shader's with.

Layout (float32 words; the HEADER's integers are uint32 bits):
- header: W, H of the map; PW, PH and the count of the prefiltered levels; the BRDF table's side; cos and sin of
  the rotation; the word offsets of the map, the marginal CDF, the conditional CDFs, the prefiltered levels and the
  BRDF table; then 9 x RGB spherical-harmonics coefficients of the irradiance / pi (at SH_AT).
- the map (H x W x RGB, times the intensity; maps wider than MAX_WIDTH are box-averaged down first);
- sampling: the marginal CDF over rows (H + 1) and each row's conditional CDF over columns (H x (W + 1)) of
  f = luminance x sin(theta) (+ a floor of 1e-4 x its mean, so that no direction that may carry light has pdf 0);
  the solid-angle pdf of a direction is pdf_uv / (2 pi^2 sin theta);
- the GGX-prefiltered radiance (split sum, Karis 2013) at roughness (k + 1) / LEVELS, k < LEVELS, each PW x PH,
  from a 128 x 64 copy of the map (roughness 0 is the map itself);
- the BRDF table: LUT x LUT (n.v, roughness) of the scale and bias on F0 of the GGX lobe's directional albedo
  (height-correlated Smith, as brdf.glsl), by importance sampling.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from engine.errors import SceneError

from . import _check
from .environment import equirect_directions

HEADER = 48
SH_AT = 16
MAX_WIDTH = 2048
PREFILTER = (32, 64)  # rows, columns of each prefiltered level
SOURCE = (64, 128)  # the map's copy the sharpest level is filtered from (and the SH projected from)
ROUGH_SOURCE = (32, 64)  # the rougher levels' (their lobes span many of its texels)
LEVELS = 4
LUT = 32
FLOOR = 1e-4
# header word indices
W_, H_, PW_, PH_, NL_, LUT_, COS_, SIN_, MAP_, MARG_, COND_, PRE_, BRDF_ = range(13)
LUMA = np.array([0.2126, 0.7152, 0.0722])


def resample(img: np.ndarray, h: int, w: int) -> np.ndarray:
    """Box average (or nearest, where it grows) of an (H, W, C) image to (h, w, C)."""
    out = np.asarray(img, np.float64)
    for axis, n in ((0, h), (1, w)):
        size = out.shape[axis]
        if size == n:
            continue
        if size > n:
            edges = (np.arange(n) * size) // n
            counts = np.diff(np.append(edges, size))
            sums = np.add.reduceat(out, edges, axis=axis)
            shape = [1, 1, 1]
            shape[axis] = n
            out = sums / counts.reshape(shape)
        else:
            out = np.take(out, (np.arange(n) * size) // n, axis=axis)
    return out


def band_solid_angles(h: int, w: int) -> np.ndarray:
    """(h,) the solid angle of one texel in each row of an h x w equirect map."""
    j = np.arange(h)
    return (2 * np.pi / w) * (np.cos(j * np.pi / h) - np.cos((j + 1) * np.pi / h))


def sh_basis(d: np.ndarray) -> np.ndarray:
    """(..., 9) real spherical harmonics up to l = 2 at unit directions (..., 3), in environment.glsl's order."""
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    return np.stack(
        [
            np.full_like(x, 0.282095),
            0.488603 * y,
            0.488603 * z,
            0.488603 * x,
            1.092548 * x * y,
            1.092548 * y * z,
            0.315392 * (3 * z * z - 1),
            1.092548 * x * z,
            0.546274 * (x * x - y * y),
        ],
        axis=-1,
    )


def sh_irradiance(img: np.ndarray) -> np.ndarray:
    """(9, 3) coefficients of E(n) / pi (the radiance a white Lambert surface reflects) of an equirect map
    (Ramamoorthi and Hanrahan 2001: the cosine lobe's bands pi, 2pi/3, pi/4)."""
    h, w = img.shape[:2]
    d = equirect_directions(h, w)
    weight = band_solid_angles(h, w)[:, None]
    c = np.einsum("hwk,hwc,h->kc", sh_basis(d), img, weight[:, 0])
    bands = np.array([np.pi] + [2 * np.pi / 3] * 3 + [np.pi / 4] * 5)
    return c * bands[:, None] / np.pi


def eval_sh(coeffs: np.ndarray, n: np.ndarray) -> np.ndarray:
    """E(n) / pi at unit normals (..., 3) from `sh_irradiance` coefficients (clamped at 0, as the shader)."""
    return np.maximum(sh_basis(n) @ coeffs, 0.0)


def prefilter(src: np.ndarray, roughness: float, size=PREFILTER) -> np.ndarray:
    """An equirect map `src` filtered by the GGX lobe of `roughness` around each output direction (n = v = r):
    weights D(h) (n.l) over the source's solid angle."""
    h, w = src.shape[:2]
    sd = equirect_directions(h, w).reshape(-1, 3).astype(np.float32)
    sw = np.repeat(band_solid_angles(h, w), w).astype(np.float32)
    radiance = src.reshape(-1, 3).astype(np.float32)
    out_d = equirect_directions(*size).reshape(-1, 3).astype(np.float32)
    a2 = np.float32(float(roughness) ** 4)
    out = np.empty((len(out_d), 3), np.float32)
    for start in range(0, len(out_d), 256):
        c = out_d[start : start + 256] @ sd.T
        dd = (0.5 * (a2 - 1)) * (1 + c) + 1  # (n.h)^2 (a2 - 1) + 1 with (n.h)^2 = (1 + n.l) / 2
        wts = np.maximum(c, 0) * sw / (dd * dd)  # D(h) (n.l) dw, less D's constant factor
        out[start : start + 256] = (wts @ radiance) / np.maximum(wts.sum(axis=1, keepdims=True), 1e-30)
    return out.reshape(*size, 3)


@lru_cache(maxsize=1)
def brdf_table(n: int = LUT, samples: int = 512) -> np.ndarray:
    """(n, n, 2) [n.v index][roughness index]: scale A and bias B with directional albedo = F0 A + B, at the cell
    centres, by GGX importance sampling (Hammersley points) with brdf.glsl's height-correlated Smith."""
    n_v = (np.arange(n) + 0.5) / n
    rough = np.maximum((np.arange(n) + 0.5) / n, 0.045)
    i = np.arange(samples)
    u1 = (i + 0.5) / samples
    u2 = np.array([int(f"{k:032b}"[::-1], 2) for k in i]) / 2.0**32  # radical inverse (base 2)
    out = np.zeros((n, n, 2))
    for a, nv in enumerate(n_v):
        v = np.array([math.sqrt(1 - nv * nv), 0.0, nv])
        for b, r in enumerate(rough):
            a2 = r**4
            cos_h = np.sqrt((1 - u1) / (1 + (a2 - 1) * u1))
            sin_h = np.sqrt(1 - cos_h**2)
            hx, hz = sin_h * np.cos(2 * np.pi * u2), cos_h  # (v has no y: the y of h drops out)
            v_h = v[0] * hx + v[2] * hz
            lz = 2 * v_h * hz - v[2]
            ok = lz > 0
            n_l = np.where(ok, lz, 0.0)
            gv = n_l * np.sqrt(nv * nv * (1 - a2) + a2)
            gl = nv * np.sqrt(n_l * n_l * (1 - a2) + a2)
            vis = 0.5 / np.maximum(gv + gl, 1e-12)
            g = np.where(ok, 4 * vis * n_l * v_h / hz, 0.0)
            fc = (1 - np.clip(v_h, 0, 1)) ** 5
            out[a, b] = [np.mean(g * (1 - fc)), np.mean(g * fc)]
    return out.astype(np.float32)


def sampling_cdfs(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(marginal (H + 1,), conditional (H, W + 1)) CDFs of luminance x sin(theta), floored (module doc)."""
    h, w = img.shape[:2]
    sin_t = np.sin((np.arange(h) + 0.5) * np.pi / h)
    f = np.maximum(np.asarray(img, np.float64) @ LUMA, 0.0) * sin_t[:, None]
    mean = f.mean()
    f = f + FLOOR * mean if mean > 0 else np.broadcast_to(sin_t[:, None], (h, w)).copy()
    rows = f.sum(axis=1)
    cond = np.zeros((h, w + 1))
    cond[:, 1:] = np.cumsum(f, axis=1) / rows[:, None]
    cond[:, -1] = 1.0
    marg = np.zeros(h + 1)
    marg[1:] = np.cumsum(rows) / rows.sum()
    marg[-1] = 1.0
    return marg, cond


def build(img: np.ndarray, intensity: float = 1.0, rotation: float = 0.0) -> np.ndarray:
    """The float32 words of the environment buffer (module doc) of an (H, 2H, 3) map."""
    img = np.asarray(img, np.float32)
    while img.shape[1] > MAX_WIDTH:
        img = resample(img, img.shape[0] // 2, img.shape[1] // 2).astype(np.float32)
    top = float(img.max())
    if top * float(intensity) > _check.MAX_VALUE:  # (intensity may be assigned after the map's own check)
        raise SceneError(
            f"environment: intensity {intensity:g} times the map's peak {top:g} is {top * float(intensity):g}, "
            f"above {_check.MAX_VALUE:g}"
        )
    img = img * np.float32(intensity)
    h, w = img.shape[:2]
    marg, cond = sampling_cdfs(img)
    sharp = resample(img, *SOURCE)  # the sharpest level's source (and the SH's)
    rough = resample(sharp, *ROUGH_SOURCE)
    levels = [prefilter(sharp if (k + 1) / LEVELS < 0.5 else rough, (k + 1) / LEVELS) for k in range(LEVELS)]
    lut = brdf_table()
    parts = [img.reshape(-1), marg, cond.reshape(-1), np.concatenate([lv.reshape(-1) for lv in levels]), lut]
    offsets = np.cumsum([HEADER] + [p.size for p in parts])
    out = np.zeros(int(offsets[-1]), np.float32)
    words = out.view(np.uint32)
    words[[W_, H_, PW_, PH_, NL_, LUT_]] = [w, h, PREFILTER[1], PREFILTER[0], LEVELS, LUT]
    rad = math.radians(rotation)
    out[COS_], out[SIN_] = math.cos(rad), math.sin(rad)
    words[MAP_ : MAP_ + 5] = offsets[:5]
    out[SH_AT : SH_AT + 27] = sh_irradiance(sharp if w > SOURCE[1] else img).reshape(-1)
    for p, off in zip(parts, offsets[:-1]):
        out[off : off + p.size] = p.reshape(-1)
    return out


# ---- the shader's sampling, in numpy (tests) --------------------------------------------------------------------
def _rot(words: np.ndarray):
    return float(words[COS_]), float(words[SIN_])


def to_local(words, d):
    c, s = _rot(words)
    return np.stack([c * d[..., 0] - s * d[..., 2], d[..., 1], s * d[..., 0] + c * d[..., 2]], axis=-1)


def to_world(words, d):
    c, s = _rot(words)
    return np.stack([c * d[..., 0] + s * d[..., 2], d[..., 1], -s * d[..., 0] + c * d[..., 2]], axis=-1)


def _tables(words):
    iw = words.view(np.uint32)
    w, h = int(iw[W_]), int(iw[H_])
    marg = words[iw[MARG_] : iw[MARG_] + h + 1].astype(np.float64)
    cond = words[iw[COND_] : iw[COND_] + h * (w + 1)].astype(np.float64).reshape(h, w + 1)
    return w, h, marg, cond


def sample(words: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Directions (N, 3) and their solid-angle pdfs (N,) for uniform points u (N, 2), as environment_sample."""
    w, h, marg, cond = _tables(words)
    j = np.clip(np.searchsorted(marg, u[:, 1], side="right") - 1, 0, h - 1)
    dv = (u[:, 1] - marg[j]) / np.maximum(marg[j + 1] - marg[j], 1e-30)
    row = cond[j]
    i = np.clip(np.array([np.searchsorted(r, x, side="right") - 1 for r, x in zip(row, u[:, 0])]), 0, w - 1)
    du = (u[:, 0] - row[np.arange(len(i)), i]) / np.maximum(
        row[np.arange(len(i)), i + 1] - row[np.arange(len(i)), i], 1e-30
    )
    uu, vv = (i + du) / w, (j + dv) / h
    theta, phi = vv * np.pi, uu * 2 * np.pi
    st = np.sin(theta)
    d = np.stack([st * np.sin(phi), np.cos(theta), -st * np.cos(phi)], axis=-1)
    pdf_uv = (marg[j + 1] - marg[j]) * h * (row[np.arange(len(i)), i + 1] - row[np.arange(len(i)), i]) * w
    pdf = np.where(st > 0, pdf_uv / (2 * np.pi**2 * np.maximum(st, 1e-30)), 0.0)
    return to_world(words, d), pdf


def pdf(words: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The solid-angle pdf (N,) of `sample` at unit world directions (N, 3), as environment_pdf."""
    w, h, marg, cond = _tables(words)
    ld = to_local(words, d)
    u = np.mod(np.arctan2(ld[:, 0], -ld[:, 2]) / (2 * np.pi), 1.0)
    v = np.arccos(np.clip(ld[:, 1], -1, 1)) / np.pi
    i, j = np.minimum((u * w).astype(int), w - 1), np.minimum((v * h).astype(int), h - 1)
    st = np.sqrt(np.maximum(1 - ld[:, 1] ** 2, 0.0))
    pdf_uv = (marg[j + 1] - marg[j]) * h * (cond[j, i + 1] - cond[j, i]) * w
    return np.where(st > 0, pdf_uv / (2 * np.pi**2 * np.maximum(st, 1e-30)), 0.0)
