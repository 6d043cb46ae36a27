"""Writing output files so that nothing is lost: every file the engine writes goes to a temporary file in the same
folder and is renamed over the target only once it is complete, so a crash, a kill or a full disk leaves the old file
or the new one, never a part. Errors name the path; temporaries of writers that died are removed by the next write,
and a run removes those of its own targets left by a killed run (`remove_stale_temporaries`). A writer holds an
advisory lock (flock) on its temporary until the rename, which tells a live writer's temporary from a dead one's.
"""

from __future__ import annotations

import errno
import os
import re
import stat
import tempfile
from collections.abc import Iterable
from pathlib import Path

try:
    import fcntl  # POSIX only: the writers' locks (elsewhere none, see remove_stale_temporaries)
except ImportError:  # pragma: no cover - not POSIX: no locks; only temporaries of dead writers are removed
    fcntl = None  # type: ignore[assignment]

from .errors import ConfigError, EngineError, shown

_TMP_SUFFIX = ".tmp"
#: Our temporaries' names: `.<target name>.part-<pid>-<mkstemp's random part>.tmp`.
_TEMPORARY = re.compile(r"\.(?P<target>.+)\.part-(?P<pid>\d{1,10})-[A-Za-z0-9_]{1,32}\.tmp", re.S)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_MODE = 0o666 & ~_umask()  # what open() would have given a new file


def _prefix(path: Path) -> str:
    return f".{path.name}.part-"


def _remove_stale(path: Path):
    """Temporaries for `path` left by writers that no longer run (their pid is in the name)."""
    try:
        names = os.listdir(path.parent or ".")
    except OSError:
        return
    prefix = _prefix(path)
    for name in names:
        if not (name.startswith(prefix) and name.endswith(_TMP_SUFFIX)):
            continue
        pid = name[len(prefix) :].split("-", 1)[0]
        if pid.isdigit() and not running(int(pid)):
            try:
                os.unlink(path.parent / name)
            except OSError:
                pass


def remove_stale_temporaries(targets: Iterable[os.PathLike[str] | str], before: float) -> list[Path]:
    """Remove the temporaries that writes of `targets` left when their writer was killed; returns those removed.

    Conservative: only files named as our temporaries of one of the targets (`.NAME.part-PID-RANDOM.tmp`), in the
    targets' own folders (not below), regular files of this user, last modified before `before` (the calling run's
    start, `time.time()`), and not locked by a live writer (`atomic_write` holds a lock until its rename). Without
    locks (not POSIX), also only those whose writer's pid no longer runs."""
    wanted: dict[Path, set[str]] = {}
    for t in targets:
        path = Path(os.fspath(t))
        wanted.setdefault(path.parent, set()).add(path.name)
    removed = []
    for folder, names in wanted.items():
        try:
            entries = os.listdir(folder)
        except OSError:
            continue
        for name in entries:
            m = _TEMPORARY.fullmatch(name)
            if m is None or m.group("target") not in names:
                continue
            if fcntl is None and running(int(m.group("pid"))):
                continue
            if _remove_if_stale(folder / name, before):
                removed.append(folder / name)
    return removed


def _remove_if_stale(path: Path, before: float) -> bool:
    try:
        st = os.lstat(path)
        if not stat.S_ISREG(st.st_mode) or st.st_uid != os.getuid() or st.st_mtime >= before:
            return False
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError:
        return False
    try:
        now = os.fstat(fd)
        if (now.st_dev, now.st_ino) != (st.st_dev, st.st_ino):
            return False  # replaced since it was looked at
        if fcntl is not None:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # a live writer holds it: BlockingIOError
        os.unlink(path)
        return True
    except OSError:
        return False
    finally:
        os.close(fd)


def _lock(fd: int) -> None:
    """The writer's lock on its temporary (see remove_stale_temporaries); best effort."""
    if fcntl is not None:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            pass


def running(pid) -> bool:
    """Is a process with this id alive (one of another user counts as alive)?"""
    if not isinstance(pid, int) or pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _reason(exc: OSError) -> str:
    if exc.errno == errno.ENOSPC:
        return "no space left on the device"
    if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        return "permission denied (read-only folder or file system)"
    return exc.strerror or str(exc)


def atomic_write(path, write, what: str = "file") -> Path:
    """Write `path` through `write(binary_file)`: to a temporary file in the same folder, flushed to disk, then
    renamed over `path`. On any failure the temporary is removed, `path` is left as it was, and an OSError becomes an
    EngineError naming the path and the reason."""
    path = Path(os.fspath(path))
    _remove_stale(path)
    try:
        fd, tmp = tempfile.mkstemp(
            prefix=f"{_prefix(path)}{os.getpid()}-",
            suffix=_TMP_SUFFIX,
            dir=str(path.parent) if str(path.parent) else ".",
        )
    except OSError as exc:
        raise EngineError(f"{path}: cannot write {what}: {_reason(exc)}") from None
    try:
        _lock(fd)
        with os.fdopen(fd, "wb") as f:  # closed (and the lock let go) only once renamed
            write(f)
            f.flush()
            os.fsync(f.fileno())
            os.fchmod(f.fileno(), _MODE)
            os.replace(tmp, path)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        if isinstance(exc, OSError):
            raise EngineError(f"{path}: cannot write {what}: {_reason(exc)}") from None
        raise
    return path


def atomic_write_bytes(path, data: bytes, what: str = "file") -> Path:
    return atomic_write(path, lambda f: f.write(data), what)


def atomic_write_text(path, text: str, what: str = "file") -> Path:
    return atomic_write(path, lambda f: f.write(text.encode("utf-8")), what)


def check_writable(path, what: str = "file") -> Path:
    """Fail early, before work that a failed write would lose: `path`'s folder exists and a file can be created in it
    (probed, so that read-only file systems are found even when running as root)."""
    path = Path(os.fspath(path))
    folder = path.parent if str(path.parent) else Path(".")
    try:
        if "\0" in str(path):
            raise ValueError
        os.fsencode(path)
    except (UnicodeError, ValueError):  # a NUL, or text no file name can hold (a lone surrogate from Python)
        raise ConfigError(f"{shown(path)}: not a valid file name") from None
    if path.is_dir():
        raise ConfigError(f"{path}: is a folder, not {'an' if what[:1] in 'aeiou' else 'a'} {what}")
    if not folder.is_dir():
        raise ConfigError(f"{path}: cannot write {what}: no folder {str(folder)!r}")
    try:
        fd, probe = tempfile.mkstemp(prefix=f"{_prefix(path)}{os.getpid()}-", suffix=_TMP_SUFFIX, dir=str(folder))
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot write {what}: {_reason(exc)}") from None
    return path
