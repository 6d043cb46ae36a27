"""Shader sources, committed SPIR-V and its manifest, compilation with glslangValidator, hot reload.

Rendering normally loads the committed SPIR-V in `shaders/spv/` (in an installed package, its copy: engine/data.py)
and needs no compiler. The manifest
(`shaders/spv/manifest.json`) records, per shader, a hash of its source and of every file it
includes, so a test can tell when the committed SPIR-V is stale without comparing SPIR-V bytes.

With hot reload, `ShaderLibrary.poll()` looks at the GLSL files' modification times, recompiles
only the shaders whose source or includes changed (into a temporary folder, never into
`shaders/spv/`), and reports which shaders have new SPIR-V and which failed, with the compiler's
message.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import stat
import subprocess
import tempfile
from pathlib import Path

from .data import SHADERS_DIR
from .errors import ShaderError, shown
from .files import atomic_write_bytes, atomic_write_text

ROOT = SHADERS_DIR  # the checkout's shaders/, or the installed package's copy (engine/data.py)
GLSL_DIR = ROOT / "glsl"
SPV_DIR = ROOT / "spv"
MANIFEST = "manifest.json"
STAGES = (".vert", ".frag", ".comp")
TARGET_ENV = "vulkan1.2"
_INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"', re.M)


def shader_sources(glsl_dir: Path = GLSL_DIR) -> list[Path]:
    """Every compilable shader (by stage extension) in the folder, includes excluded; regular files only (or links
    to them): a FIFO or device named `*.comp` would block whoever opens it."""
    return sorted(p for p in Path(glsl_dir).iterdir() if p.suffix in STAGES and _regular(p))


def _regular(path) -> bool:
    try:
        return stat.S_ISREG(os.stat(path).st_mode)
    except (OSError, ValueError):
        return False


def read_source(path) -> str:
    """A GLSL file's text. Read as bytes and decoded as UTF-8 (ASCII is what glslang takes); a file that is not
    UTF-8 is a ShaderError naming the file, line and byte. Opened without blocking and read only if it is a
    regular file, so a FIFO put where a source was expected is refused instead of hanging its reader."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise ShaderError(f"{shown(path)}: cannot read: {exc.strerror or exc}") from None
    with os.fdopen(fd, "rb") as f:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise ShaderError(f"{shown(path)}: not a regular file")
        data = f.read()
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise ShaderError(
            f"{shown(path)}:{line}: not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start})"
        ) from None


def includes_of(path: Path, glsl_dir: Path, _seen=None) -> list[Path]:
    """Every file `path` includes, transitively (looked up next to the file, then in include/). A source that
    cannot be read as UTF-8 text is a ShaderError (read_source)."""
    seen = _seen if _seen is not None else set()
    out = []
    for name in _INCLUDE.findall(read_source(path)):
        for base in (Path(path).parent, Path(glsl_dir) / "include"):
            cand = (base / name).resolve()
            if cand.exists():
                break
        else:
            continue  # glslang will report the missing include with its own message
        if cand not in seen:
            seen.add(cand)
            out.append(cand)
            out.extend(includes_of(cand, glsl_dir, seen))
    return out


