"""Results down in one read: kernels' outputs as parts of one buffer.

A frame of the local update moves a few kilobytes each way in dozens of small arrays, and on
PoCL's CPU devices each transfer command costs far more than its bytes: a queued write or read
of a few KB costs tens of times what creating a buffer from host memory does (little more than
the copy) or what queuing a kernel launch does (docs/decisions/0006-fewer-waits-and-transfers.md).
So inputs go up as new
buffers (:meth:`pydynrad.device.devices.Device.to_device`: OpenCL keeps one alive while a command uses
it, so there is nothing to hold or wait for and no buffer to share between calls), and
:class:`ReadSlab` gives kernels their outputs as sub-buffers of one buffer, read back with one
command.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInputError

__all__ = ["ReadSlab"]


class ReadSlab:
    """One device buffer split into aligned parts of ``sizes[i]`` elements of ``dtype``.

    ``parts[i]`` is a sub-buffer a kernel writes; :meth:`read` brings back any of them with one
    read of the span that covers them (whole parts in between included: a few bytes more in
    one command beat a command per part). Parts start on every device's base address
    alignment, as sub-buffers must. Reads assume the in-order queue of a :class:`~pydynrad.device.Device`.
    """

    def __init__(self, device, sizes, dtype) -> None:
        import pyopencl as cl

        self.device, self.dtype = device, np.dtype(dtype)
        self.sizes = [max(1, int(n)) for n in sizes]
        self.offsets, self.nbytes = self.layout(device, self.sizes, self.dtype)
        self.buffer = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, self.nbytes)
        self.parts = [self.buffer.get_sub_region(o, n * self.dtype.itemsize) for o, n in zip(self.offsets, self.sizes)]

    @staticmethod
    def layout(device, sizes, dtype) -> tuple[list[int], int]:
        """(byte offset of each part, bytes in all) of a slab of parts of ``sizes`` elements
        (at least one each) of ``dtype`` on ``device``: what one takes before it is made."""
        itemsize = np.dtype(dtype).itemsize
        align = max([itemsize] + [int(d.mem_base_addr_align) // 8 for d in device.context.devices])
        offsets, end = [], 0
        for n in sizes:
            offsets.append(end)
            end += -(-max(1, int(n)) * itemsize // align) * align
        return offsets, end

    def read(self, items) -> list[np.ndarray]:
        """(part index, count) pairs: the first ``count`` elements of each part, as new arrays,
        after one read (which also waits for every command queued before it)."""
        import pyopencl as cl

        items = list(items)
        bad = [(i, n) for i, n in items if not (0 <= i < len(self.sizes) and 1 <= n <= self.sizes[i])]
        if not items or bad:
            raise InvalidInputError(
                f"ReadSlab.read needs (part, count) items with 1 <= count <= the part's size {self.sizes}; got {items}"
            )
        lo = min(self.offsets[i] for i, _ in items)
        hi = max(self.offsets[i] + n * self.dtype.itemsize for i, n in items)
        host = np.empty(hi - lo, dtype=np.uint8)
        cl.enqueue_copy(self.device.queue, host, self.buffer, src_offset=lo, is_blocking=True)
        return [
            host[self.offsets[i] - lo : self.offsets[i] - lo + n * self.dtype.itemsize].view(self.dtype).copy()
            for i, n in items
        ]
