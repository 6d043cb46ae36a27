"""GLSL std140 structs from one list of fields: the numpy dtype that packs them and the GLSL text that reads them.

LIGHT = Struct("Light", [("pos_type", "vec4"), ...])
FRAME = Struct("FrameData", [("view_proj", "mat4"), ("eye", "vec3"), ("near", "float"), ...,
                             ("lights", LIGHT, 16)])
FRAME.dtype   # numpy structured dtype with the std140 offsets: np.zeros((), FRAME.dtype)["near"] = 0.1
FRAME.glsl()  # "struct FrameData { mat4 view_proj; vec3 eye; float near; ... };"
"""

from __future__ import annotations

import numpy as np

# GLSL type -> (numpy base type, shape, std140 alignment, size)
SCALARS = {
    "float": (np.float32, (), 4, 4),
    "uint": (np.uint32, (), 4, 4),
    "int": (np.int32, (), 4, 4),
    "vec2": (np.float32, (2,), 8, 8),
    "vec3": (np.float32, (3,), 16, 12),
    "vec4": (np.float32, (4,), 16, 16),
    "uvec4": (np.uint32, (4,), 16, 16),
    "ivec4": (np.int32, (4,), 16, 16),
    # matrices as GLSL stores them: column-major, so a numpy (4, 4) field holds the transpose (M.T)
    "mat4": (np.float32, (4, 4), 16, 64),
}


def _round(n: int, to: int) -> int:
    return -(-n // to) * to


class Struct:
    """A std140 struct. Fields: (name, GLSL type or Struct[, array length]), with a trailing comment optional."""

    def __init__(self, name: str, fields, doc: dict | None = None):
        self.name, self.fields, self.doc = name, list(fields), dict(doc or {})
        names, formats, offsets = [], [], []
        off = 0
        for field in self.fields:
            fname, ftype, count = (tuple(field) + (None,))[:3]
            if isinstance(ftype, Struct):
                align, size, fmt = 16, _round(ftype.dtype.itemsize, 16), ftype.dtype
            else:
                base, shape, align, size = SCALARS[ftype]
                fmt = np.dtype((base, shape)) if shape else np.dtype(base)
            if count is not None:  # std140 arrays: every element aligned and padded to 16 bytes
                align, size = 16, _round(size, 16)
                if fmt.itemsize != size:
                    raise ValueError(f"{name}.{fname}: std140 arrays of {ftype} need padding this class lacks")
                fmt = np.dtype((fmt, (count,)))
                size *= count
            off = _round(off, align)
            names.append(fname)
            formats.append(fmt)
            offsets.append(off)
            off += size
        self.dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": _round(off, 16)})

    @property
    def size(self) -> int:
        return self.dtype.itemsize

    def glsl(self) -> str:
        lines = [f"struct {self.name} {{"]
        for field in self.fields:
            fname, ftype, count = (tuple(field) + (None,))[:3]
            tname = ftype.name if isinstance(ftype, Struct) else ftype
            decl = f"    {tname} {fname}" + (f"[{count}]" if count is not None else "") + ";"
            note = self.doc.get(fname)
            lines.append(f"{decl:<36}// {note}" if note else decl)
        lines.append("};")
        return "\n".join(lines)
