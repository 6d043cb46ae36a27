"""One Vulkan device shared by several users: `Device` (the public `engine.Device`) and `Scope`, one user's share.

A `Scope` is what a Tracer or a Renderer on a shared context uses as its context: it passes everything through to
the `Context` (device, queue, limits, submit, the lock) but has its own command pool and its own list of objects to
destroy, so that closing the user frees what it made, recording its command buffers needs no lock shared with the
other users (Vulkan: a pool's buffers are recorded from one thread at a time), and the context stays for the others.
"""

from __future__ import annotations

import threading
import weakref
from typing import Any

import vulkan as vk

from ..lifetime import Closes
from ..errors import ConfigError
from .context import Context


class Scope:
    """One user's share of a `Context`: its own command pool and destroy list; anything else is the context's."""

    def __init__(self, ctx: Context, owner: str = ""):
        ctx.check_open(owner or "Scope")
        self.__dict__["parent"] = ctx  # (attribute reads fall through to the context: __getattr__)
        self.owner = owner
        self._destroy_stack: list = []
        self.pool = vk.vkCreateCommandPool(
            ctx.device,
            vk.VkCommandPoolCreateInfo(
                flags=vk.VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT, queueFamilyIndex=ctx.queue_family
            ),
            None,
        )
        self._open = True
        ctx.add_scope(self)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.__dict__["parent"], name)

    # the counters a resource updates on its context belong to the context
    @property
    def allocations(self) -> int:
        return self.parent.allocations

    @allocations.setter
    def allocations(self, value: int) -> None:
        with self.parent.lock:
            self.parent.allocations = value

    @property
    def root(self) -> Context:
        return self.parent

    @property
    def closed(self) -> bool:
        """Closed itself, or its context is."""
        return not self._open or self.parent.closed

    def check_open(self, what: str):
        if not self._open and not self.parent.closed:
            raise ConfigError(f"{what}: closed")
        self.parent.check_open(what)

    def defer_destroy(self, fn, *args):
        """Register a destructor to run when this scope closes (or its context does), newest first."""
        self._destroy_stack.append((fn, args))

    def allocate_command_buffer(self):
        return vk.vkAllocateCommandBuffers(
            self.parent.device,
            vk.VkCommandBufferAllocateInfo(
                commandPool=self.pool, level=vk.VK_COMMAND_BUFFER_LEVEL_PRIMARY, commandBufferCount=1
            ),
        )[0]

    def free_command_buffer(self, cmd):
        self.parent.forget_command_buffer(cmd)
        vk.vkFreeCommandBuffers(self.parent.device, self.pool, 1, [cmd])

    def close(self):
        """Wait for the device to finish what was submitted, then destroy this scope's objects, newest first."""
        ctx = self.parent
        with ctx.lock:
            if not self._open:
                return
            if not ctx.closed:
                try:
                    ctx.wait_idle()
                except Exception:  # a lost device: destroying its objects is still allowed
                    pass
            self.destroy_objects()
            ctx.remove_scope(self)

    def destroy_objects(self):
        """Destroy this scope's objects and its pool (the context calls it, under its lock, while the device is
        still there)."""
        if not self._open:
            return
        self._open = False
        if self.parent.hung:  # the GPU may still run what uses them: left to the driver (freed at process exit)
            self._destroy_stack.clear()
            return
        while self._destroy_stack:
            fn, args = self._destroy_stack.pop()
            fn(*args)
        vk.vkDestroyCommandPool(self.parent.device, self.pool, None)  # (frees its command buffers)
        self.pool = None


class Device(Closes):
    """A Vulkan device that Renderers, Tracers and RaycastingScenes share: one instance, one logical device, one
    queue, made once (opening a device takes a second or two; a Tracer on an open Device costs only its BVH build and
    upload).

        with engine.Device() as dev:                           # or engine.Device("H200"), engine.Device(0)
            a = engine.Tracer(v1, f1, device=dev)
            b = engine.Tracer(v2, f2, device=dev)
            r = engine.Renderer(640, 480, device=dev)
            ...                                                # any of them from any thread

    Each object on it keeps its own buffers, pipelines and command buffers and frees them when it is closed; the
    Device stays open for the others. What its objects share (the trace kernels, the Tracers' stream buffers: each
    query takes a set of those for its call, engine/rt/stream.py `SlotPool`) is the Device's, freed with it.
    Submissions to the one queue are serialized (each object also runs one call at a time), so objects on one Device
    may be used from different threads.

    `close()` (or the end of the `with` block) first waits for calls in progress on the objects still open on it,
    closes them (a later call on one raises `ConfigError` saying that its Device was closed), then frees the device.
    A closed Device refuses new objects with a `ConfigError`; closing twice is harmless.
    """

    def __init__(self, index_or_name: int | str | None = None, *, validation: bool = False):
        """Open a Vulkan device.

        Args:
            index_or_name: the device's index in `hybrid info`'s list or part of its name (default:
                $HYBRID_DEVICE, else discrete GPU > integrated > CPU).
            validation: turn the Khronos validation layer on (also $HYBRID_VALIDATION=1); its errors collect in
                `validation_errors`.

        Raises:
            ConfigError: no device matches `index_or_name`.
            VulkanError: no usable Vulkan device.
        """
        if index_or_name is not None and (isinstance(index_or_name, bool) or not isinstance(index_or_name, (int, str))):
            raise ConfigError(
                f"Device: index_or_name must be a device index or part of its name, got {type(index_or_name).__name__}"
            )
        self._lock = threading.Lock()  # the list of users only; never held while a user closes
        self._users: weakref.WeakSet[Any] = weakref.WeakSet()
        self._closed = False
        self.context = Context(device=index_or_name, validation=validation or None)

    @property
    def name(self) -> str:
        """The device's name, e.g. "NVIDIA H200" or "llvmpipe (LLVM 15.0.7, 256 bits)"."""
        return str(self.context.device_info["name"])

    @property
    def closed(self) -> bool:
        """Has `close()` run?"""
        return self._closed

    @property
    def users(self) -> int:
        """How many objects (Tracers, Renderers, a RaycastingScene's tracer) are open on it."""
        with self._lock:
            return sum(1 for u in list(self._users) if getattr(u, "ctx", None) is not None)

    @property
    def validation_errors(self) -> list[str]:
        """Error-severity validation messages so far (with validation on), of every object on this Device."""
        return self.context.validation_errors

    def _attach(self, user: Any, who: str) -> Scope:
        """A new `Scope` for `user` (a Tracer, a Renderer), which `close()` will close if it is still open then.
        `who` names the user in the error raised when this Device is closed."""
        with self._lock:
            if self._closed:
                raise ConfigError(f"{who}: its engine.Device is closed (make a new engine.Device)")
            self._users.add(user)
            return Scope(self.context, who)

    def _detach(self, user: Any) -> None:
        with self._lock:
            self._users.discard(user)

    def close(self) -> None:
        """Close the objects still open on this Device (after their calls in progress), then free the device."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            users = list(self._users)
            self._users.clear()
        for user in users:  # outside the lock: a user's close() may be waiting for it (detach)
            user.close()
        self.context.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else f"{self.users} users"
        return f"<engine.Device {self.name!r}, {state}>"
