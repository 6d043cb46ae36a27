"""What a SPIR-V module declares: its descriptor bindings (set, number, type, count, access), its specialization
constants by name, and the size of its push constants.

Pipelines build their descriptor-set layouts and specialization data from this, so binding numbers and constant ids
are written once, in the GLSL. A binding is named by its GLSL variable; an anonymous block by its only member
(`buffer MasksRaw { float masks_raw[]; };` is "masks_raw"), else by its block name.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import vulkan as vk

from ..errors import ShaderError

MAGIC = 0x07230203

# opcodes
OP_NAME, OP_MEMBER_NAME = 5, 6
OP_TYPE_BOOL, OP_TYPE_INT, OP_TYPE_FLOAT, OP_TYPE_VECTOR, OP_TYPE_MATRIX = 20, 21, 22, 23, 24
OP_TYPE_IMAGE, OP_TYPE_SAMPLER, OP_TYPE_SAMPLED_IMAGE, OP_TYPE_ARRAY, OP_TYPE_RUNTIME_ARRAY = 25, 26, 27, 28, 29
OP_TYPE_STRUCT, OP_TYPE_POINTER = 30, 32
OP_CONSTANT = 43
OP_SPEC_TRUE, OP_SPEC_FALSE, OP_SPEC = 48, 49, 50
OP_VARIABLE = 59
OP_DECORATE, OP_MEMBER_DECORATE = 71, 72
# decorations
DEC_SPEC_ID, DEC_BLOCK, DEC_BUFFER_BLOCK, DEC_ARRAY_STRIDE, DEC_MATRIX_STRIDE = 1, 2, 3, 6, 7
DEC_NON_WRITABLE, DEC_NON_READABLE, DEC_BINDING, DEC_SET, DEC_OFFSET = 24, 25, 33, 34, 35
# storage classes
SC_UNIFORM_CONSTANT, SC_UNIFORM, SC_PUSH_CONSTANT, SC_STORAGE_BUFFER = 0, 2, 9, 12
DIM_BUFFER = 5
_TYPE_OPS = (
    OP_TYPE_BOOL,
    OP_TYPE_INT,
    OP_TYPE_FLOAT,
    OP_TYPE_VECTOR,
    OP_TYPE_MATRIX,
    OP_TYPE_IMAGE,
    OP_TYPE_SAMPLER,
    OP_TYPE_SAMPLED_IMAGE,
    OP_TYPE_ARRAY,
    OP_TYPE_RUNTIME_ARRAY,
    OP_TYPE_STRUCT,
    OP_TYPE_POINTER,
)

#: Descriptor types by their short names (the names pass declarations use).
DESCRIPTOR_TYPES = {
    "uniform": vk.VK_DESCRIPTOR_TYPE_UNIFORM_BUFFER,
    "buffer": vk.VK_DESCRIPTOR_TYPE_STORAGE_BUFFER,
    "image": vk.VK_DESCRIPTOR_TYPE_STORAGE_IMAGE,
    "texture": vk.VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER,
    "sampled_image": vk.VK_DESCRIPTOR_TYPE_SAMPLED_IMAGE,
    "sampler": vk.VK_DESCRIPTOR_TYPE_SAMPLER,
    "uniform_texel": vk.VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER,
    "storage_texel": vk.VK_DESCRIPTOR_TYPE_STORAGE_TEXEL_BUFFER,
}


@dataclass(frozen=True)
class Binding:
    name: str
    set: int
    binding: int
    kind: str  # a DESCRIPTOR_TYPES key
    count: int  # array length (1 for a single descriptor)
    access: str  # "read", "write" or "read_write" (what the shader may do to it)

    @property
    def descriptor_type(self) -> int:
        return DESCRIPTOR_TYPES[self.kind]


@dataclass(frozen=True)
class Constant:
    name: str
    id: int
    type: str  # "bool", "int", "uint" or "float"
    default: object


@dataclass(frozen=True)
class Interface:
    """A shader module's resource interface."""

    bindings: tuple  # Binding, sorted by (set, binding)
    constants: dict  # name -> Constant
    push_size: int  # bytes of the push-constant block (0: none)

    def set(self, index: int) -> dict:
        """name -> Binding of one descriptor set."""
        return {b.name: b for b in self.bindings if b.set == index}

    def sets(self) -> list[int]:
        return sorted({b.set for b in self.bindings})

    def merged(self, other: "Interface") -> "Interface":
        """The union of two stages' interfaces (a graphics pipeline's vertex and fragment shaders)."""
        by_key = {(b.set, b.binding): b for b in self.bindings}
        for b in other.bindings:
            old = by_key.get((b.set, b.binding))
            if old is not None and (old.kind, old.count) != (b.kind, b.count):
                raise ShaderError(
                    f"binding {b.set}.{b.binding}: {old.name} is a {old.kind} in one stage and "
                    f"{b.name} a {b.kind} in another"
                )
            if old is None or old.access != b.access:
                by_key[(b.set, b.binding)] = (
                    b if old is None else Binding(old.name, old.set, old.binding, old.kind, old.count, "read_write")
                )
        # (a graphics pipeline gives both stages one specialization map: an id must mean one constant in both)
        for name, c in other.constants.items():
            clash = [n for n, mine in self.constants.items() if mine.id == c.id and n != name]
            if clash:
                raise ShaderError(f"specialization constant id {c.id} is {clash[0]} in one stage and {name} in another")
        return Interface(
            tuple(sorted(by_key.values(), key=lambda b: (b.set, b.binding))),
            {**self.constants, **other.constants},
            max(self.push_size, other.push_size),
        )

    def specialization(self, values: dict, shader: str = "shader") -> dict:
        """{constant id: value} from {constant name: value}; an unknown name is a ShaderError."""
        out = {}
        for name, value in values.items():
            c = self.constants.get(name)
            if c is None:
                known = ", ".join(sorted(self.constants)) or "none"
                raise ShaderError(f"{shader}: no specialization constant {name!r} (it has: {known})")
            out[c.id] = float(value) if c.type == "float" else value
        return out


