"""Device.to_device copies at once; ReadSlab's parts are separate buffers read back in one command, and
its reads are checked; a Device refuses an out-of-order queue."""

import numpy as np
import pyopencl as cl
import pytest

from pydynrad.device.transfers import ReadSlab


def test_to_device_holds_a_copy(device):
    host = np.arange(10, dtype=np.float32)
    buf = device.to_device(host)
    host[:] = -1.0  # after the upload: the buffer must keep the values it was made from
    out = np.empty(10, dtype=np.float32)
    cl.enqueue_copy(device.queue, out, buf, is_blocking=True)
    np.testing.assert_array_equal(out, np.arange(10, dtype=np.float32))
    assert device.to_device(np.zeros((0, 4), dtype=np.int32)).size == 4  # one element: no empty buffers


def test_read_slab_parts(device):
    sizes = [3, 17, 1, 40]  # odd sizes: every part must still start aligned
    slab = ReadSlab(device, sizes, np.float64)
    align = int(device.cl_device.mem_base_addr_align) // 8
    assert all(o % align == 0 for o in slab.offsets)
    for i, (part, n) in enumerate(zip(slab.parts, sizes)):
        cl.enqueue_copy(device.queue, part, np.full(n, i + 0.5))
    got = slab.read([(3, 40), (1, 5), (0, 3)])
    np.testing.assert_array_equal(got[0], np.full(40, 3.5))
    np.testing.assert_array_equal(got[1], np.full(5, 1.5))
    np.testing.assert_array_equal(got[2], np.full(3, 0.5))
    assert slab.read([(2, 1)])[0].tolist() == [2.5]


def test_read_slab_refuses_reads_past_a_part(device):
    from pydynrad import InvalidInputError

    slab = ReadSlab(device, [4, 4], np.float32)
    for items in ([(0, 5)], [(2, 1)], [(0, 0)], []):
        with pytest.raises(InvalidInputError, match="ReadSlab.read"):
            slab.read(items)


def test_an_out_of_order_queue_is_refused(device):
    from pydynrad import InvalidInputError
    from pydynrad.device.devices import Device

    props = cl.command_queue_properties.OUT_OF_ORDER_EXEC_MODE_ENABLE
    try:
        queue = cl.CommandQueue(device.context, properties=props)
    except cl.Error:
        pytest.skip(f"{device.name} has no out-of-order queues")
    with pytest.raises(InvalidInputError, match="in-order"):
        Device(device.context, queue)
