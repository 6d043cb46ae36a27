"""Vulkan instance, device and queue: the one object every other vk helper hangs off.

`Context` owns the instance, the (optional) validation messenger, the logical device, one
queue that does graphics + compute (+ present when a surface is given), a command pool and a
list of objects to destroy on `close()` in reverse order of creation.

Threads: the queue, the command pool and the one-shot command buffer are used under `lock`, so objects on one
context (a Renderer and Tracers) may run from different threads; each of those objects serializes its own calls.
"""

from __future__ import annotations

import logging
import os
import threading
import time
import weakref

import vulkan as vk

from ..errors import ConfigError, VulkanError
from . import faults
from .pipeline_cache import PipelineCache

log = logging.getLogger("engine.vk")

_CData = vk.ffi.CData
_vkQueueSubmit = vk.lib.vkQueueSubmit  # the loader's entry point, called without the wrapper's conversions

_vkGetFenceStatus = vk.lib.vkGetFenceStatus


def _spin(device, fence, seconds: float):
    """Poll `fence` until it is signalled or `seconds` passed (the caller then waits for it as usual)."""
    end = time.perf_counter() + seconds
    while _vkGetFenceStatus(device, fence) == vk.VK_NOT_READY and time.perf_counter() < end:
        pass


_TYPE_RANK = {  # lower is better: discrete > integrated > virtual > CPU
    vk.VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU: 0,
    vk.VK_PHYSICAL_DEVICE_TYPE_INTEGRATED_GPU: 1,
    vk.VK_PHYSICAL_DEVICE_TYPE_VIRTUAL_GPU: 2,
    vk.VK_PHYSICAL_DEVICE_TYPE_CPU: 3,
    vk.VK_PHYSICAL_DEVICE_TYPE_OTHER: 4,
}
_TYPE_NAME = {
    vk.VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU: "discrete GPU",
    vk.VK_PHYSICAL_DEVICE_TYPE_INTEGRATED_GPU: "integrated GPU",
    vk.VK_PHYSICAL_DEVICE_TYPE_VIRTUAL_GPU: "virtual GPU",
    vk.VK_PHYSICAL_DEVICE_TYPE_CPU: "CPU",
    vk.VK_PHYSICAL_DEVICE_TYPE_OTHER: "other",
}
VALIDATION_LAYER = "VK_LAYER_KHRONOS_validation"
DEVICE_ENV = "HYBRID_DEVICE"
GPU_TIMEOUT_ENV = "HYBRID_GPU_TIMEOUT"
DEFAULT_GPU_TIMEOUT_S = 300.0  # no one command buffer of the engine's runs that long (a frame, a chunk of rays)
NO_TIMEOUT = 0xFFFFFFFFFFFFFFFF
VALIDATION_ENV = "HYBRID_VALIDATION"


def _env_flag(name: str) -> bool:
    value = os.environ.get(name, "").strip().lower()
    if value in ("1", "true", "yes", "on"):
        return True
    if value in ("", "0", "false", "no", "off"):
        return False
    raise ConfigError(f"${name}={os.environ[name]!r}: expected 1 / true / yes / on or 0 / false / no / off")


def _create_instance(extensions: list[str], layers: list[str]):
    app = vk.VkApplicationInfo(
        pApplicationName="hybrid",
        applicationVersion=1,
        pEngineName="hybrid",
        engineVersion=1,
        apiVersion=vk.VK_MAKE_VERSION(1, 3, 0),
    )
    info = vk.VkInstanceCreateInfo(
        pApplicationInfo=app,
        enabledLayerCount=len(layers),
        ppEnabledLayerNames=layers or None,
        enabledExtensionCount=len(extensions),
        ppEnabledExtensionNames=extensions or None,
    )
    try:
        return vk.vkCreateInstance(info, None)
    except vk.VkErrorIncompatibleDriver:
        raise VulkanError("no Vulkan driver found (install mesa-vulkan-drivers, or set VK_DRIVER_FILES)") from None
    except (vk.VkError, OSError) as exc:  # OSError: no libvulkan at all
        raise VulkanError(f"could not create a Vulkan instance: {type(exc).__name__} {exc}") from None


