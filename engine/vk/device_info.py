"""What a Context's physical device is: name, type, API, vendor and device ids, driver (for reports such as bench's)."""

from __future__ import annotations

import vulkan as vk


def device_details(ctx) -> dict:
    """Name, type, API and driver of a Context's physical device (driver name/info through Vulkan 1.2 properties)."""
    info = dict(ctx.device_info)
    info.pop("rank", None)
    props = ctx.properties
    info.update(
        vendor_id=hex(props.vendorID),
        device_id=hex(props.deviceID),
        driver_version=int(props.driverVersion),
        timestamp_period_ns=ctx.timestamp_period_ns,
    )
    try:
        drv = vk.VkPhysicalDeviceDriverProperties()
        vk.vkGetPhysicalDeviceProperties2(ctx.physical, vk.VkPhysicalDeviceProperties2(pNext=drv))
        info["driver"] = vk.ffi.string(drv.driverName).decode()
        info["driver_info"] = vk.ffi.string(drv.driverInfo).decode()
    except Exception:  # an older driver without VkPhysicalDeviceDriverProperties
        pass
    return info
