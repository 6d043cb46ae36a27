"""The architecture as a contract: layers and their imports, Vulkan only in engine/vk, the limits on a function's
size and where they may be waived, and the passes' declarations against their shaders' SPIR-V (docs/architecture.md
describes the layers; tests/test_style.py runs ruff, which measures the functions)."""

import ast
import re
import struct
from pathlib import Path

import pytest

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10 (tomli is in the dev extra)
    import tomli as tomllib

from engine.errors import ShaderError
from engine.passes.accumulate import AccumulatePass
from engine.passes.ao import AOPass
from engine.passes.base import check_interface, read, write
from engine.passes.cull import CullPass
from engine.passes.debug_view import DebugViewPass
from engine.passes.denoise import DenoisePass
from engine.passes.gbuffer import ResolvePass
from engine.passes.interface import FRAME, GLSL_PATH, glsl_text
from engine.passes.lighting import LightingPass
from engine.passes.shadows import ShadowPass
from engine.shaders import ShaderLibrary
from engine.vk.reflect import reflect

ROOT = Path(__file__).resolve().parents[1]
ENGINE = ROOT / "engine"

#: Bottom to top. A module imports only from its own package or from lower layers (plus the PEERS edges).
LAYERS = [
    ["engine.errors", "engine._version", "engine.lifetime"],
    ["engine.limits", "engine.parallel", "engine.files", "engine.data", "engine.native", "engine.progress"],
    ["engine.vk", "engine.bvh", "engine.scene", "engine.shaders", "engine.passes.std140"],
    ["engine.passes.interface"],  # what host and shaders share: below the scene on the GPU, which it lays out
    ["engine.gpu"],
    ["engine.passes"],
    [
        "engine.settings",
        "engine.outputs",
        "engine.pointcloud",
        "engine.frame",
        "engine.steady",
        "engine.renderer",
        "engine.rt",
    ],
    ["engine.viewer", "engine.bench", "engine.sequence", "engine.batch"],
    ["engine.cli", "engine.__main__", "engine"],
]
PEERS = {
    ("engine.frame", "engine.settings"),
    ("engine.frame", "engine.outputs"),
    ("engine.frame", "engine.pointcloud"),
    ("engine.renderer", "engine.settings"),
    ("engine.renderer", "engine.frame"),
    ("engine.renderer", "engine.steady"),
    ("engine.__main__", "engine.cli"),
}
#: The ruff rules that measure a function (pyproject.toml): cyclomatic complexity, branches, statements.
SIZE_RULES = {"C901", "PLR0912", "PLR0915"}
PASSES = [LightingPass, DebugViewPass, AccumulatePass, DenoisePass, ShadowPass, AOPass, ResolvePass, CullPass]


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules() -> dict:
    return {module_name(p): p for p in sorted(ENGINE.rglob("*.py"))}


def resolve(mod: str, path: Path, node: ast.ImportFrom) -> list[str]:
    """Absolute engine module names an ImportFrom refers to (module and, where they are modules, its names)."""
    if node.level:
        base = mod.split(".") if path.name == "__init__.py" else mod.split(".")[:-1]
        base = base[: len(base) - node.level + 1]
        target = ".".join(base + ([node.module] if node.module else []))
    else:
        target = node.module or ""
    if not target.startswith("engine"):
        return []
    known = modules()
    subs = [f"{target}.{a.name}" for a in node.names if f"{target}.{a.name}" in known]
    return subs if len(subs) == len(node.names) else [target] + subs  # `from . import module` is no package use


def imports(mod: str, path: Path):
    """(engine modules imported at module level, imports inside functions as (line, names, is_engine))."""
    tree = ast.parse(path.read_text())
    top, inner = set(), []
    for node in ast.walk(tree):
        if not isinstance(node, (ast.Import, ast.ImportFrom)):
            continue
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
            engine_names = [n for n in names if n.startswith("engine")]
        else:
            names = [node.module or "."]
            engine_names = resolve(mod, path, node)
        if node.col_offset == 0:
            top.update(engine_names)
        else:
            inner.append((node.lineno, names, bool(engine_names)))
    return top, inner


