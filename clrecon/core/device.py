"""OpenCL device layer: enumerate and choose devices, profiling queues, cached program builds.

The library never prints; everything here either returns data or raises
:class:`~clrecon.core.errors.DeviceError` / :class:`~clrecon.core.errors.KernelBuildError`.

Choosing a device: ``get_device(spec)`` with ``spec`` an index into :func:`list_devices`, a
case-insensitive substring of ``"platform / device"``, or ``None`` (then the environment
variable ``CLRECON_DEVICE``, then the first GPU, then the first device, simulators such as
Oclgrind last: they are chosen by name or index only). Converged
references come from :func:`trusted_device` (PoCL), never from that choice.

Programs are built and cached by :mod:`clrecon.core.build` (binaries on disk:
:mod:`clrecon.core.program_cache`); this module re-exports their public names, so that
``clrecon.core.device`` stays the one import of the device layer.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Union

import numpy as np
import pyopencl as cl

from clrecon.core.build import (
    Defines,
    build_options,
    build_program,
    build_source,
    get_kernel,
    kernel_source,
    language_options,
    native_fp32_atomic_add,
    opencl_c_std,
    source_hash,
)
from clrecon.core.errors import DeviceError
from clrecon.core.fsutil import ENV_CACHE_DIR
from clrecon.core.knobs import KnobTypeError
from clrecon.core.program_cache import program_cache_dir, program_cache_stats

__all__ = [
    "ENV_CACHE_DIR", "ENV_DEVICE", "TRUSTED_PLATFORM", "Defines", "Device", "DeviceInfo",
    "DeviceSpec", "build_options", "build_program", "build_source", "describe", "event_ms",
    "fixed_to_float", "from_queue", "get_device", "get_kernel", "kernel_source",
    "language_options", "list_devices", "native_fp32_atomic_add", "opencl_c_std",
    "program_cache_dir", "program_cache_stats", "source_hash", "trusted_device",
]

ENV_DEVICE = "CLRECON_DEVICE"

DeviceSpec = Union[int, str, None]


@dataclass(frozen=True)
class DeviceInfo:
    """What a person (and the tuning database) needs to know about one OpenCL device."""

    index: int
    platform: str
    platform_version: str
    name: str
    vendor: str
    driver: str
    version: str
    device_type: str
    compute_units: int
    global_mem_bytes: int
    local_mem_bytes: int
    max_work_group_size: int
    image_support: bool
    int64_atomics: bool
    native_float_atomics: bool

    @property
    def label(self) -> str:
        return f"{self.platform} / {self.name}"

    @property
    def atomics(self) -> str:
        """Short description of the float accumulation paths this device gets."""
        float_path = "native float add" if self.native_float_atomics else "float CAS loop"
        fixed = "int64 fixed point" if self.int64_atomics else "no int64 atomics"
        return f"{float_path}, {fixed}"

    def fingerprint(self) -> dict:
        """Identity used as a tuning-database key (platform kept apart from hardware vendor)."""
        return {
            "platform": self.platform,
            "platform_version": self.platform_version,
            "vendor": self.vendor,
            "device": self.name,
            "driver": self.driver,
            "device_type": self.device_type,
            "compute_units": self.compute_units,
        }


def _type_name(bits: int) -> str:
    for flag, name in ((cl.device_type.GPU, "GPU"), (cl.device_type.CPU, "CPU"),
                       (cl.device_type.ACCELERATOR, "ACCELERATOR")):
        if bits & flag:
            return name
    return "OTHER"


def _info(index: int, dev: cl.Device) -> DeviceInfo:
    ext = dev.extensions.split()
    return DeviceInfo(
        index=index,
        platform=dev.platform.name.strip(),
        platform_version=dev.platform.version.strip(),
        name=dev.name.strip(),
        vendor=dev.vendor.strip(),
        driver=dev.driver_version.strip(),
        version=dev.version.strip(),
        device_type=_type_name(dev.type),
        compute_units=int(dev.max_compute_units),
        global_mem_bytes=int(dev.global_mem_size),
        local_mem_bytes=int(dev.local_mem_size),
        max_work_group_size=int(dev.max_work_group_size),
        image_support=bool(dev.image_support),
        int64_atomics="cl_khr_int64_base_atomics" in ext,
        native_float_atomics="cl_ext_float_atomics" in ext,
    )


def _all_devices() -> list[cl.Device]:
    try:
        platforms = cl.get_platforms()
    except cl.Error as exc:  # no ICD at all
        raise DeviceError(
            "no OpenCL platform found; install a driver (e.g. `apt-get install "
            "pocl-opencl-icd` for the CPU)"
        ) from exc
    devices = []
    for plat in platforms:
        try:
            devices.extend(plat.get_devices())
        except cl.Error:  # a platform with no devices of any type
            continue
    return devices


def list_devices() -> list[DeviceInfo]:
    """Every OpenCL device on every platform, in a stable order (the index of ``--device``)."""
    return [_info(i, d) for i, d in enumerate(_all_devices())]


def _check_spec(spec, name: str = "device"):
    """``spec`` if it is a device index, a name substring or ``None``; a ``TypeError``
    (``KnobTypeError``) or ``ValueError`` naming the argument otherwise."""
    if spec is None:
        return None
    if isinstance(spec, (bool, np.bool_)) or not isinstance(spec, (int, np.integer, str)):
        raise KnobTypeError(f"{name}: must be a device index (int), a name substring (str), "
                            f"a Device or None, got {spec!r} ({type(spec).__name__})")
    if isinstance(spec, str):
        if not spec.strip():
            raise ValueError(f"{name}: empty device name (give an index, a substring of "
                             f"'platform / device' or None)")
        return spec
    return int(spec)


#: platforms that simulate a device (Oclgrind checks every memory access): kernels run orders
#: of magnitude slower than on hardware, so neither ``get_device(None)`` nor the default test
#: run takes one while a real device is present
SIMULATOR_PLATFORMS = ("Oclgrind",)


def is_simulator(platform: str) -> bool:
    """Whether the platform named ``platform`` is a simulator (:data:`SIMULATOR_PLATFORMS`)."""
    return any(s.lower() in platform.strip().lower() for s in SIMULATOR_PLATFORMS)


def cpu_context(context: cl.Context) -> bool:
    """Whether every device of ``context`` is a CPU: the passes that take several outputs a
    work-item as explicit vector lanes there (PoCL 3.1 does not vectorise across work-items a
    kernel that holds vector values) ask this."""
    return all(d.type & cl.device_type.CPU for d in context.devices)


def _default_index(devices: list[cl.Device]) -> int:
    """The first GPU, else the first device; simulators only where nothing else is."""
    real = [i for i, d in enumerate(devices) if not is_simulator(d.platform.name)]
    pool = real or list(range(len(devices)))
    gpus = [i for i in pool if devices[i].type & cl.device_type.GPU]
    return (gpus or pool)[0]


def _pick(spec: DeviceSpec) -> tuple[int, cl.Device]:
    spec = _check_spec(spec)
    devices = _all_devices()
    if not devices:
        raise DeviceError("no OpenCL device found on any platform")
    if spec is None:
        spec = _check_spec(os.environ.get(ENV_DEVICE, "").strip() or None, ENV_DEVICE)
    if spec is None:
        i = _default_index(devices)
        return i, devices[i]
    if isinstance(spec, str) and spec.strip().isdigit():
        spec = int(spec)
    labels = [f"{d.platform.name.strip()} / {d.name.strip()}" for d in devices]
    if isinstance(spec, int):
        if not 0 <= spec < len(devices):
            raise DeviceError(f"device index {spec} out of range; devices: {labels}")
        return spec, devices[spec]
    matches = [i for i, lab in enumerate(labels) if spec.lower() in lab.lower()]
    if not matches:
        raise DeviceError(f"no OpenCL device matches {spec!r}; devices: {labels}")
    return matches[0], devices[matches[0]]


@dataclass(eq=False)
class Device:
    """One OpenCL device with its context and an in-order profiling queue."""

    info: DeviceInfo
    device: cl.Device
    context: cl.Context
    queue: cl.CommandQueue = field(repr=False)

    def program(self, name: str, defines: Defines | None = None) -> cl.Program:
        return build_program(self.context, name, defines)

    def kernel(self, name: str, kernel_name: str, defines: Defines | None = None) -> cl.Kernel:
        return get_kernel(self.context, name, kernel_name, defines)


_devices: dict[int, Device] = {}


def get_device(spec: DeviceSpec = None) -> Device:
    """The :class:`Device` for ``spec`` (see module docstring); one per device per process."""
    if isinstance(spec, Device):
        return spec
    index, dev = _pick(spec)
    if index not in _devices:
        ctx = cl.Context([dev])
        queue = cl.CommandQueue(ctx, properties=cl.command_queue_properties.PROFILING_ENABLE)
        _devices[index] = Device(_info(index, dev), dev, ctx, queue)
    return _devices[index]


#: the platform converged references come from (:func:`trusted_device`)
TRUSTED_PLATFORM = "Portable Computing Language"


def trusted_device() -> Device:
    """The device converged references are rendered on: PoCL's CPU device (else another PoCL
    device), whatever ``CLRECON_DEVICE`` or ``--device`` choose. A reference made on the
    device under test would carry that device's own faults into the image it is compared
    with (Intel's CPU compiler once returned garbage from ``raytrace_reference``, and the
    comparisons agreed with it); PoCL is the platform CI checks against the NumPy tracer.
    Raises :class:`~clrecon.core.errors.DeviceError` where no PoCL device is registered."""
    devices = _all_devices()
    pocl = [i for i, d in enumerate(devices) if d.platform.name.strip() == TRUSTED_PLATFORM]
    if not pocl:
        labels = [f"{d.platform.name.strip()} / {d.name.strip()}" for d in devices]
        raise DeviceError(
            f"no trusted device for references: they are rendered on PoCL ('{TRUSTED_PLATFORM}'"
            f"), which is not among the devices {labels}; install it (`bash run.sh setup`) and, "
            f"where OCL_ICD_VENDORS is set, put its .icd file in that folder too (or, from "
            f"Python, give render_reference the device= to render on)")
    cpus = [i for i in pocl if devices[i].type & cl.device_type.CPU]
    return get_device((cpus or pocl)[0])


def describe(dev: cl.Device) -> DeviceInfo:
    """:class:`DeviceInfo` of any ``cl.Device`` (index -1 if it is not in the list)."""
    for i, d in enumerate(_all_devices()):
        if d.int_ptr == dev.int_ptr:
            return _info(i, d)
    return _info(-1, dev)


def from_queue(queue: cl.CommandQueue) -> DeviceInfo:
    """Describe the device of a caller's queue (for embedding in a foreign pipeline)."""
    return describe(queue.device)


def event_ms(event: cl.Event) -> float:
    """Device time of a completed profiling event, in milliseconds."""
    return (event.profile.end - event.profile.start) * 1e-6


def fixed_to_float(values, shift: int = 20):
    """Convert int64 fixed-point sums written by ``atomic_add_fixed`` to float32."""
    return (np.asarray(values, dtype=np.int64).astype(np.float64) / float(1 << shift)).astype(
        np.float32
    )