def describe_devices() -> list[dict]:
    """List every Vulkan physical device (no logical device is created)."""
    try:
        available = {e.extensionName for e in vk.vkEnumerateInstanceExtensionProperties(None)}
    except (vk.VkError, OSError) as exc:
        raise VulkanError(f"the Vulkan loader is not usable: {exc}") from None
    del available
    inst = _create_instance([], [])
    try:
        return [_describe(i, p) for i, p in enumerate(vk.vkEnumeratePhysicalDevices(inst))]
    finally:
        vk.vkDestroyInstance(inst, None)


def _describe(index, phys) -> dict:
    props = vk.vkGetPhysicalDeviceProperties(phys)
    api = props.apiVersion
    return {
        "index": index,
        "name": vk.ffi.string(props.deviceName).decode() if not isinstance(props.deviceName, str) else props.deviceName,
        "type": _TYPE_NAME.get(props.deviceType, "other"),
        "rank": _TYPE_RANK.get(props.deviceType, 9),
        "api": f"{vk.VK_VERSION_MAJOR(api)}.{vk.VK_VERSION_MINOR(api)}.{vk.VK_VERSION_PATCH(api)}",
    }


def choose_device(descs: list[dict], selector=None) -> int:
    """Pick a device index: explicit selector (index or name substring) > $HYBRID_DEVICE > best type."""
    if not descs:
        raise VulkanError("no Vulkan device found (install mesa-vulkan-drivers for the lavapipe CPU device)")
    source = "device"
    if selector is None and os.environ.get(DEVICE_ENV):
        selector, source = os.environ[DEVICE_ENV], DEVICE_ENV
    if selector is None:
        return min(descs, key=lambda d: (d["rank"], d["index"]))["index"]
    text = str(selector).strip()
    if text.lstrip("-").isdigit():
        idx = int(text)
        if not 0 <= idx < len(descs):
            raise ConfigError(f"{source}={selector!r}: no such device index (have 0..{len(descs) - 1})")
        return idx
    matches = [d for d in descs if text.lower() in d["name"].lower()]
    if not matches:
        names = ", ".join(d["name"] for d in descs)
        raise ConfigError(f"{source}={selector!r}: no device name contains it (devices: {names})")
    return matches[0]["index"]


_LIVE: "weakref.WeakSet[Context]" = weakref.WeakSet()


def gpu_timeout_ns() -> int:
    """$HYBRID_GPU_TIMEOUT (seconds; 0: none) in ns, DEFAULT_GPU_TIMEOUT_S when unset."""
    text = os.environ.get(GPU_TIMEOUT_ENV, "").strip()
    try:
        seconds = float(text) if text else DEFAULT_GPU_TIMEOUT_S
    except ValueError:
        seconds = -1.0
    if not seconds >= 0 or seconds == float("inf"):
        raise ConfigError(f"{GPU_TIMEOUT_ENV}={text!r}: expected seconds >= 0 (0: no limit)")
    return NO_TIMEOUT if seconds == 0 else min(int(seconds * 1e9), NO_TIMEOUT - 1)


def live_contexts() -> int:
    """How many Contexts are open in this process (each holds a Vulkan device)."""
    return sum(1 for c in list(_LIVE) if not c.closed)


