"""What trimesh reads without a word or reports obscurely, found in the file itself: OBJ face index 0, and why a
glTF cannot be followed (not JSON, no buffers, references past the end of a list). Each returns a one-line
problem, or None."""

from __future__ import annotations

import base64
import binascii
import io
import json
import re
import warnings

from PIL import Image

from engine.errors import shown

# A face ("f") line with a vertex, UV or normal index of 0: OBJ indices start at 1 (negative ones count back), and
# trimesh turns a 0 into a reference to the last vertex.
# (Lines are found by their newline, a literal the regex engine scans for quickly: 0.75 s for a 145 MB OBJ that
# trimesh reads in 4.8 s.)
_OBJ_ZERO_INDEX = re.compile(rb"\n[ \t]*f[ \t][^\n#]*?(?<=[ \t/])[+-]?0+(?=[ \t/\r\n#]|$)")


def check_mesh_file(path: str, ext: str) -> str | None:
    """A problem of the file at `path` that trimesh would accept silently, or None."""
    if ext != ".obj":
        return None
    with open(path, "rb") as fh:
        data = fh.read()
    first = data.find(b"\n")
    if _OBJ_ZERO_INDEX.search(b"\n" + data[: first if first >= 0 else len(data)]):
        line = 1
    else:
        m = _OBJ_ZERO_INDEX.search(data)
        if m is None:
            return None
        line = data.count(b"\n", 0, m.start()) + 2  # the match starts at the newline before the line
    return f"line {line}: face index 0 (OBJ indices start at 1; negative ones count back from the last vertex)"


def _read_gltf(path: str):
    """(bytes of the file, the JSON text, the BIN chunk of a .glb or b"")."""
    with open(path, "rb") as fh:
        data = fh.read()
    if data[:4] != b"glTF":
        return data, data, b""
    # binary: a 12-byte header, then chunks of (length, type, data): JSON first, BIN next
    length = int.from_bytes(data[12:16], "little") if len(data) >= 20 else 0
    end = 20 + length
    bin_length = int.from_bytes(data[end : end + 4], "little") if len(data) >= end + 8 else 0
    return data, data[20:end], data[end + 8 : end + 8 + bin_length]


def bomb_pixels(exc: Exception) -> int | None:
    """The pixel count in pillow's DecompressionBombError ('Image size (N pixels) exceeds limit ...')."""
    digits = str(exc).split("(", 1)[-1].split(" ", 1)[0]
    return int(digits) if digits.isdigit() else None


def bomb_images(path: str) -> list[tuple[int, int | None]]:
    """The images inside a glTF (GLB buffer views, data URIs) that pillow refuses to open as decompression bombs,
    which trimesh drops without a word: (index, pixel count) each."""
    try:
        data, text, binary = _read_gltf(path)
        doc = json.loads(text.decode("utf-8-sig"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError):
        return []
    images = doc.get("images") if isinstance(doc, dict) else None
    views = doc.get("bufferViews") if isinstance(doc, dict) else None
    found = []
    for i, img in enumerate(images if isinstance(images, list) else []):
        blob = None
        if not isinstance(img, dict):
            continue
        v = img.get("bufferView")
        if (
            binary
            and isinstance(v, int)
            and isinstance(views, list)
            and 0 <= v < len(views)
            and isinstance(views[v], dict)
        ):
            offset, length = views[v].get("byteOffset", 0), views[v].get("byteLength", 0)
            if isinstance(offset, int) and isinstance(length, int):
                blob = binary[offset : offset + length]
        uri = img.get("uri")
        if isinstance(uri, str) and uri.startswith("data:") and "," in uri:
            try:
                blob = base64.b64decode(uri.split(",", 1)[1])
            except (binascii.Error, ValueError):
                blob = None
        if not blob:
            continue
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                Image.open(io.BytesIO(blob)).close()
        except Image.DecompressionBombError as exc:
            found.append((i, bomb_pixels(exc)))
        except Exception:
            pass
    return found


def diagnose_gltf(path: str) -> str | None:
    """Why the glTF at `path` cannot be read, when its JSON says so, or None."""
    try:
        data, text, _ = _read_gltf(path)
    except OSError:
        return None
    if data[:4] == b"glTF":
        what = "the JSON chunk of this .glb is not valid JSON"
    else:
        what = "not a glTF file: a .gltf is JSON text (binary glTF is .glb), and this is not valid JSON"
    try:
        doc = json.loads(text.decode("utf-8-sig"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        detail = shown(str(exc).splitlines()[0] if str(exc) else type(exc).__name__, limit=120)
        return f"{what} ({detail})"
    if not isinstance(doc, dict):
        return f"not a glTF file: its JSON is a {type(doc).__name__}, not an object"
    return _references(doc, glb=data[:4] == b"glTF")


def _references(doc: dict, glb: bool) -> str | None:
    """The first reference in `doc` to an item that does not exist (accessor -> bufferView -> buffer,
    primitive -> accessor), or a buffer with nowhere to read it from."""

    def items(key):
        value = doc.get(key, [])
        return value if isinstance(value, list) else []

    buffers, views, accessors = items("buffers"), items("bufferViews"), items("accessors")
    for i, buf in enumerate(buffers):
        if not isinstance(buf, dict):
            return f"buffers[{i}] is not an object"
        if "uri" not in buf and not (glb and i == 0):
            return f"buffers[{i}] has no 'uri' (only the first buffer of a .glb may be its binary chunk)"
    for i, view in enumerate(views):
        b = view.get("buffer") if isinstance(view, dict) else None
        if not isinstance(b, int) or not 0 <= b < len(buffers):
            return f"bufferViews[{i}] refers to buffer {b!r}, but the file has {_count(buffers, 'buffer')}"
    for i, acc in enumerate(accessors):
        v = acc.get("bufferView") if isinstance(acc, dict) else None
        if v is not None and (not isinstance(v, int) or not 0 <= v < len(views)):
            return f"accessors[{i}] refers to bufferView {v!r}, but the file has {_count(views, 'bufferView')}"
    for m, mesh in enumerate(items("meshes")):
        prims = mesh.get("primitives", []) if isinstance(mesh, dict) else []
        for p, prim in enumerate(prims if isinstance(prims, list) else []):
            attrs = prim.get("attributes", {}) if isinstance(prim, dict) else {}
            refs = list(attrs.items()) if isinstance(attrs, dict) else []
            if isinstance(prim, dict) and "indices" in prim:
                refs.append(("indices", prim["indices"]))
            for name, a in refs:
                if not isinstance(a, int) or not 0 <= a < len(accessors):
                    return (
                        f"meshes[{m}].primitives[{p}] {shown(name, limit=40)} refers to accessor {a!r}, "
                        f"but the file has {_count(accessors, 'accessor')}"
                    )
    return None


def _count(items: list, what: str) -> str:
    return f"no {what}s" if not items else f"{len(items)} {what}{'s' if len(items) != 1 else ''}"