def layer_of(mod: str):
    best = None
    for i, group in enumerate(LAYERS):
        for prefix in group:
            if (mod == prefix or mod.startswith(prefix + ".")) and (best is None or len(prefix) > len(best[1])):
                best = (i, prefix)
    return best


def test_every_engine_module_has_a_layer():
    assert [m for m in modules() if layer_of(m) is None] == []


def test_imports_go_down_the_layers():
    bad = []
    for mod, path in modules().items():
        here, here_group = layer_of(mod)
        top, _ = imports(mod, path)
        for target in top:
            there, there_group = layer_of(target)
            if there < here or there_group == here_group or (here_group, there_group) in PEERS:
                continue
            bad.append(f"{mod} imports {target} ({here_group} may not depend on {there_group})")
    assert bad == []


def test_the_tracer_does_not_import_the_passes():
    """engine.rt reaches the scene on the GPU through engine.gpu, not through the renderer's passes (the host/shader
    interface, engine.passes.interface, is an entry of its own below them)."""
    bad = []
    for mod, path in modules().items():
        if layer_of(mod)[1] != "engine.rt":
            continue
        bad += [f"{mod} imports {t}" for t in sorted(imports(mod, path)[0]) if layer_of(t)[1] == "engine.passes"]
    assert bad == []


def test_no_import_cycles():
    graph = {mod: {t for t in imports(mod, path)[0] if t in modules() and t != mod} for mod, path in modules().items()}
    state, cycles = {}, []

    def visit(node, stack):
        state[node] = "open"
        for nxt in sorted(graph[node]):
            if nxt.startswith(node + ".") and node in ("engine",):
                continue  # the package's own public API re-exports
            if state.get(nxt) == "open":
                cycles.append(" -> ".join(stack[stack.index(nxt) :] + [nxt]) if nxt in stack else nxt)
            elif nxt not in state:
                visit(nxt, stack + [nxt])
        state[node] = "done"

    for mod in sorted(graph):
        if mod not in state:
            visit(mod, [mod])
    assert cycles == []


def test_no_engine_imports_inside_functions_and_deferred_ones_say_why():
    bad = []
    for mod, path in modules().items():
        lines = path.read_text().splitlines()
        for lineno, names, is_engine in imports(mod, path)[1]:
            if is_engine:
                bad.append(f"{path.relative_to(ROOT)}:{lineno}: engine import inside a function: {names}")
            elif "#" not in lines[lineno - 1] and not lines[lineno - 2].strip().startswith("#"):
                bad.append(f"{path.relative_to(ROOT)}:{lineno}: deferred import of {names} without a comment why")
    assert bad == []


def test_vulkan_is_called_only_in_engine_vk():
    bad = []
    for mod, path in modules().items():
        if mod.startswith("engine.vk"):
            continue
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Import) and any(a.name.split(".")[0] == "vulkan" for a in node.names):
                bad.append(f"{path.relative_to(ROOT)}:{node.lineno}")
            if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "vulkan":
                bad.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert bad == []


def test_function_size_is_measured():
    """Functions, not modules, have a size limit: ruff's complexity, branch and statement rules are selected with
    finite thresholds (a module of many small functions may be as long as it needs)."""
    lint = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["ruff"]["lint"]
    selected = set(lint["select"])
    assert "C90" in selected and {"PLR0912", "PLR0915"} <= selected, lint["select"]
    assert not SIZE_RULES & set(lint.get("ignore", []))
    assert 0 < lint["mccabe"]["max-complexity"] <= 25
    assert 0 < lint["pylint"]["max-branches"] <= 25 and 0 < lint["pylint"]["max-statements"] <= 100


