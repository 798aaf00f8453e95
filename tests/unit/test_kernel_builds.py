"""Every kernel file builds on its own, with its default defines, on every device: a kernel
whose host always passes some define still compiles for a reader, a linter or a new host,
and a default that drifted from the code (an undeclared identifier, a header that needs a
macro) fails here rather than in the pass that happens to use it last."""
from __future__ import annotations

import pyopencl as cl
import pytest

from clrecon.core import device as cldev
from clrecon.core.errors import KernelBuildError
from clrecon.core.resources import kernels_dir

#: defines a kernel file cannot do without, and why: the value here is only one a host
#: could pass. Every other compile-time constant of every file has a default.
REQUIRED: dict[str, dict] = {
    # the record size of the renderer's struct: no default could be right (adapter.py
    # passes RecordLayout.defines()); the file stops with an #error naming it
    "adapt": {"STRIDE": 16},
}

KERNEL_FILES = sorted(p.stem for p in kernels_dir().glob("*.cl"))


def test_the_table_names_only_existing_files():
    assert KERNEL_FILES, "no kernel files found"
    assert set(REQUIRED) <= set(KERNEL_FILES)


@pytest.mark.parametrize("name", KERNEL_FILES)
def test_kernel_file_builds_alone(device, name):
    prg = cldev.build_program(device.context, name, REQUIRED.get(name, {}))
    kernels = prg.all_kernels()
    assert kernels, f"kernels/{name}.cl defines no kernel"
    for k in kernels:  # each kernel of the file is there for the device
        assert k.get_work_group_info(cl.kernel_work_group_info.WORK_GROUP_SIZE,
                                     device.device) >= 1


@pytest.mark.parametrize("name", sorted(REQUIRED))
def test_required_defines_are_required(device, name):
    """A define listed as required really is: without it the build fails naming it (else the
    file should give it a default and leave the table)."""
    for define in REQUIRED[name]:
        partial = {k: v for k, v in REQUIRED[name].items() if k != define}
        with pytest.raises(KernelBuildError, match=define):
            cldev.build_program(device.context, name, partial)
