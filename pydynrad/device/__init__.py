"""The device layer: OpenCL devices, programs, launches and device-resident matrices.

* :mod:`.devices`: which device runs the kernels, program building and caching;
* :mod:`.launch`: global and local sizes, the layout defines every kernel is built with;
* :mod:`.pocl`: PoCL's target and cache settings;
* :mod:`.matrix`: :class:`DeviceMatrix`, a dense matrix held on the device;
* :mod:`.csr` and :mod:`.sell`: sparse matrices on the device (CSR, SELL-C-sigma);
* :mod:`.transfers`: reads and writes between host and device.

Nothing here imports the geometry, the lights or the solvers.
"""

from .devices import Device, DeviceTraits, default_device, list_devices
from .matrix import DeviceMatrix

__all__ = ["Device", "DeviceMatrix", "DeviceTraits", "default_device", "list_devices"]