def test_size_limits_are_waived_only_in_pyproject():
    """A function over a limit is listed in pyproject.toml's per-file-ignores with its reason, where all such
    exceptions can be read at once, not waived by a `# noqa` next to it."""
    noqa = re.compile(r"#\s*(ruff:\s*)?noqa\b[^#\n]*\b(" + "|".join(sorted(SIZE_RULES)) + r")\b")
    bad = []
    for folder in ("engine", "tests", "tools", "examples"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            for lineno, line in enumerate(path.read_text().splitlines(), 1):
                if noqa.search(line):
                    bad.append(f"{path.relative_to(ROOT)}:{lineno}: {line.strip()}")
    assert bad == []


# ---- passes against their shaders --------------------------------------------------------------------------------
@pytest.mark.parametrize("cls", PASSES, ids=lambda c: c.__name__)
def test_pass_declarations_match_the_committed_spirv(cls):
    """Every binding of set 0 declared with the shader's name, descriptor kind and access; nothing undeclared."""
    lib = ShaderLibrary()
    check_interface(cls.shader, cls.bindings, reflect(lib.get(cls.shader), cls.shader))


@pytest.mark.parametrize("cls", [ShadowPass, AOPass, DenoisePass, ResolvePass], ids=lambda c: c.__name__)
def test_pass_constants_exist_in_the_shader(cls):
    """The specialization constants a pass sets by name are the shader's (a typo would be a ShaderError)."""
    lib = ShaderLibrary()
    interface = reflect(lib.get(cls.shader), cls.shader)
    wanted = {
        ShadowPass: {"WORK_SHARES", "BVH_STACK_REGS", "BVH_WIDE", "BVH_COMPRESSED", "BVH_IMAGE_FETCH"},
        AOPass: {"WORK_SHARES", "BVH_STACK_REGS", "BVH_POSTPONE_LEAVES"},
        DenoisePass: {"DENOISE_TEXEL", "WORK_SHARES"},
        ResolvePass: {"TEXTURE_ARRAYS"},
    }[cls]
    assert wanted <= set(interface.constants)


def test_a_declaration_that_disagrees_with_the_shader_is_refused_by_name():
    lib = ShaderLibrary()
    interface = reflect(lib.get("lighting.comp"), "lighting.comp")
    wrong_kind = {**LightingPass.bindings, "masks": read("image", "masks.final")}
    with pytest.raises(ShaderError, match="lighting.comp: masks: declared image, the shader has buffer"):
        check_interface("lighting.comp", wrong_kind, interface)
    wrong_access = {**LightingPass.bindings, "out_hdr": read("image", "hdr")}
    with pytest.raises(ShaderError, match="out_hdr: declared read, the shader's access is write"):
        check_interface("lighting.comp", wrong_access, interface)
    missing = {k: v for k, v in LightingPass.bindings.items() if k != "ao"}
    with pytest.raises(ShaderError, match=r"binding 5 \(ao, buffer\) is not declared"):
        check_interface("lighting.comp", missing, interface)
    extra = {**LightingPass.bindings, "bloom": write("image", "hdr")}
    with pytest.raises(ShaderError, match="bloom is declared but the shader has no such binding"):
        check_interface("lighting.comp", extra, interface)


def test_unknown_specialization_constant_is_a_clear_error():
    lib = ShaderLibrary()
    interface = reflect(lib.get("denoise.comp"), "denoise.comp")
    assert interface.specialization({"DENOISE_TEXEL": True}) == {interface.constants["DENOISE_TEXEL"].id: True}
    with pytest.raises(ShaderError, match="no specialization constant 'DENOISE_TEXELS'"):
        interface.specialization({"DENOISE_TEXELS": True}, "denoise.comp")


def test_generated_interface_glsl_is_up_to_date():
    assert GLSL_PATH.read_text() == glsl_text(), "stale: run tools/compile_shaders.py"


def test_frame_block_layout_matches_the_shaders_std140():
    """The FRAME dtype's field offsets are the ones glslang gives the generated struct (OpMemberDecorate Offset)."""
    lib = ShaderLibrary()
    spirv = lib.get("lighting.comp")
    assert reflect(spirv).bindings[0].name == "frame"
    words = struct.unpack(f"<{len(spirv) // 4}I", spirv)
    offsets, i = [], 5
    while i < len(words):
        n, op = words[i] >> 16, words[i] & 0xFFFF
        if op == 72 and words[i + 3] == 35:  # OpMemberDecorate ... Offset
            offsets.append((words[i + 1], words[i + 2], words[i + 4]))
        i += n
    by_struct = {}
    for sid, member, off in offsets:
        by_struct.setdefault(sid, {})[member] = off
    want = [FRAME.dtype.fields[n][1] for n in FRAME.dtype.names]
    assert any([s[m] for m in sorted(s)] == want for s in by_struct.values())
