"""``shadow`` on any device URL: the device with a calibrated twin in lockstep beside it.

``shadow=1`` names divergences on the console; ``shadow=PATH`` appends them to the JSON-lines
file PATH as well; ``shadow_warmup_s=S`` is the device time over which the shadow learns the
noise first (default :data:`twin.shadow.device.DEFAULT_WARMUP_S`). The twin is the URL's parameter set, in the device's clamp
orientation (:func:`twin.device.sim_url.open_shadow_twin`), so code written for a device runs
unchanged with its shadow. The driver finds this module by name
(:data:`twin.driver.url.WRAPPER_MODULES`); importing it loads no twin until a shadow is opened.
"""

from __future__ import annotations

import math
from typing import cast

from twin.driver.device import Device
from twin.driver.url import DeviceRequest, Wrapper, register_wrapper

__all__ = ["shadowed"]


def shadowed(device: Device, request: DeviceRequest) -> Device:
    """``device``, or with ``shadow`` in the URL the device with its twin beside it."""
    url, options = request.url, request.options
    value = options.get("shadow", "0")
    if value in ("0", ""):
        if "shadow_warmup_s" in options:
            raise ValueError(f"device URL {url!r}: shadow_warmup_s configures the shadow; give shadow=1 too")
        return device
    from twin.device.sim_url import open_shadow_twin
    from twin.shadow.device import DEFAULT_WARMUP_S, ShadowDevice

    warmup = options.get("shadow_warmup_s", str(DEFAULT_WARMUP_S))
    try:
        warmup_s = float(warmup)
    except ValueError:
        warmup_s = math.nan
    if not (math.isfinite(warmup_s) and warmup_s > 0):
        raise ValueError(f"device URL {url!r}: shadow_warmup_s = {warmup!r}: expected a time > 0 (s)")
    shadow = ShadowDevice(device, open_shadow_twin(request.params, device.base_rotation), request.params,
                          warmup_s=warmup_s, log_path=None if value == "1" else value)
    return cast(Device, shadow)  # it answers every Device call, passing each on to both


register_wrapper(Wrapper("shadow", ("shadow", "shadow_warmup_s"), shadowed))
