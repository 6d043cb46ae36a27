"""What a compute pass is: a shader, its bindings by name, its specialization constants by name, and the frame
resources it reads and writes.

    class LightingPass(ComputePass):
        shader = "lighting.comp"
        bindings = {"frame": read("uniform", "frame"), "g_albedo": read("image", "albedo"),
                    "out_color": write("image", "color"), ...}

Binding numbers, descriptor types and set layouts come from the shader's SPIR-V (engine/vk/reflect.py); the
declaration is checked against it when the pipeline is made and on every hot reload, so a shader and its pass
cannot drift apart silently. The reads and writes go to the Recorder, which derives the barriers between passes.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import ShaderError
from ..vk import ComputePipeline, DescriptorSet, Recorder
from ..vk.reflect import Interface, reflect

ACCESS = ("read", "write", "read_write")


@dataclass(frozen=True)
class Use:
    """One binding of a pass: its descriptor kind (engine.vk.reflect.DESCRIPTOR_TYPES), the frame resource bound
    there ("" when the pass binds it itself) and what the shader does to it."""

    kind: str
    resource: str = ""
    access: str = "read"


def read(kind: str, resource: str = "") -> Use:
    return Use(kind, resource, "read")


def write(kind: str, resource: str = "") -> Use:
    return Use(kind, resource, "write")


def update(kind: str, resource: str = "") -> Use:
    return Use(kind, resource, "read_write")


def check_interface(shader: str, declared: dict, interface: Interface, set_index: int = 0):
    """A ShaderError naming every binding where the declaration and the SPIR-V's set `set_index` disagree."""
    actual = interface.set(set_index)
    problems = []
    for name in sorted(set(declared) - set(actual)):
        problems.append(f"{name} is declared but the shader has no such binding in set {set_index}")
    for name in sorted(set(actual) - set(declared)):
        b = actual[name]
        problems.append(f"binding {b.binding} ({name}, {b.kind}) is not declared by the pass")
    for name in sorted(set(declared) & set(actual)):
        want, got = declared[name], actual[name]
        if want.kind != got.kind:
            problems.append(f"{name}: declared {want.kind}, the shader has {got.kind}")
        elif want.access != got.access:
            problems.append(f"{name}: declared {want.access}, the shader's access is {got.access}")
    if problems:
        raise ShaderError(f"{shader}: " + "; ".join(problems))


class ComputePass:
    """A compute shader run over the frame: subclasses set `name`, `shader`, `bindings` (set 0) and override
    `constants` (specialization constants by name) and `record`."""

    name = ""
    shader = ""
    bindings: dict = {}

    def __init__(self, ctx, library, resources: dict, shared_sets=()):
        """`resources`: frame resource name -> Buffer / Image; `shared_sets`: descriptor sets 1.. (the scene BVH)."""
        self.ctx, self.library, self.shared_sets = ctx, library, tuple(shared_sets)
        spirv = library.get(self.shader)
        self.interface = reflect(spirv, self.shader)
        check_interface(self.shader, self.bindings, self.interface)
        self.set = DescriptorSet(ctx, self.interface.set(0).values())
        self.spirv = spirv  # the current pipeline's SPIR-V (hot reload may hold newer SPIR-V that was refused)
        self.values = dict(self.constants(ctx))
        self.pipeline = ComputePipeline(
            ctx,
            spirv,
            [self.set, *self.shared_sets],
            push_size=self.interface.push_size,
            spec=self.interface.specialization(self.values, self.shader) or None,
            name=self.name,
        )
        self.bind(resources)

    def constants(self, ctx) -> dict:
        """Specialization constants by name for this device (default: the shader's own defaults)."""
        return {}

    # ---- resources ------------------------------------------------------------------------
    @property
    def shaders(self) -> tuple:
        return (self.shader,)

    def bind(self, resources: dict, targets=None):
        """Bind every declared frame resource (after the targets were made or re-made)."""
        self.resources = resources
        for binding, use in self.bindings.items():
            if use.resource:
                self.set.bind(binding, resources[use.resource])

    @property
    def reads(self) -> list:
        return [self.resources[u.resource] for u in self.bindings.values() if u.resource and u.access != "write"]

    @property
    def writes(self) -> list:
        return [self.resources[u.resource] for u in self.bindings.values() if u.resource and u.access != "read"]

    # ---- pipeline -------------------------------------------------------------------------
    def reload(self, library):
        """New SPIR-V from hot reload: used only when it still matches the declaration (else a ShaderError, and the
        last good pipeline stays)."""
        spirv = library.get(self.shader)
        interface = reflect(spirv, self.shader)
        check_interface(self.shader, self.bindings, interface)
        for index in range(len(self.shared_sets) + 1):  # the set layouts the pipeline layout was made with
            if interface.set(index) != self.interface.set(index):
                changed = set(interface.set(index).items()) ^ set(self.interface.set(index).items())
                names = ", ".join(sorted({name for name, _ in changed}))
                raise ShaderError(
                    f"{self.shader}: set {index}'s layout changed ({names}: binding numbers or array "
                    "sizes); restart to use it"
                )
        if interface.sets() != self.interface.sets() or interface.push_size != self.interface.push_size:
            raise ShaderError(
                f"{self.shader}: its sets or push constants changed (sets {interface.sets()}, "
                f"{interface.push_size} bytes of push constants); restart to use it"
            )
        spec = interface.specialization(self.values, self.shader) or None
        old = self.pipeline.spec
        self.pipeline.spec = spec
        try:
            self.pipeline.rebuild(spirv)
        except BaseException:
            self.pipeline.spec = old
            raise
        self.interface, self.spirv = interface, spirv

    def specialize(self, **values):
        """Re-create the pipeline with these constants changed (by name), where they differ from the current ones;
        on failure the old pipeline and constants stay."""
        merged = {**self.values, **values}
        if merged == self.values:
            return
        self.pipeline.specialize(self.spirv, self.interface.specialization(merged, self.shader))
        self.values = merged

    def dispatch(self, rec: Recorder, groups, push=None, sets=None, reads=None, writes=None):
        """Record one dispatch (the declared reads and writes unless given)."""
        rec.dispatch(
            self.pipeline,
            [sets or self.set, *self.shared_sets],
            groups,
            push=push,
            reads=self.reads if reads is None else reads,
            writes=self.writes if writes is None else writes,
        )

    @staticmethod
    def tiles(width: int, height: int, depth: int = 1) -> tuple:
        """Workgroups of 8x8 pixels over an image."""
        return (width + 7) // 8, (height + 7) // 8, depth