def _string(words, start) -> str:
    raw = struct.pack(f"<{len(words) - start}I", *words[start:])
    return raw.split(b"\0", 1)[0].decode("utf-8", "replace")


def reflect(spirv: bytes, name: str = "shader") -> Interface:
    """The resource interface of one SPIR-V module (a ShaderError if it is not SPIR-V)."""
    module = _Module(spirv, name)
    bindings, push_size = [], 0
    for ptr_type, var, storage in module.variables:
        pointee = module.types[ptr_type][1][1]
        if storage == SC_PUSH_CONSTANT:
            push_size = max(push_size, module.size_of(pointee))
        elif DEC_BINDING in module.decorations.get(var, {}):
            bindings.append(module.binding(var, pointee, storage))
    return Interface(tuple(sorted(bindings, key=lambda b: (b.set, b.binding))), module.spec_constants(), push_size)


class _Module:
    """The instructions of a SPIR-V module that reflection reads (names, decorations, types, constants, variables),
    and what they say about one variable, type or constant."""

    def __init__(self, spirv: bytes, name: str):
        if len(spirv) < 20 or len(spirv) % 4:
            raise ShaderError(f"{name}: not a SPIR-V binary")
        words = struct.unpack(f"<{len(spirv) // 4}I", spirv)
        if words[0] != MAGIC:
            raise ShaderError(f"{name}: not a SPIR-V binary")
        self.name = name
        self.names, self.member_names, self.decorations, self.member_decorations = {}, {}, {}, {}
        self.types, self.constants, self.variables, self.specs = {}, {}, [], {}
        i = 5
        while i < len(words):
            count, op = words[i] >> 16, words[i] & 0xFFFF
            if count == 0:
                raise ShaderError(f"{name}: malformed SPIR-V (zero-length instruction at word {i})")
            self._read(op, words[i : i + count])
            i += count

    def _read(self, op: int, ins) -> None:
        """Record one instruction (`ins`: its words, the opcode word first) if reflection needs it."""
        if op == OP_NAME:  # the first name wins: a local `const int x = SPEC;` names the same id again
            self.names.setdefault(ins[1], _string(ins, 2))
        elif op == OP_MEMBER_NAME:
            self.member_names.setdefault(ins[1], {})[ins[2]] = _string(ins, 3)
        elif op == OP_DECORATE:
            self.decorations.setdefault(ins[1], {})[ins[2]] = ins[3] if len(ins) > 3 else True
        elif op == OP_MEMBER_DECORATE:
            members = self.member_decorations.setdefault(ins[1], {})
            members.setdefault(ins[2], {})[ins[3]] = ins[4] if len(ins) > 4 else True
        elif op in _TYPE_OPS:
            self.types[ins[1]] = (op, tuple(ins[2:]))
        elif op == OP_CONSTANT:
            self.constants[ins[2]] = ins[3]
        elif op in (OP_SPEC_TRUE, OP_SPEC_FALSE, OP_SPEC):
            self.specs[ins[2]] = (op, ins[1], ins[3] if op == OP_SPEC else op == OP_SPEC_TRUE)
        elif op == OP_VARIABLE:
            self.variables.append((ins[1], ins[2], ins[3]))

    def scalar_name(self, type_id) -> str:
        op, args = self.types[type_id]
        if op == OP_TYPE_BOOL:
            return "bool"
        if op == OP_TYPE_FLOAT:
            return "float"
        return "int" if args[1] else "uint"

    def size_of(self, type_id) -> int:
        """Bytes of a push-constant block or member."""
        op, args = self.types[type_id]
        if op in (OP_TYPE_INT, OP_TYPE_FLOAT):
            return args[0] // 8
        if op == OP_TYPE_VECTOR:
            return self.size_of(args[0]) * args[1]
        if op == OP_TYPE_MATRIX:
            stride = 16
            return stride * args[1]
        if op == OP_TYPE_ARRAY:
            stride = self.decorations.get(type_id, {}).get(DEC_ARRAY_STRIDE, self.size_of(args[0]))
            return stride * self.constants[args[1]]
        if op == OP_TYPE_STRUCT:
            offs = self.member_decorations.get(type_id, {})
            return max((offs.get(m, {}).get(DEC_OFFSET, 0) + self.size_of(t) for m, t in enumerate(args)), default=0)
        raise ShaderError(f"{self.name}: cannot size a push-constant member of SPIR-V type op {op}")

    def binding(self, var, pointee, storage) -> Binding:
        """The descriptor binding of variable `var` (which has a Binding decoration), of type `pointee`."""
        dec = self.decorations[var]
        count, base = 1, pointee
        while self.types[base][0] in (OP_TYPE_ARRAY, OP_TYPE_RUNTIME_ARRAY):
            op, args = self.types[base]
            count = count * self.constants[args[1]] if op == OP_TYPE_ARRAY else 0
            base = args[0]
        if self.types[base][0] == OP_TYPE_STRUCT:
            kind, access, label = self._block(var, base, storage)
        else:
            kind, access = self._opaque(base, dec)
            label = self.names.get(var, "")
        return Binding(
            label or f"binding{dec[DEC_BINDING]}", dec.get(DEC_SET, 0), dec[DEC_BINDING], kind, count, access
        )

    def _block(self, var, base, storage) -> tuple[str, str, str]:
        """(kind, access, name) of a uniform or storage block: named by its variable, else by its only member, else
        by its block name."""
        args = self.types[base][1]
        members = self.member_decorations.get(base, {})
        access = "read_write"
        if storage == SC_UNIFORM and DEC_BLOCK in self.decorations.get(base, {}):
            kind, access = "uniform", "read"
        else:
            kind = "buffer"
            flags = [members.get(m, {}) for m in range(len(args))]
            if flags and all(DEC_NON_WRITABLE in f for f in flags):
                access = "read"
            elif flags and all(DEC_NON_READABLE in f for f in flags):
                access = "write"
        label = (
            self.names.get(var)
            or (self.member_names.get(base, {}).get(0) if len(args) == 1 else None)
            or self.names.get(base, "")
        )
        return kind, access, label

    def _opaque(self, base, dec) -> tuple[str, str]:
        """(kind, access) of an image, sampler or texel buffer binding (`dec`: the variable's decorations)."""
        op, args = self.types[base]
        access = "read_write"
        if op == OP_TYPE_SAMPLED_IMAGE:  # a sampled image, or a texel fetch from a uniform texel buffer
            dim = self.types[args[0]][1][1]
            kind, access = ("uniform_texel" if dim == DIM_BUFFER else "texture"), "read"
        elif op == OP_TYPE_SAMPLER:
            kind, access = "sampler", "read"
        elif op == OP_TYPE_IMAGE:
            dim, sampled = args[1], args[5]
            if dim == DIM_BUFFER:
                kind = "storage_texel" if sampled == 2 else "uniform_texel"
            else:
                kind = "image" if sampled == 2 else "sampled_image"
            if sampled != 2:
                access = "read"
        else:
            raise ShaderError(f"{self.name}: binding {dec[DEC_BINDING]} has an unsupported type (SPIR-V op {op})")
        if access == "read_write":
            if DEC_NON_WRITABLE in dec:
                access = "read"
            elif DEC_NON_READABLE in dec:
                access = "write"
        return kind, access

    def spec_constants(self) -> dict:
        """name -> Constant of the specialization constants (those with a SpecId)."""
        consts = {}
        for cid, (op, type_id, value) in self.specs.items():
            dec = self.decorations.get(cid, {})
            if DEC_SPEC_ID not in dec:
                continue
            ctype = self.scalar_name(type_id)
            if op == OP_SPEC:
                value = (
                    struct.unpack("<f", struct.pack("<I", value))[0]
                    if ctype == "float"
                    else (struct.unpack("<i", struct.pack("<I", value))[0] if ctype == "int" else value)
                )
            cname = self.names.get(cid) or f"constant{dec[DEC_SPEC_ID]}"
            consts[cname] = Constant(cname, dec[DEC_SPEC_ID], ctype, value)
        return consts