class Context:
    """Instance + device + queue. Use as a context manager or call close()."""

    def __init__(
        self,
        device=None,
        validation: bool | None = None,
        instance_extensions=(),
        device_extensions=(),
        surface_factory=None,
    ):
        self.lock = threading.RLock()  # the queue, the command pool, the one-shot command buffer, teardown
        self.lost = False  # VK_ERROR_DEVICE_LOST was seen: nothing more is submitted
        self.hung = False  # lost by the GPU timeout: its work may still run, so nothing of it is destroyed
        self.allocations = 0  # live device-memory allocations (Buffer, Image)
        self.validation = _env_flag(VALIDATION_ENV) if validation is None else bool(validation)
        self.validation_errors: list[str] = []
        self.validation_messages: list[str] = []
        self._destroy_stack = []
        self._scopes = []  # engine.vk.shared.Scope: users' shares, closed before this context's own objects
        self.memo: dict = {}  # objects its users share (pipelines by shader and constants), under memo_lock
        self.memo_lock = threading.Lock()
        self._submit_infos = {}  # (cmd, wait semaphores, wait stages, signal semaphores) -> VkSubmitInfo*
        self.instance = None
        self.device = None
        self._messenger = None
        self.surface = None
        self.pipeline_cache = None  # PipelineCache: every pipeline made on this device goes through it
        self.external_memory_fd = False  # VK_KHR_external_memory_fd enabled (set in _init)
        self._fault = None  # engine.vk.faults.FaultInjector, with $HYBRID_FAULT_INJECTION only
        self.gpu_timeout_ns = gpu_timeout_ns()  # a wait longer than this: the device hangs, and is treated as lost
        try:
            self._init(device, list(instance_extensions), list(device_extensions), surface_factory)
        except BaseException:
            self.close()
            raise
        _LIVE.add(self)

    # ---- set-up -------------------------------------------------------------------------
    def _init(self, selector, inst_exts, dev_exts, surface_factory):
        layers = []
        try:
            available_layers = {p.layerName for p in vk.vkEnumerateInstanceLayerProperties()}
        except (vk.VkError, OSError) as exc:
            raise VulkanError(f"the Vulkan loader is not usable: {exc}") from None
        if self.validation:
            if VALIDATION_LAYER not in available_layers:
                raise VulkanError(
                    f"validation requested but {VALIDATION_LAYER} is not installed "
                    "(apt-get install vulkan-validationlayers)"
                )
            layers.append(VALIDATION_LAYER)
            inst_exts.append(vk.VK_EXT_DEBUG_UTILS_EXTENSION_NAME)
        self.instance = _create_instance(inst_exts, layers)
        if self.validation:
            self._install_messenger()
        if surface_factory is not None:
            self.surface = surface_factory(self.instance)

        physicals = vk.vkEnumeratePhysicalDevices(self.instance)
        descs = [_describe(i, p) for i, p in enumerate(physicals)]
        index = choose_device(descs, selector)
        self.physical = physicals[index]
        self.device_info = descs[index]
        self.properties = vk.vkGetPhysicalDeviceProperties(self.physical)
        self.limits = self.properties.limits
        self.memory_properties = vk.vkGetPhysicalDeviceMemoryProperties(self.physical)
        self.timestamp_period_ns = float(self.limits.timestampPeriod)

        families = vk.vkGetPhysicalDeviceQueueFamilyProperties(self.physical)
        want = vk.VK_QUEUE_GRAPHICS_BIT | vk.VK_QUEUE_COMPUTE_BIT
        self.queue_family = None
        for i, fam in enumerate(families):
            if fam.queueFlags & want != want:
                continue
            if self.surface is not None:
                get_support = vk.vkGetInstanceProcAddr(self.instance, "vkGetPhysicalDeviceSurfaceSupportKHR")
                if not get_support(self.physical, i, self.surface):
                    continue
            self.queue_family = i
            self.timestamp_bits = fam.timestampValidBits
            break
        if self.queue_family is None:
            raise VulkanError(
                f"device {self.device_info['name']!r} has no graphics+compute queue"
                + (" that can present" if self.surface is not None else "")
            )

        # memory that CUDA can map (engine.vk.external): enabled wherever the device offers it
        offered = {e.extensionName for e in vk.vkEnumerateDeviceExtensionProperties(self.physical, None)}
        self.external_memory_fd = vk.VK_KHR_EXTERNAL_MEMORY_FD_EXTENSION_NAME in offered
        if self.external_memory_fd and vk.VK_KHR_EXTERNAL_MEMORY_FD_EXTENSION_NAME not in dev_exts:
            dev_exts.append(vk.VK_KHR_EXTERNAL_MEMORY_FD_EXTENSION_NAME)
        f13 = vk.VkPhysicalDeviceVulkan13Features(dynamicRendering=vk.VK_TRUE)
        f12 = vk.VkPhysicalDeviceVulkan12Features(pNext=f13, hostQueryReset=vk.VK_TRUE)
        # geometryShader: only for gl_PrimitiveID in the G-buffer's visibility fragment shader (the Renderer checks it)
        self.geometry_shader = bool(vk.vkGetPhysicalDeviceFeatures(self.physical).geometryShader)
        # samplerAnisotropy: anisotropic texture filtering where the device has it (Sampler caps at max_anisotropy)
        aniso = bool(vk.vkGetPhysicalDeviceFeatures(self.physical).samplerAnisotropy)
        self.max_anisotropy = float(self.limits.maxSamplerAnisotropy) if aniso else 1.0
        # drawIndirectFirstInstance: the G-buffer's culled indirect draws start at their instance list's slot
        self.draw_indirect_first_instance = bool(
            vk.vkGetPhysicalDeviceFeatures(self.physical).drawIndirectFirstInstance
        )
        # shaderInt64 + shaderBufferInt64Atomics: the G-buffer's software raster of small instances (64-bit
        # depth + id atomics, engine/passes/soft_raster.py); without them every instance takes the hardware raster
        have12 = vk.VkPhysicalDeviceVulkan12Features()
        vk.vkGetPhysicalDeviceFeatures2(self.physical, vk.VkPhysicalDeviceFeatures2(pNext=have12))
        self.int64_atomics = bool(
            vk.vkGetPhysicalDeviceFeatures(self.physical).shaderInt64 and have12.shaderBufferInt64Atomics
        )
        if self.int64_atomics:
            f12.shaderBufferInt64Atomics = vk.VK_TRUE
        fault_at = faults.requested()  # a test's deliberate device loss (engine/vk/faults.py)
        if fault_at is not None:
            faults.check_device(self.device_info, bool(have12.bufferDeviceAddress))
            f12.bufferDeviceAddress = vk.VK_TRUE
        feats = vk.VkPhysicalDeviceFeatures2(
            pNext=f12,
            features=vk.VkPhysicalDeviceFeatures(
                geometryShader=vk.VK_TRUE if self.geometry_shader else vk.VK_FALSE,
                drawIndirectFirstInstance=vk.VK_TRUE if self.draw_indirect_first_instance else vk.VK_FALSE,
                samplerAnisotropy=vk.VK_TRUE if aniso else vk.VK_FALSE,
                shaderInt64=vk.VK_TRUE if self.int64_atomics else vk.VK_FALSE,
            ),
        )
        prio = vk.ffi.new("float[]", [1.0])
        qinfo = vk.VkDeviceQueueCreateInfo(queueFamilyIndex=self.queue_family, queueCount=1, pQueuePriorities=prio)
        dinfo = vk.VkDeviceCreateInfo(
            pNext=feats,
            queueCreateInfoCount=1,
            pQueueCreateInfos=[qinfo],
            enabledExtensionCount=len(dev_exts),
            ppEnabledExtensionNames=dev_exts or None,
        )
        try:
            self.device = vk.vkCreateDevice(self.physical, dinfo, None)
        except vk.VkError as exc:
            raise VulkanError(
                f"could not create a device on {self.device_info['name']!r}: {type(exc).__name__}"
            ) from None
        self.queue = vk.vkGetDeviceQueue(self.device, self.queue_family, 0)
        self.command_pool = vk.vkCreateCommandPool(
            self.device,
            vk.VkCommandPoolCreateInfo(
                flags=vk.VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT, queueFamilyIndex=self.queue_family
            ),
            None,
        )
        self.fence = vk.vkCreateFence(self.device, vk.VkFenceCreateInfo(), None)
        self._one_shot = self.allocate_command_buffer()
        self.pipeline_cache = PipelineCache(self.device, self.properties)
        if fault_at is not None:
            self._fault = faults.FaultInjector(self, fault_at)

    def _install_messenger(self):
        sev = vk.VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT

        def callback(severity, types, data, user):
            msg = vk.ffi.string(data.pMessage).decode(errors="replace")
            self.validation_messages.append(msg)
            if severity & sev:
                self.validation_errors.append(msg)
                log.error("validation: %s", msg)
            else:
                log.debug("validation: %s", msg)
            return 0

        self._callback = callback  # keep alive
        info = vk.VkDebugUtilsMessengerCreateInfoEXT(
            messageSeverity=(vk.VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT | sev),
            messageType=(
                vk.VK_DEBUG_UTILS_MESSAGE_TYPE_GENERAL_BIT_EXT
                | vk.VK_DEBUG_UTILS_MESSAGE_TYPE_VALIDATION_BIT_EXT
                | vk.VK_DEBUG_UTILS_MESSAGE_TYPE_PERFORMANCE_BIT_EXT
            ),
            pfnUserCallback=callback,
        )
        create = vk.vkGetInstanceProcAddr(self.instance, "vkCreateDebugUtilsMessengerEXT")
        self._messenger = create(self.instance, info, None)

    # ---- lifetime -----------------------------------------------------------------------
    def defer_destroy(self, fn, *args):
        """Register a destructor to run on close(), newest first."""
        self._destroy_stack.append((fn, args))

    @property
    def root(self) -> "Context":
        """The context itself (a Scope's is its context): where objects shared by its users are made."""
        return self

    def add_scope(self, scope):
        with self.lock:
            self._scopes.append(scope)

    def remove_scope(self, scope):
        with self.lock:
            if scope in self._scopes:
                self._scopes.remove(scope)

    @property
    def closed(self) -> bool:
        """Has close() run (or did set-up fail)? Then no Vulkan call may use this context."""
        return self.device is None

    def check_open(self, what: str):
        """Raise a ConfigError naming `what` (the caller: "Tracer", "Renderer") if this context is closed: a Vulkan
        call on a destroyed device aborts the process instead of raising."""
        if self.device is None:
            raise ConfigError(f"{what}: the Vulkan context is closed (create a new engine.vk.Context)")
        if self.lost:
            raise VulkanError(f"{what}: the Vulkan device was lost; close this object and create a new one")

    def wait_idle(self):
        """Block until the queue has run everything submitted (a lost device: return at once, nothing will run).
        Through a fence, so that a device that hangs is found by the GPU timeout like any other wait."""
        with self.lock:
            if self.device is not None and not self.lost:
                try:
                    result = _vkQueueSubmit(self.queue, 0, vk.ffi.NULL, self.fence)
                    if result != vk.VK_SUCCESS:
                        raise vk.exception_codes[result]
                except vk.VkErrorDeviceLost:
                    self.lost = True
                    raise VulkanError("the Vulkan device was lost") from None
                self.wait_fences([self.fence])
                vk.vkResetFences(self.device, 1, [self.fence])

    def wait_fences(self, fences) -> None:
        """Block until every fence in `fences` is signalled. A device lost, or one that has not finished within the
        GPU timeout (a hang, which a driver may never report), marks this context lost: a VulkanError."""
        fences = list(fences)
        try:
            vk.vkWaitForFences(self.device, len(fences), fences, vk.VK_TRUE, self.gpu_timeout_ns)
        except vk.VkTimeout:
            self.lost = self.hung = True
            raise VulkanError(
                f"the GPU did not finish its work within {self.gpu_timeout_ns / 1e9:g} s ({GPU_TIMEOUT_ENV}): the "
                "device is treated as lost; close this object and create a new one"
            ) from None
        except vk.VkErrorDeviceLost:
            self.lost = True
            raise VulkanError("the Vulkan device was lost while running a command buffer") from None

    def close(self):
        with self.lock:
            self._close()

    def _close(self):
        if self.hung:
            self._abandon()
        if self.device is not None:
            try:
                self.wait_idle()
            except VulkanError:  # lost, or hung: destroying the objects of a lost device is allowed
                pass
            while self._scopes:  # users still open: their objects go first (they were made on ours)
                self._scopes.pop().destroy_objects()
            while self._destroy_stack:
                fn, args = self._destroy_stack.pop()
                fn(*args)
            if self.pipeline_cache is not None:
                if not self.lost:
                    self.pipeline_cache.save()
                self.pipeline_cache.destroy()
                self.pipeline_cache = None
            if getattr(self, "fence", None) is not None:
                vk.vkDestroyFence(self.device, self.fence, None)
            if getattr(self, "command_pool", None) is not None:
                vk.vkDestroyCommandPool(self.device, self.command_pool, None)
            vk.vkDestroyDevice(self.device, None)
            self.device = None
        if self.instance is not None:
            if self.surface is not None:
                vk.vkGetInstanceProcAddr(self.instance, "vkDestroySurfaceKHR")(self.instance, self.surface, None)
                self.surface = None
            if self._messenger is not None:
                destroy = vk.vkGetInstanceProcAddr(self.instance, "vkDestroyDebugUtilsMessengerEXT")
                destroy(self.instance, self._messenger, None)
                self._messenger = None
            vk.vkDestroyInstance(self.instance, None)
            self.instance = None

    def _abandon(self):
        """Close a hung device without a Vulkan call: destroying what its work may still use could crash the
        driver, so the objects are left to it (freed when the process exits)."""
        if self.device is not None:
            log.info(
                "%s did not finish its work in time: its Vulkan objects are left to the driver until this process "
                "exits",
                self.device_info["name"],
            )
        self._scopes.clear()
        self._destroy_stack.clear()
        self.pipeline_cache = None
        self.device = self.instance = self._messenger = self.surface = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # ---- commands -----------------------------------------------------------------------
    def allocate_command_buffer(self):
        with self.lock:
            return vk.vkAllocateCommandBuffers(
                self.device,
                vk.VkCommandBufferAllocateInfo(
                    commandPool=self.command_pool, level=vk.VK_COMMAND_BUFFER_LEVEL_PRIMARY, commandBufferCount=1
                ),
            )[0]

    def forget_command_buffer(self, cmd):
        """Drop the cached submit infos of a command buffer about to be freed."""
        with self.lock:
            for key in [k for k in self._submit_infos if k[0] == cmd]:
                del self._submit_infos[key]

    def free_command_buffer(self, cmd):
        with self.lock:
            self.forget_command_buffer(cmd)
            vk.vkFreeCommandBuffers(self.device, self.command_pool, 1, [cmd])

    def submit(
        self, cmd, wait=True, wait_semaphores=(), wait_stages=(), signal_semaphores=(), fence=None, spin_s: float = 0.0
    ):
        """Submit one recorded command buffer; by default block until it finished (`spin_s`: polling the fence for up
        to that many seconds first, which wakes sooner than the driver's blocking wait, for sub-millisecond work).

        The VkSubmitInfo (and its handle arrays) is built once per (command buffer, semaphores, stages) and
        reused, and vkQueueSubmit is called through the raw cffi function: a re-submitted frame costs one
        dict lookup and one foreign call here (the viewer's per-frame path). Under `lock`, with the wait."""
        with self.lock:
            if self.device is None:
                raise ConfigError("submit: the Vulkan context is closed")
            if self.lost:
                raise VulkanError("the Vulkan device was lost; nothing more can run on it")
            if self._fault is not None and self._fault.due():  # a test's deliberate device loss, ahead of cmd
                fault, self._fault = self._fault, None
                self.submit(fault.cmd, wait=False)
            key = (cmd, tuple(wait_semaphores), tuple(wait_stages), tuple(signal_semaphores))
            entry = self._submit_infos.get(key)
            if entry is None:
                entry = self._submit_info(key)
            use_fence = fence if fence is not None else (self.fence if wait else None)
            if not isinstance(use_fence, _CData):
                use_fence = vk.ffi.cast("VkFence", use_fence) if use_fence else vk.ffi.NULL
            try:
                result = _vkQueueSubmit(self.queue, 1, entry[0], use_fence)
                if result != vk.VK_SUCCESS:
                    raise vk.exception_codes[result]
                if wait and fence is None:
                    if spin_s > 0:
                        _spin(self.device, self.fence, spin_s)
                    self.wait_fences([self.fence])
                    vk.vkResetFences(self.device, 1, [self.fence])
            except vk.VkErrorDeviceLost:
                self.lost = True
                raise VulkanError("the Vulkan device was lost while running a command buffer") from None

    def _submit_info(self, key):
        """[VkSubmitInfo*, the arrays it points to] for `key` (see submit), cached: the list keeps them alive."""
        cmd, waits, stages, signals = key
        if len(stages) != len(waits):
            raise ValueError(f"submit: {len(waits)} wait semaphores but {len(stages)} wait stages")
        ffi = vk.ffi
        info = ffi.new("VkSubmitInfo*")
        info.sType = vk.VK_STRUCTURE_TYPE_SUBMIT_INFO
        keep = [info, ffi.new("VkCommandBuffer[1]", [cmd])]
        info.commandBufferCount, info.pCommandBuffers = 1, keep[1]
        if waits:
            keep += [ffi.new("VkSemaphore[]", list(waits)), ffi.new("VkPipelineStageFlags[]", list(stages))]
            info.waitSemaphoreCount, info.pWaitSemaphores, info.pWaitDstStageMask = len(waits), keep[-2], keep[-1]
        if signals:
            keep.append(ffi.new("VkSemaphore[]", list(signals)))
            info.signalSemaphoreCount, info.pSignalSemaphores = len(signals), keep[-1]
        if len(self._submit_infos) >= 256:  # handles of freed objects; a bound, not a policy
            self._submit_infos.clear()
        self._submit_infos[key] = keep
        return keep

    def one_shot(self):
        """`with ctx.one_shot() as cmd:` records into a command buffer and runs it on exit."""
        return _OneShot(self)

    def memory_type(self, type_bits: int, want: int, avoid: int = 0) -> int:
        mp = self.memory_properties
        for i in range(mp.memoryTypeCount):
            flags = mp.memoryTypes[i].propertyFlags
            if type_bits & (1 << i) and flags & want == want and not flags & avoid:
                return i
        if avoid:
            return self.memory_type(type_bits, want)
        raise VulkanError(f"no memory type with flags {want:#x} for type bits {type_bits:#x}")


class _OneShot:
    def __init__(self, ctx):
        self.ctx = ctx

    def __enter__(self):
        self.ctx.lock.acquire()  # the one-shot command buffer is shared: held until it has run
        cmd = self.ctx._one_shot
        vk.vkResetCommandBuffer(cmd, 0)
        vk.vkBeginCommandBuffer(cmd, vk.VkCommandBufferBeginInfo(flags=vk.VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT))
        return cmd

    def __exit__(self, exc_type, *rest):
        try:
            cmd = self.ctx._one_shot
            vk.vkEndCommandBuffer(cmd)
            if exc_type is None:
                self.ctx.submit(cmd)
        finally:
            self.ctx.lock.release()
