"""OpenCL device selection and program building.

One place decides which device runs the kernels and builds each program once per context:

* ``PYOPENCL_CTX`` is honoured exactly as pyopencl documents it (e.g. ``PYOPENCL_CTX=0:0``);
* otherwise the first PoCL CPU device is used, falling back to the first device of any
  platform, so the same code runs on a laptop's CPU and on any OpenCL GPU unchanged.

Programs are read from the ``.cl`` files shipped as package data (``pydynrad.kernels``),
built with ``-I <kernel dir>`` so sources can ``#include`` shared helpers, and cached per
(context, file, defines). pyopencl's binary cache is used where it helps; PoCL keeps its own,
in ``POCL_CACHE_DIR`` (set here to a writable per-user folder when the user has not chosen one,
so a second run reuses the compiled work-group functions instead of compiling them again
inside the first frames).

Compiler output (build logs, pyopencl's ``CompilerWarning``) stays silent unless the user asks
for it with ``PYOPENCL_COMPILER_OUTPUT=1`` or ``PYDYNRAD_DEBUG=1``.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import threading
import warnings
from dataclasses import dataclass, field, replace
from functools import cached_property
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import DeviceError, InvalidInputError, KernelBuildError
from .pocl import cache_tag, compiler_target, fix_cpu_name, host_cpu_family, replaced_cpu

if TYPE_CHECKING:  # pyopencl is imported lazily so that `import pydynrad` stays cheap
    import pyopencl as cl

__all__ = ["Device", "DeviceTraits", "default_device", "device_or_default", "kernel_dir", "list_devices", "real_dtype"]


def _writable(folder: Path) -> bool:
    try:
        folder.mkdir(parents=True, exist_ok=True)
        return os.access(folder, os.W_OK)
    except OSError:
        return False


def _use_pocl_cache() -> None:
    """Point PoCL's kernel cache at a writable folder unless ``POCL_CACHE_DIR`` is set.

    PoCL compiles each kernel's work-group function at its first launch (per local size) and
    caches it on disk; without a writable cache every run compiles again. Must run before
    PoCL is loaded (the first pyopencl platform query)."""
    if os.environ.get("POCL_CACHE_DIR"):
        return
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    tag = cache_tag()  # see pocl_target: PoCL's own key cannot tell the CPU names written apart
    for folder in (
        base / "pocl" / tag,
        Path(tempfile.gettempdir()) / f"pocl-cache-{getattr(os, 'getuid', lambda: 0)()}" / tag,
    ):
        if _writable(folder):
            os.environ["POCL_CACHE_DIR"] = str(folder)
            return


def compiler_output_wanted() -> bool:
    """Whether build logs are shown: ``PYOPENCL_COMPILER_OUTPUT=1`` or ``PYDYNRAD_DEBUG=1``."""
    return any(os.environ.get(v, "0") not in ("", "0") for v in ("PYOPENCL_COMPILER_OUTPUT", "PYDYNRAD_DEBUG"))


class _Printed:
    text = ""


@contextlib.contextmanager
def _captured_stderr():
    """Collect what is written to file descriptor 2 meanwhile (PoCL's clang prints its
    diagnostics, "N warnings generated", there directly, past Python's sys.stderr).

    Only around a build, under the program lock: the build blocks the thread that would
    otherwise print, so little else can land here."""
    out = _Printed()
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no real fd 2 (an embedding host): nothing to capture
        yield out
        return
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield out
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            out.text = tmp.read().decode(errors="replace")


def kernel_dir() -> Path:
    """The folder holding the ``.cl`` sources (works for wheels and editable installs)."""
    return Path(str(resources.files("pydynrad.kernels")))


@dataclass(frozen=True)
class DeviceTraits:
    """What the kernel layouts (:mod:`pydynrad.device.launch`) know of a device: they read nothing else,
    so a layout can be chosen for, and tested against, a device that is not here.

    cpu : bool
        A CPU device (a few fat work-items with long contiguous runs) or not (many coalesced ones).
    compute_units : int
        ``max_compute_units``: cores on a CPU, multiprocessors on a GPU.
    float_width, double_width : int
        ``preferred_vector_width_float`` / ``_double``: elements per native SIMD register on a
        CPU (16/8 with AVX-512, 8/4 with AVX2, 4/2 with SSE or NEON); GPUs often report 1.
    max_work_group : int
        ``max_work_group_size``.
    local_mem_bytes : int
        ``local_mem_size``.
    aligned_vectors : bool
        Kernels may use aligned vector dereference and clang's vector conversions
        (``PDR_CLANG_VECTORS`` in ``kernels/storage.h``): see :attr:`Device.aligned_vector_access`.
    cache_bytes : int
        ``global_mem_cache_size`` (PoCL: the CPU's last-level cache; 0 where not reported).
    """

    cpu: bool
    compute_units: int
    float_width: int
    double_width: int
    max_work_group: int
    local_mem_bytes: int
    aligned_vectors: bool = False
    cache_bytes: int = 0


@dataclass(eq=False)
class Device:
    """An OpenCL context and in-order queue on one device, with a program cache.

    Create one with :func:`default_device` (the usual way) or wrap an existing context.
    """

    context: cl.Context
    queue: cl.CommandQueue = None  # type: ignore[assignment]
    _programs: dict = field(default_factory=dict, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    _traits: DeviceTraits | None = field(default=None, repr=False)
    # Per thread, (program id, name) -> (program, kernel): see kernel().
    _kernels: threading.local = field(default_factory=threading.local, repr=False)

    def __post_init__(self) -> None:
        import pyopencl as cl

        for d in self.context.devices:
            fix_cpu_name(d)
        if self.queue is None:
            self.queue = cl.CommandQueue(self.context)
        elif self.queue.properties & cl.command_queue_properties.OUT_OF_ORDER_EXEC_MODE_ENABLE:
            # Every launcher relies on it: a read waits for the kernels before it, a scratch
            # buffer is reused after the kernel that read it.
            raise InvalidInputError(
                "pydynrad needs an in-order command queue; got one with OUT_OF_ORDER_EXEC_MODE_ENABLE"
            )

    @property
    def cl_device(self):
        return self.context.devices[0]

    @property
    def name(self) -> str:
        d = self.cl_device
        return f"{d.platform.name.strip()} / {d.name.strip()}"

    @cached_property
    def supports_fp64(self) -> bool:
        d = self.cl_device
        return "cl_khr_fp64" in d.extensions or bool(getattr(d, "double_fp_config", 0))

    @property
    def is_cpu(self) -> bool:
        import pyopencl as cl

        # Oclgrind reports every type bit (CPU | GPU | ACCELERATOR): it simulates a GPU-like
        # device, so a device that says GPU gets the GPU layouts even where it also says CPU.
        t = self.cl_device.type
        return bool(t & cl.device_type.CPU) and not t & cl.device_type.GPU

    @cached_property
    def aligned_vector_access(self) -> bool:
        """Whether kernels may read and write 16-wide vectors by aligned dereference
        (``PDR_CLANG_VECTORS`` in ``kernels/storage.h``): PoCL CPU devices, whose compiler is
        clang and whose buffers start on >= 128-byte boundaries. Their vload/vstore builtins
        are not inlined, which costs about 2x in streaming loops."""
        d = self.cl_device
        return (
            self.is_cpu
            and "portable computing language" in d.platform.name.lower()
            and int(d.mem_base_addr_align) >= 1024
        )

    @property
    def traits(self) -> DeviceTraits:
        """What the kernel layouts read of this device (as reported, unless :meth:`with_traits` set them)."""
        if self._traits is None:
            d = self.cl_device
            self._traits = DeviceTraits(
                cpu=self.is_cpu,
                compute_units=max(1, int(d.max_compute_units)),
                float_width=max(1, int(d.preferred_vector_width_float)),
                double_width=max(1, int(d.preferred_vector_width_double)),
                max_work_group=int(d.max_work_group_size),
                local_mem_bytes=int(d.local_mem_size),
                aligned_vectors=self.aligned_vector_access,
                cache_bytes=int(d.global_mem_cache_size),
            )
        return self._traits

    def with_traits(self, **changes) -> Device:
        """The same context, queue and program cache with some :class:`DeviceTraits` changed, so
        every layout is chosen as for that device: e.g. ``with_traits(float_width=8,
        aligned_vectors=False)`` runs the kernels an AVX2 CPU without PoCL would get."""
        return Device(self.context, self.queue, self._programs, self._lock, replace(self.traits, **changes))

    @property
    def global_mem_bytes(self) -> int:
        return int(self.cl_device.global_mem_size)

    @property
    def max_alloc_bytes(self) -> int:
        return int(self.cl_device.max_mem_alloc_size)

    def program(self, filename: str, defines: dict[str, object] | None = None):
        """Build (once) and return the program in ``kernels/<filename>``.

        ``defines`` become ``-D NAME=VALUE`` options, so one source serves several storage
        types or tile sizes; each distinct set is built and cached separately.
        """
        import pyopencl as cl

        opts = tuple(sorted(f"-D{k}={v}" for k, v in (defines or {}).items()))
        key = (filename, opts)
        with self._lock:
            prg = self._programs.get(key)
            if prg is not None:
                return prg
            path = kernel_dir() / filename
            try:
                src = path.read_text()
            except OSError as exc:
                raise KernelBuildError(f"cannot read kernel source {path}: {exc}") from exc
            options = ["-I", str(kernel_dir()), *opts]
            try:
                with warnings.catch_warnings(), _captured_stderr() as printed:
                    warnings.simplefilter("ignore", cl.CompilerWarning)
                    prg = cl.Program(self.context, src).build(options=options)
            except cl.RuntimeError as exc:
                # pyopencl puts each device's build log into the message.
                log = str(exc)
                if "unknown target CPU" in log:
                    log += (
                        "\n(this OpenCL compiler does not know this CPU, and pydynrad could not give it one: "
                        "see pydynrad/device/pocl.py)"
                    )
                raise KernelBuildError(f"OpenCL build of {filename} failed on {self.name}", log) from exc
            if compiler_output_wanted():
                log = str(prg.get_build_info(self.cl_device, cl.program_build_info.LOG) or "").strip()
                text = "\n".join(t for t in (log, printed.text.strip()) if t)
                if text:
                    warnings.warn(
                        f"build log of {filename} {' '.join(opts)} on {self.name}:\n{text}",
                        cl.CompilerWarning,
                        stacklevel=2,
                    )
            self._programs[key] = prg
            return prg

    def kernel(self, filename: str, name: str, defines: dict[str, object] | None = None):
        """Kernel ``name`` of :meth:`program` (filename, defines): one object per thread, made
        once and reused. A kernel object holds its arguments, so it must not be shared across
        threads; within one, every caller sets all arguments and enqueues in one call, so
        sharing is safe. A fresh pyopencl Kernel pays its argument handler's setup on every
        call, many times a reused one's cost, and a frame or a move makes several
        (docs/decisions/0005-warm-up-and-fixed-local-sizes.md)."""
        import pyopencl as cl

        prg = self.program(filename, defines)
        cache = getattr(self._kernels, "cache", None)
        if cache is None:
            cache = self._kernels.cache = {}
        hit = cache.get((id(prg), name))
        if hit is None or hit[0] is not prg:
            hit = cache[(id(prg), name)] = (prg, cl.Kernel(prg, name))
        return hit[1]

    def info(self) -> dict[str, object]:
        """What a user needs to know about this device, as plain values."""
        d = self.cl_device
        family = host_cpu_family() if self.is_cpu else None
        return {
            "platform": d.platform.name.strip(),
            "device": d.name.strip(),
            "version": d.version.strip(),
            "type": "CPU" if self.is_cpu else "GPU/accelerator",
            "compute_units": int(d.max_compute_units),
            "global_memory_MiB": self.global_mem_bytes // 2**20,
            "max_alloc_MiB": self.max_alloc_bytes // 2**20,
            "fp64": self.supports_fp64,
            "fp16_arithmetic": "cl_khr_fp16" in d.extensions,
            **(
                {"compiler_cpu": f"{replaced_cpu(d)} (PoCL's LLVM named it {target[1]})"}
                if replaced_cpu(d) and (target := compiler_target(d))
                else {}
            ),
            **({"cpu_family": family} if family else {}),
        }

    def to_device(self, array: np.ndarray):
        """Copy a host array to a new read-only device buffer (one element where it is empty).

        Also the way small per-call inputs go up: on PoCL this costs little more than the copy,
        where a queued write into an existing buffer costs tens of times as much
        (:mod:`pydynrad.device.transfers`)."""
        import pyopencl as cl

        a = np.ascontiguousarray(array)
        if a.nbytes == 0:
            a = np.zeros(1, dtype=a.dtype)
        return cl.Buffer(self.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR, hostbuf=a)


_default: Device | None = None
_default_lock = threading.Lock()


def _pick_cl_device():
    _use_pocl_cache()
    import pyopencl as cl

    if os.environ.get("PYOPENCL_CTX"):
        try:
            return cl.create_some_context(interactive=False)
        except cl.Error as exc:
            raise DeviceError(
                f"PYOPENCL_CTX={os.environ['PYOPENCL_CTX']!r} selects no OpenCL device ({exc}); "
                "`pydynrad info` lists the valid values"
            ) from exc
    try:
        platforms = cl.get_platforms()
    except cl.Error as exc:
        raise DeviceError(
            "no OpenCL platform found; install the PoCL wheel (pip install pocl-binary-distribution) "
            "or a GPU vendor's OpenCL driver"
        ) from exc
    candidates = []
    for p in platforms:
        try:
            devs = p.get_devices()
        except cl.Error:
            continue
        for d in devs:
            pocl_cpu = "portable computing language" in p.name.lower() and d.type & cl.device_type.CPU
            candidates.append((0 if pocl_cpu else 1, d))
    if not candidates:
        raise DeviceError("OpenCL platforms exist but none offers a device")
    candidates.sort(key=lambda t: t[0])
    return cl.Context([candidates[0][1]])


def default_device() -> Device:
    """The process-wide device: built on first use, shared by every call after that."""
    global _default
    with _default_lock:
        if _default is None:
            _default = Device(_pick_cl_device())
        return _default


def device_or_default(device) -> Device:
    """``device`` where it is a :class:`Device`, the :func:`default_device` for None;
    InvalidInputError for anything else (a name, a pyopencl device)."""
    if device is None:
        return default_device()
    if not isinstance(device, Device):
        raise InvalidInputError(
            f"device must be a pydynrad Device (pydynrad.default_device(), pydynrad.device.Device(...)) "
            f"or None; got {type(device).__name__}"
        )
    return device


def list_devices() -> list[dict[str, object]]:
    """Every OpenCL device visible to this process, with the ``PYOPENCL_CTX`` key selecting it."""
    import pyopencl as cl

    out = []
    for pi, p in enumerate(cl.get_platforms()):
        for di, d in enumerate(p.get_devices()):
            out.append(
                {
                    "PYOPENCL_CTX": f"{pi}:{di}",
                    "platform": p.name.strip(),
                    "device": d.name.strip(),
                    "type": cl.device_type.to_string(d.type),  # type: ignore[operator]  # pyopencl's stub types the class, not its static method
                    "compute_units": int(d.max_compute_units),
                    "global_memory_MiB": int(d.global_mem_size) // 2**20,
                }
            )
    return out


def real_dtype(dtype, device) -> np.dtype:
    """``dtype`` as the working precision of kernels on ``device``: float32, or float64 where
    the device has ``cl_khr_fp64`` (:class:`DeviceError` otherwise)."""
    real = np.dtype(dtype)
    if real not in (np.float32, np.float64):
        raise InvalidInputError(f"dtype must be float32 or float64; got {real}")
    if real == np.float64 and not device.supports_fp64:
        raise DeviceError(f"float64 needs cl_khr_fp64, which {device.name} lacks; use dtype=np.float32")
    return real
