"""Past one machine: the job's items as Ray tasks (`hybrid batch JOB --ray ADDRESS`, `pip install .[distributed]`).

Each task renders a shard of items on one worker: with `num_gpus=1` where the cluster has GPUs (its Renderer opens
the Vulkan GPU of the index Ray assigned it), else with one CPU (lavapipe). Tasks write their files straight to the
output folder, which every node must see at the same path (a shared file system); they return their records, and
the driver merges them into the manifest as tasks finish.

`--ray local` starts a Ray instance in the driver's process for this run, on loopback only; an ADDRESS on loopback
(127.x, localhost) is a cluster on this machine and is reached on loopback only too.
"""

from __future__ import annotations

import ipaddress
import logging
import os
import socket
from collections.abc import Callable

from ..errors import ConfigError, EngineError
from ..vk import describe_devices
from .job import Item, Job
from .pool import auto_shard_size, shards
from .render import ItemRenderer, record, worker_name

# Ray binds its servers to the node's address; with this set to 0 before Ray is imported, the node's address is
# the loopback one (Ray's single-machine mode), so a local cluster listens on 127.0.0.1 only.
_LOOPBACK_ENV = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"


def is_loopback(address: str) -> bool:
    host = address.rsplit(":", 1)[0].strip("[]") if ":" in address else address
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def import_ray(address: str):
    """Ray, imported for `address` ("local", or a cluster's GCS address host:port, or "auto")."""
    local = address == "local" or is_loopback(address)
    if local:
        os.environ.setdefault(_LOOPBACK_ENV, "0")
    try:
        import ray  # an optional dependency: only --ray needs it
    except ImportError:
        raise ConfigError("--ray needs Ray: pip install 'hybrid-renderer[distributed]' (or pip install ray)") from None
    return ray


def run_ray(
    job: Job, todo: list[Item], on_record: Callable[[dict], None], *, address: str, shard_size: int | None = None
) -> dict:
    """Render `todo` as Ray tasks on the cluster at `address` (or "local"); records go to `on_record` as tasks end.
    Returns {"devices": the devices' names, "errors": validation errors found when the tasks' Renderers closed,
    "cluster": a line about the cluster}."""
    local = address == "local"
    if not local and address != "auto":
        _probe(address)  # Ray itself retries an address where nothing listens for minutes
    ray = import_ray(address)
    try:
        if local:
            ray.init(include_dashboard=False, log_to_driver=False, logging_level=logging.WARNING)
        else:
            ray.init(address=address, log_to_driver=False, logging_level=logging.WARNING)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        why = _first_line(exc) + (f" ({_first_line(exc.__cause__)})" if exc.__cause__ is not None else "")
        raise ConfigError(f"--ray {address}: cannot connect: {why}") from None
    try:
        node = ray.util.get_node_ip_address()
        if (local or is_loopback(address)) and not is_loopback(node):
            raise EngineError(
                f"--ray {address}: Ray chose the address {node}, not loopback; set {_LOOPBACK_ENV}=0 before Ray starts"
            )
        res = ray.cluster_resources()
        gpus, cpus = int(res.get("GPU", 0)), int(res.get("CPU", 1))
        options = {"num_gpus": 1} if gpus else {"num_cpus": 1}
        size = shard_size or auto_shard_size(len(todo), gpus or cpus)
        task = ray.remote(max_retries=1)(render_shard).options(**options)
        job_ref = ray.put(job)  # once in the object store, not once per task
        parts = {task.remote(job_ref, part): part for part in shards(todo, size)}
        devices, late = set(), []
        total = len(parts)
        while parts:
            ready, _ = ray.wait(list(parts), num_returns=1)
            part = parts.pop(ready[0])
            try:
                out = ray.get(ready[0])
            except ray.exceptions.RayError as exc:
                why = f"Ray task failed: {type(exc).__name__}: {_first_line(exc)}"
                out = {"records": [record(it, "failed", "ray", error=why) for it in part], "devices": [], "errors": []}
            for rec in out["records"]:
                on_record(rec)
            devices.update(out["devices"])
            late.extend(out["errors"])
        kind = f"{gpus} GPUs" if gpus else f"{cpus} CPUs"
        return {
            "devices": sorted(devices),
            "errors": late,
            "cluster": f"Ray at {'local (' + node + ')' if local else address}: {kind}, {total} tasks",
        }
    finally:
        ray.shutdown()


def render_shard(job: Job, items: list[Item]) -> dict:
    """A Ray task: the items on this worker's GPU (or CPU device); {"records", "devices", "errors"}."""
    import ray  # in a Ray worker: Ray is there

    gpu_ids = ray.get_gpu_ids()
    name = worker_name(f"ray {ray.util.get_node_ip_address()}")
    try:
        device = ray_device(gpu_ids)
        with ItemRenderer(job, device, name) as ir:
            records = list(ir.render(items))
        return {"records": records, "devices": [ir.device], "errors": ir.unreported_errors()}
    except EngineError as exc:
        return {"records": [record(it, "failed", name, error=str(exc)) for it in items], "devices": [], "errors": []}


def ray_device(gpu_ids) -> int | None:
    """The Vulkan device of the GPU Ray assigned (`ray.get_gpu_ids()`): the GPUs in Vulkan's order (that of their
    PCI buses, as CUDA's with identical GPUs), that index; None (the default device) without one, or when
    $HYBRID_DEVICE chooses."""
    if not gpu_ids or os.environ.get("HYBRID_DEVICE"):
        return None
    gpus = [d["index"] for d in describe_devices() if d["type"] in ("discrete GPU", "integrated GPU")]
    if not gpus:
        return None
    return gpus[int(gpu_ids[0]) % len(gpus)]


def _probe(address: str, timeout: float = 5.0) -> None:
    """A ConfigError unless a TCP connection to host:port (the cluster's GCS) opens within `timeout` seconds."""
    host, sep, port = address.rpartition(":")
    host = host.strip("[]")
    if not sep or not host or not port.isdigit():
        raise ConfigError(
            f"--ray {address!r}: expected the cluster's address as host:port (e.g. head-node:6379), 'auto' or 'local'"
        )
    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except OSError as exc:
        raise ConfigError(f"--ray {address}: no Ray cluster answers there ({exc.strerror or exc})") from None


def _first_line(exc: BaseException) -> str:
    lines = str(exc).strip().splitlines()
    return lines[0] if lines else type(exc).__name__