def source_hash(path: Path, glsl_dir: Path = GLSL_DIR) -> str:
    """sha256 over the shader's source and its includes (by name relative to glsl_dir, then content)."""
    h = hashlib.sha256()
    glsl_dir = Path(glsl_dir).resolve()
    for f in [Path(path).resolve()] + sorted(includes_of(path, glsl_dir)):
        h.update(str(f.relative_to(glsl_dir)).encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()


def glslang() -> str:
    exe = shutil.which("glslangValidator")
    if exe is None:
        raise ShaderError("glslangValidator not found (apt-get install glslang-tools)")
    return exe


def compile_shader(src: Path, out: Path, glsl_dir: Path = GLSL_DIR) -> None:
    """Compile one GLSL file to SPIR-V; raise ShaderError with the compiler's message on failure."""
    cmd = [
        glslang(),
        "-V",
        "--target-env",
        TARGET_ENV,
        "-I" + str(Path(glsl_dir) / "include"),
        "-o",
        str(out),
        str(src),
    ]
    try:
        # Its output quotes the source, which need not be UTF-8: decoded with replacement, never raising.
        res = subprocess.run(cmd, capture_output=True, text=True, errors="replace", timeout=120)
    except subprocess.TimeoutExpired:
        raise ShaderError(f"{src}: glslangValidator timed out") from None
    if res.returncode != 0:
        raise ShaderError(compiler_message(res.stdout + res.stderr, src))


_LOCATED = re.compile(r"^(?:ERROR|error):\s*(.+?):(\d+):\s*(.*)$")
_NOISE = ("compilation terminated", "compilation errors", "Missing entry point", "SPIR-V is not generated")


def compiler_message(output: str, src, max_lines: int = 6) -> str:
    """The useful part of glslangValidator's output: its located errors as `file:line: message`.

    glslang prints the file name, then `ERROR: file:line: 'token' : message` lines, then a summary and, after
    any compile error, a consequential link error ("Missing entry point"); only the located lines are kept (the
    first few, the rest counted). Without any, every ERROR line is kept; without those, the whole output."""
    located, other = [], []
    for line in output.splitlines():
        line = line.rstrip()
        m = _LOCATED.match(line)
        if m:
            path, lineno, text = m.groups()
            text = re.sub(r"^''\s*:\s*", "", text).strip()  # syntax errors carry an empty token
            text = re.sub(r"^('[^']*')\s*:\s+", r"\1: ", text)
            if text != "compilation terminated":
                located.append(f"{path}:{lineno}: {text}")
        elif "ERROR" in line and not any(n in line for n in _NOISE):
            other.append(line.replace("ERROR: ", "", 1).strip())
    lines = located or other
    if not lines:
        return f"{src}: glslangValidator failed: {output.strip() or 'no output'}"
    if len(lines) > max_lines:
        lines = lines[:max_lines] + [f"(+{len(lines) - max_lines} more)"]
    msg = "\n".join(lines)
    if not located:  # link errors name no file: say which shader
        msg = f"{src}: {msg}"
    return msg


def compile_all(glsl_dir: Path = GLSL_DIR, spv_dir: Path = SPV_DIR) -> dict:
    """Compile every shader into spv_dir and write the manifest; returns the manifest."""
    spv_dir.mkdir(parents=True, exist_ok=True)
    manifest = {}
    with tempfile.TemporaryDirectory(prefix="hybrid-compile-") as tmp:
        for src in shader_sources(glsl_dir):  # compiled aside, then each .spv replaced whole (engine.files)
            out = Path(tmp) / (src.name + ".spv")
            compile_shader(src, out, glsl_dir)
            atomic_write_bytes(spv_dir / (src.name + ".spv"), out.read_bytes(), "SPIR-V")
            manifest[src.name] = {
                "source_sha256": source_hash(src, glsl_dir),
                "includes": sorted(str(p.relative_to(Path(glsl_dir).resolve())) for p in includes_of(src, glsl_dir)),
            }
    atomic_write_text(spv_dir / MANIFEST, json.dumps(manifest, indent=2, sort_keys=True) + "\n", "shader manifest")
    return manifest


def stale_shaders(glsl_dir: Path = GLSL_DIR, spv_dir: Path = SPV_DIR) -> list[str]:
    """Names of shaders whose committed SPIR-V does not match their current sources (or is missing)."""
    try:
        manifest = json.loads((spv_dir / MANIFEST).read_text())
    except (OSError, ValueError):
        return ["<manifest missing or unreadable>"]
    stale = []
    names = {s.name for s in shader_sources(glsl_dir)}
    for src in shader_sources(glsl_dir):
        entry = manifest.get(src.name)
        if (
            entry is None
            or entry.get("source_sha256") != source_hash(src, glsl_dir)
            or not (spv_dir / (src.name + ".spv")).exists()
        ):
            stale.append(src.name)
    stale += sorted(n + " (no source)" for n in manifest if n not in names)
    return stale


def spv_temp_dir() -> tempfile.TemporaryDirectory:
    """A temporary folder for hot-reloaded SPIR-V, named hybrid-spv-<pid>-*. A process that dies (a crashed or
    killed viewer) cannot remove its own, so the folders of processes that no longer run are removed first (only
    this user's)."""
    tmp = tempfile.gettempdir()
    try:
        entries = list(os.scandir(tmp))
    except OSError:
        entries = []
    for entry in entries:
        m = _SPV_TEMP.fullmatch(entry.name)
        try:
            if m is None or not entry.is_dir(follow_symlinks=False) or entry.stat().st_uid != os.getuid():
                continue
        except OSError:
            continue
        if not _running(int(m.group(1))):
            shutil.rmtree(entry.path, ignore_errors=True)
    return tempfile.TemporaryDirectory(prefix=f"hybrid-spv-{os.getpid()}-", dir=tmp)


_SPV_TEMP = re.compile(r"hybrid-spv-(\d{1,10})-[^/]+")


def _running(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, OSError):  # another user's process, or not a pid: leave it
        return True
    return True


class ShaderLibrary:
    """Where pipelines get their SPIR-V. Committed SPIR-V by default; compiled on change with hot reload."""

    def __init__(self, glsl_dir=None, hot_reload: bool = False, spv_dir=None):
        self.glsl_dir = Path(glsl_dir) if glsl_dir is not None else GLSL_DIR
        self.spv_dir = Path(spv_dir) if spv_dir is not None else SPV_DIR
        self.hot_reload = hot_reload
        self.errors: dict[str, str] = {}
        self.versions: dict[str, int] = {}  # name -> how many times hot reload compiled it (new SPIR-V)
        self._compiled: dict[str, bytes] = {}
        self._tmp = None
        self._stamps: dict[str, float] = {}
        if not self.glsl_dir.is_dir() and hot_reload:
            raise ShaderError(f"{self.glsl_dir}: shader folder not found")
        if hot_reload:
            self._tmp = spv_temp_dir()
            self._stamps = self._scan()
            if glsl_dir is not None:  # a separate source folder: build it all now
                for src in shader_sources(self.glsl_dir):
                    self._try_compile(src)

    def get(self, name: str) -> bytes:
        """SPIR-V bytes for e.g. 'lighting.comp'."""
        if name in self._compiled:
            return self._compiled[name]
        path = self.spv_dir / (name + ".spv")
        try:
            return path.read_bytes()
        except OSError:
            raise ShaderError(f"{path}: SPIR-V not found (run tools/compile_shaders.py)") from None

    def _scan(self) -> dict[str, tuple]:
        # Size and inode besides the time: a file rewritten in place (or replaced) within one tick of a coarse
        # file-system clock still looks changed after a poll that saw it half written.
        stamps = {}
        for dirpath, _, files in os.walk(self.glsl_dir):
            for f in files:
                p = os.path.join(dirpath, f)
                try:
                    st = os.stat(p)
                except OSError:
                    continue
                if stat.S_ISREG(st.st_mode):  # only regular files are watched (a FIFO is never opened)
                    stamps[p] = (st.st_mtime_ns, st.st_size, st.st_ino)
        return stamps

    def _try_compile(self, src: Path) -> bool:
        out = Path(self._tmp.name) / (src.name + ".spv")
        try:
            includes_of(src, self.glsl_dir)  # the source and its includes are regular UTF-8 files (read_source)
            compile_shader(src, out, self.glsl_dir)
        except ShaderError as exc:
            self.errors[str(src)] = str(exc)
            return False
        self.errors.pop(str(src), None)
        self._compiled[src.name] = out.read_bytes()
        self.versions[src.name] = self.versions.get(src.name, 0) + 1
        return True

    def poll(self) -> set[str]:
        """Recompile shaders affected by changed files; return the names that have new SPIR-V.

        While the folder is missing nothing is compiled (the last good SPIR-V stays) and `errors` says so under the
        folder's path; once it is back, its files are compared with what was seen before it went."""
        if not self.hot_reload:
            return set()
        folder = str(self.glsl_dir)
        stamps = self._scan()
        try:
            sources = shader_sources(self.glsl_dir)
        except OSError:  # removed or renamed: keep the old stamps to compare its return with
            self.errors[folder] = f"{folder}: the shader folder is gone; hot reload resumes when it is back"
            return set()
        self.errors.pop(folder, None)
        changed = {Path(p).resolve() for p, t in stamps.items() if self._stamps.get(p) != t}
        changed |= {Path(p).resolve() for p in self._stamps if p not in stamps}
        self._stamps = stamps
        if not changed:
            return set()
        updated = set()
        for src in sources:
            try:
                deps = {src.resolve(), *includes_of(src, self.glsl_dir)}
            except ShaderError as exc:  # not UTF-8, not a regular file, or gone since the listing (a save by
                # rename, the folder going): the last good SPIR-V stays, the error shows; the next change retries
                if not src.exists():
                    self._stamps.pop(str(src), None)
                    continue
                self.errors[str(src)] = str(exc)
                continue
            if deps & changed or str(src) in self.errors:
                if self._try_compile(src):
                    updated.add(src.name)
        return updated

    def close(self):
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None
