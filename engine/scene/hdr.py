"""Radiance RGBE (.hdr) images: a reader (flat and run-length encoded scanlines) and a writer, in numpy.

Format (Greg Ward, "Real Pixels", Graphics Gems II; the `.hdr` files of every HDRI site): a text header starting
`#?RADIANCE` or `#?RGBE` with `FORMAT=32-bit_rle_rgbe`, a blank line, a resolution line `-Y H +X W` (rows top to
bottom), then H scanlines of 4-byte pixels (R, G, B mantissas sharing the exponent E: value = m * 2^(E - 136)).
A scanline of 8..32767 pixels may be run-length encoded per channel (bytes 2, 2, W >> 8, W & 255, then each channel
as runs: a count > 128 repeats the next byte count - 128 times, else that many literal bytes follow).
"""

from __future__ import annotations

import os

import numpy as np

from engine.errors import SceneError

MAX_SIDE = 32767  # the RLE scanline's width field; larger maps are not an equirect anyone ships


def read_hdr(path: str | os.PathLike[str]) -> np.ndarray:
    """(H, W, 3) float32 linear RGB of a Radiance .hdr file; a SceneError naming the file says what is wrong."""
    name = os.fspath(path)
    try:
        with open(name, "rb") as f:
            data = f.read()
    except OSError as exc:
        raise SceneError(f"{name}: cannot read the environment map ({exc.strerror or exc})") from None
    if not (data.startswith(b"#?RADIANCE") or data.startswith(b"#?RGBE")):
        raise SceneError(f"{name}: not a Radiance HDR file (it does not start with #?RADIANCE or #?RGBE)")
    end = data.find(b"\n\n")
    if end < 0:
        raise SceneError(f"{name}: not a Radiance HDR file (its header never ends)")
    for line in data[:end].split(b"\n"):
        if line.startswith(b"FORMAT=") and line.strip() != b"FORMAT=32-bit_rle_rgbe":
            fmt = line[7:].strip().decode("latin-1")
            raise SceneError(f"{name}: HDR format {fmt!r} is not supported (only 32-bit_rle_rgbe)")
    eol = data.find(b"\n", end + 2)
    res = data[end + 2 : eol if eol >= 0 else len(data)].split()
    if len(res) != 4 or res[0] != b"-Y" or res[2] != b"+X" or not res[1].isdigit() or not res[3].isdigit():
        shown = res and b" ".join(res).decode("latin-1", "replace")[:40]
        raise SceneError(f"{name}: HDR resolution line {shown!r} is not supported (only '-Y height +X width')")
    h, w = int(res[1]), int(res[3])
    if not (1 <= h <= MAX_SIDE and 1 <= w <= MAX_SIDE):
        raise SceneError(f"{name}: HDR size {w}x{h} is out of range (1..{MAX_SIDE} per side)")
    body = np.frombuffer(data, np.uint8, offset=eol + 1) if eol >= 0 else np.zeros(0, np.uint8)
    try:
        rgbe = _scanlines(body, w, h)
    except _Truncated:
        raise SceneError(f"{name}: HDR pixel data is truncated or corrupt ({w}x{h} expected)") from None
    return decode_rgbe(rgbe)


class _Truncated(Exception):
    pass


def _scanlines(body: np.ndarray, w: int, h: int) -> np.ndarray:
    out = np.empty((h, w, 4), np.uint8)
    pos = 0
    raw = body.tobytes()
    for y in range(h):
        rle = 8 <= w <= MAX_SIDE and pos + 4 <= len(raw) and raw[pos] == 2 and raw[pos + 1] == 2 and raw[pos + 2] < 128
        if not rle:  # flat pixels
            n = 4 * w
            if pos + n > len(raw):
                raise _Truncated
            out[y] = body[pos : pos + n].reshape(w, 4)
            pos += n
            continue
        if (raw[pos + 2] << 8 | raw[pos + 3]) != w:
            raise _Truncated
        pos += 4
        for c in range(4):
            x = 0
            row = out[y, :, c]
            while x < w:
                if pos >= len(raw):
                    raise _Truncated
                count = raw[pos]
                if count > 128:
                    count -= 128
                    if x + count > w or pos + 1 >= len(raw):
                        raise _Truncated
                    row[x : x + count] = raw[pos + 1]
                    pos += 2
                else:
                    if count == 0 or x + count > w or pos + 1 + count > len(raw):
                        raise _Truncated
                    row[x : x + count] = body[pos + 1 : pos + 1 + count]
                    pos += 1 + count
                x += count
    return out


def decode_rgbe(rgbe: np.ndarray) -> np.ndarray:
    """(..., 4) uint8 RGBE -> (..., 3) float32: m 2^(E - 136), as stb_image and Mitsuba 3 decode."""
    e = rgbe[..., 3].astype(np.int32)
    scale = np.where(e > 0, np.ldexp(1.0, e - 136), 0.0).astype(np.float32)
    return (rgbe[..., :3].astype(np.float32) * scale[..., None]).astype(np.float32)


def encode_rgbe(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) float -> (..., 4) uint8 RGBE (values below 1e-32 are black; mantissas rounded to nearest)."""
    rgb = np.maximum(np.asarray(rgb, np.float64), 0.0)
    m = rgb.max(axis=-1)
    mant, exp = np.frexp(m)
    ok = m > 1e-32
    scale = np.where(ok, mant * 256.0 / np.where(ok, m, 1.0), 0.0)
    out = np.zeros(rgb.shape[:-1] + (4,), np.uint8)
    out[..., :3] = np.clip(np.rint(rgb * scale[..., None]), 0, 255).astype(np.uint8)
    out[..., 3] = np.where(ok, exp + 128, 0).astype(np.uint8)
    return out


def write_hdr(path: str | os.PathLike[str], rgb: np.ndarray, rle: bool = True) -> None:
    """Write (H, W, 3) linear RGB as a Radiance .hdr file (run-length encoded scanlines where W allows)."""
    rgbe = encode_rgbe(rgb)
    h, w = rgbe.shape[:2]
    parts = [b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n", f"-Y {h} +X {w}\n".encode()]
    for y in range(h):
        if not (rle and 8 <= w <= MAX_SIDE):
            parts.append(rgbe[y].tobytes())
            continue
        parts.append(bytes([2, 2, w >> 8, w & 255]))
        for c in range(4):
            parts.append(_rle(rgbe[y, :, c].tobytes()))
    with open(os.fspath(path), "wb") as f:
        f.write(b"".join(parts))


def _rle(row: bytes) -> bytes:
    out, x, n = bytearray(), 0, len(row)
    while x < n:
        run = 1
        while x + run < n and run < 127 and row[x + run] == row[x]:
            run += 1
        if run >= 4:
            out += bytes([128 + run, row[x]])
            x += run
            continue
        start = x
        while x < n and x - start < 128 and not (x + 3 < n and row[x] == row[x + 1] == row[x + 2] == row[x + 3]):
            x += 1
        out += bytes([x - start]) + row[start:x]
    return bytes(out)
