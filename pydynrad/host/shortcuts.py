"""The one switch for work done on the host beside a CPU device.

Where the device is the host's own CPU, some passes cost less on the host (a small product
skips a call's launch and read-back; numpy builds a small multibounce matrix faster). A GPU
never takes these shortcuts, so ``PYDYNRAD_FORCE_DEVICE=1`` turns them all off on a CPU too,
and the device paths a GPU would run can be tested on PoCL.
"""

from __future__ import annotations

import os

__all__ = ["FORCE_DEVICE_ENV", "host_shortcuts"]


#: The one switch that turns off every host shortcut taken beside a CPU device (see
#: :func:`host_shortcuts`): set to anything but "" or "0", the device runs every pass it would run
#: on a GPU. For testing those paths on PoCL and under Oclgrind (tests/oclgrind/).
FORCE_DEVICE_ENV = "PYDYNRAD_FORCE_DEVICE"


def host_shortcuts(device) -> bool:
    """Whether work may go to the host instead of ``device``: the device is a CPU (its
    :class:`~pydynrad.device.DeviceTraits` say so, so ``Device.with_traits(cpu=False)`` turns them off too) and
    ``PYDYNRAD_FORCE_DEVICE`` (:data:`FORCE_DEVICE_ENV`) is unset or "0".

    Every "beside a CPU device" choice asks this, and only this: the small products of
    :func:`pydynrad.host.product.on_host` (the far field's K_c and G), the far field's F L by
    columns on the host, and ``multibounce(backend="auto")``'s numpy build. Read at each call
    (where those objects are made), so a test may set the variable for one case."""
    forced = os.environ.get(FORCE_DEVICE_ENV, "0").strip() not in ("", "0")
    return bool(getattr(device, "traits", device).cpu) and not forced
