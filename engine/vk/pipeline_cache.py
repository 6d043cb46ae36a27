"""A VkPipelineCache kept on disk between processes, so a second run skips the driver's shader compiles.

One file per device and driver: `$XDG_CACHE_HOME/hybrid/pipelines/<key>.bin` (default `~/.cache/hybrid`), where the
key hashes the vendor, device, driver version and the driver's pipelineCacheUUID. The driver's own cache entries
are keyed by the SPIR-V and its constants, so new shaders add entries and never reuse stale ones.

The file is loaded only when it is a regular file owned by this user, not writable by group or others, and its
recorded SHA-256 matches its payload; anything else is ignored (and replaced on the next save). Saved at context
close, atomically (a temporary file renamed into place), with a private mode whatever the umask, and only when the
driver has entries to keep (lavapipe in Mesa 22.3 keeps none: its data is the 32-byte header alone).

$HYBRID_PIPELINE_CACHE=0 turns it off; without a home directory there is no cache.
"""

from __future__ import annotations

import hashlib
import os
import stat
import tempfile
from pathlib import Path

import vulkan as vk

ENV = "HYBRID_PIPELINE_CACHE"
MAGIC = b"HYBRIDPC1\n"  # this file's format: MAGIC, the payload's SHA-256 (32 bytes), the payload
HEADER_BYTES = 32  # VkPipelineCacheHeaderVersionOne: a payload of no more holds no pipelines
MAX_BYTES = 256 << 20  # a larger file is not ours to trust (nor to read into memory)


def cache_dir() -> Path | None:
    """$XDG_CACHE_HOME/hybrid/pipelines (default ~/.cache/hybrid/pipelines); None without a home."""
    base = os.environ.get("XDG_CACHE_HOME")
    if base:
        return Path(base) / "hybrid" / "pipelines"
    try:
        return Path.home() / ".cache" / "hybrid" / "pipelines"
    except RuntimeError:
        return None


def enabled() -> bool:
    return os.environ.get(ENV, "1").strip().lower() not in ("0", "false", "no", "off")


def cache_path(properties) -> Path | None:
    """The file of this device and driver (`properties`: VkPhysicalDeviceProperties)."""
    where = cache_dir()
    if where is None or not enabled():
        return None
    uuid = vk.ffi.buffer(properties.pipelineCacheUUID)[:]
    ident = b"%d:%d:%d:" % (properties.vendorID, properties.deviceID, properties.driverVersion) + uuid
    return where / f"{hashlib.sha256(ident).hexdigest()[:24]}.bin"


def read_trusted(path: Path) -> bytes:
    """The payload of `path` if it is ours and intact, else b"" (a missing, foreign, shared or damaged file)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | getattr(os, "O_NONBLOCK", 0))
    except OSError:
        return b""
    with os.fdopen(fd, "rb") as f:
        st = os.fstat(f.fileno())
        if not stat.S_ISREG(st.st_mode) or st.st_uid != os.getuid() or st.st_mode & 0o022 or st.st_size > MAX_BYTES:
            return b""
        raw = f.read(MAX_BYTES + 1)
    if not raw.startswith(MAGIC) or len(raw) < len(MAGIC) + 32:
        return b""
    digest, payload = raw[len(MAGIC) : len(MAGIC) + 32], raw[len(MAGIC) + 32 :]
    return payload if hashlib.sha256(payload).digest() == digest else b""


def write_private(path: Path, payload: bytes) -> None:
    """Write MAGIC + SHA-256 + payload to `path` atomically, the folder 0700 and the file 0600."""
    path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".pc-", suffix=".tmp")  # mkstemp: mode 0600
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(MAGIC + hashlib.sha256(payload).digest() + payload)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


class PipelineCache:
    """The context's VkPipelineCache: filled from disk when made, written back by `save()`."""

    def __init__(self, device, properties):
        self.device = device
        self.path = cache_path(properties)
        self.loaded = read_trusted(self.path) if self.path is not None else b""
        self.handle = self._create(self.loaded)

    def _create(self, data: bytes):
        keep = vk.ffi.from_buffer(data) if data else vk.ffi.NULL
        try:
            return vk.vkCreatePipelineCache(
                self.device, vk.VkPipelineCacheCreateInfo(initialDataSize=len(data), pInitialData=keep), None
            )
        except vk.VkError:
            if not data:
                raise
            self.loaded = b""  # the driver refused the data: start empty
            return self._create(b"")

    def data(self) -> bytes:
        """What the driver would keep now."""
        get = vk.lib.vkGetPipelineCacheData
        size = vk.ffi.new("size_t *")
        if get(self.device, self.handle, size, vk.ffi.NULL) != vk.VK_SUCCESS or size[0] == 0:
            return b""
        buf = vk.ffi.new("char[]", size[0])
        if get(self.device, self.handle, size, buf) != vk.VK_SUCCESS:
            return b""
        return vk.ffi.buffer(buf, size[0])[:]

    def save(self) -> None:
        """Write the cache back where it gained entries; a failure to write only loses the speed-up."""
        if self.path is None:
            return
        payload = self.data()
        if len(payload) <= HEADER_BYTES or payload == self.loaded:
            return
        try:
            write_private(self.path, payload)
        except OSError:
            pass

    def destroy(self) -> None:
        if self.handle is not None:
            vk.vkDestroyPipelineCache(self.device, self.handle, None)
            self.handle = None
