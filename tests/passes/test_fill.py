"""Buffer zeroing (``kernels/fill.cl``, :mod:`clrecon.core.fill`): the bytes asked for become 0
and nothing past them changes, on the kernel's path and the runtime fill's."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest

from clrecon.core.fill import KERNEL_MIN_BYTES, zero_buffer


@pytest.mark.parametrize("nbytes", [0, 16, 1000, KERNEL_MIN_BYTES, KERNEL_MIN_BYTES + 1,
                                    KERNEL_MIN_BYTES + 15, 3 * KERNEL_MIN_BYTES + 4099])
def test_zeroes_the_leading_bytes_only(device, nbytes):
    size = nbytes + 37
    junk = np.random.default_rng(nbytes).integers(1, 256, size, dtype=np.uint8)
    buf = cl.Buffer(device.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR,
                    hostbuf=junk)
    zero_buffer(device.queue, buf, nbytes).wait()
    got = np.empty(size, np.uint8)
    cl.enqueue_copy(device.queue, got, buf)
    expected = junk.copy()
    expected[:nbytes] = 0
    assert np.count_nonzero(got[:nbytes]) == 0
    np.testing.assert_array_equal(got[nbytes:], expected[nbytes:])


def test_refuses_more_bytes_than_the_buffer(device):
    buf = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, 64)
    with pytest.raises(ValueError, match="65 bytes of a 64-byte buffer"):
        zero_buffer(device.queue, buf, 65)
