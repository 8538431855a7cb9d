"""A CPU name PoCL 3.0's compiler can compile its own kernel library for, on CPUs newer than its LLVM.

The PoCL of the pip wheel (``pocl-binary-distribution`` 3.0: PoCL 3.0-rc2 on LLVM 14.0.6) asks LLVM
for the host's CPU name and hands it to clang as ``-target-cpu``. LLVM 14 predates, among others,
AMD Zen 4 (family 19h, model 10h and up) and Zen 5 (family 1Ah), and answers wrongly for both:

- on Zen 5 it answers ``generic``; clang 14 refuses that name ("unknown target CPU 'generic'"), and
  every program build fails;
- on Zen 4 it answers ``znver3``, a CPU without AVX-512, while PoCL picks its kernel library variant
  by the host's flags (AVX-512F: the ``skylake-avx512`` variant) and reports 16-wide preferred
  vectors. Programs build, but the first launch of any kernel that calls a 16-wide builtin
  (``floor``, ``rsqrt``, ``fabs`` on ``float16``) aborts the process inside LLVM's code generator
  ("LLVM ERROR: Cannot select: ... vselect"): the library's AVX-512 code cannot be compiled for a
  CPU without it (docs/decisions/0004-pocl-compiler.md).

PoCL 3.0 has no setting for the name (``POCL_LLVM_CPU_NAME`` came in a later release) and refuses
``-target-cpu`` among build options. So, on a PoCL CPU device whose compiler CPU is ``generic``, or
lacks AVX-512 where the kernel library variant needs it (PoCL prints the CPU at the end of the
device's version string, ``HSTR: pthread-<triple>-<cpu>``), :func:`fix_cpu_name` writes another
name into PoCL's device record: the CPU that PoCL's kernel library variant for this host was
compiled for (``skylake-avx512`` where AVX-512F is present, ``haswell`` with AVX2, ...), provided
the host has the x86-64 psABI level that CPU implies; else that level itself (``x86-64-v4``,
``-v3``, ...). LLVM 14 knows both kinds of name. The variant's own CPU is preferred because LLVM
inlines a builtin of the kernel library (``floor``, ``fmin``, ``vload16``, ...) only into code
compiled for at least the features the builtin was compiled for: with ``x86-64-v4`` each is an
out-of-line call (see docs/design.md, 'Practical notes'). The record is found by content, not by a
compiled-in offset: the pointer that follows the pointer to the target triple and points at the
CPU name the version string gives. Reads go only to mapped readable memory; if the record is not
found nothing is written and builds fail (or abort) as before. ``PYDYNRAD_POCL_CPU=<an LLVM 14 CPU
name>`` chooses the name instead; it must have the instruction sets of the kernel library variant
(``znver3`` on an AVX-512 host fails: the library's AVX-512 code cannot be compiled for it).

PoCL's kernel cache keys its entries by the CPU name LLVM reports (``generic`` for every CPU it does
not know), not by the name written here, so :func:`cache_tag` names a cache folder per written name:
two such machines sharing a home folder, or a changed ``PYDYNRAD_POCL_CPU``, never reuse each
other's binaries.
"""

from __future__ import annotations

import ctypes
import functools
import os
import platform
import threading
from pathlib import Path

__all__ = [
    "host_cpu_family",
    "psabi_level",
    "library_cpu",
    "target_name",
    "cache_tag",
    "fix_cpu_name",
    "replaced_cpu",
    "compiler_target",
]

# PoCL 3.0's x86-64 kernel library variants (lib/CL/pocl_llvm_utils.cc, kernellib_feature_map), in
# its order (the last that matches wins): the CPU each was compiled for, the /proc/cpuinfo flags
# PoCL picks it by (LLVM's names translated: sse4.1 -> sse4_1, lzcnt -> abm, bmi -> bmi1), and the
# psABI level that CPU implies.
_KERNEL_LIBRARIES = (
    ("athlon64", {"sse2"}, "x86-64"),
    ("core2", {"sse2", "ssse3", "cx16"}, "x86-64"),
    ("penryn", {"sse2", "sse4_1", "cx16"}, "x86-64"),
    ("sandybridge", {"sse2", "avx", "cx16", "popcnt"}, "x86-64-v2"),
    ("ivybridge", {"sse2", "avx", "cx16", "popcnt", "f16c"}, "x86-64-v2"),
    ("bdver1", {"sse2", "avx", "cx16", "popcnt", "xop", "fma4"}, "x86-64-v2"),
    ("haswell", {"sse2", "avx", "avx2", "cx16", "popcnt", "abm", "f16c", "fma", "bmi1", "bmi2"}, "x86-64-v3"),
    ("skylake-avx512", {"sse2", "avx512f"}, "x86-64-v4"),
)

# The x86-64 psABI micro-architecture levels by the /proc/cpuinfo flags each adds to the one before
# (x86-64 psABI 1.0, section 3.1.1); "abm" is how Linux names LZCNT.
_LEVELS = (
    ("x86-64-v2", {"cx16", "lahf_lm", "popcnt", "sse4_1", "sse4_2", "ssse3"}),
    ("x86-64-v3", {"avx", "avx2", "bmi1", "bmi2", "f16c", "fma", "abm", "movbe", "xsave"}),
    ("x86-64-v4", {"avx512f", "avx512bw", "avx512cd", "avx512dq", "avx512vl"}),
)

_lock = threading.Lock()
_replaced: dict[int, str] = {}  # cl_device_id address -> the name written there


def psabi_level(flags: set[str]) -> str:
    """The highest x86-64 psABI level (an LLVM CPU name) whose features are all in ``flags``."""
    name = "x86-64"
    have: set[str] = set()
    for level, needs in _LEVELS:
        have |= needs
        if not have <= flags:
            break
        name = level
    return name


@functools.cache
def _cpuinfo() -> dict[str, str]:
    """The first processor's fields of /proc/cpuinfo (empty where there is none)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return {}
    fields: dict[str, str] = {}
    for line in text.splitlines():
        if not line.strip():
            break
        key, _, value = line.partition(":")
        fields.setdefault(key.strip(), value.strip())
    return fields


def _cpu_flags() -> set[str]:
    return set(_cpuinfo().get("flags", "").split())


def host_cpu_family() -> str | None:
    """The host CPU's family and model as /proc/cpuinfo gives them, in hex as vendors write them
    (``"17h/31h"`` for an AMD Zen 2 EPYC), or None where unknown. Cloud CPUs often report a bare
    model name (``"AMD EPYC"``) shared by several generations; this tells them apart."""
    info = _cpuinfo()
    try:
        return f"{int(info['cpu family']):x}h/{int(info['model']):x}h"
    except (KeyError, ValueError):
        return None


def library_cpu(flags: set[str]) -> str:
    """The CPU name to compile for on a host with ``flags``: that of the kernel library variant PoCL
    picks there if the host has the psABI level it implies, else the host's psABI level."""
    level = psabi_level(flags)
    order = ["x86-64"] + [name for name, _ in _LEVELS]
    chosen = [(cpu, implies) for cpu, needs, implies in _KERNEL_LIBRARIES if needs <= flags]
    if chosen and order.index(level) >= order.index(chosen[-1][1]):
        return chosen[-1][0]
    return level


def target_name() -> str:
    """The CPU name :func:`fix_cpu_name` writes: ``PYDYNRAD_POCL_CPU`` or :func:`library_cpu`."""
    return os.environ.get("PYDYNRAD_POCL_CPU") or library_cpu(_cpu_flags())


def cache_tag() -> str:
    """A folder name for PoCL's kernel cache that separates the names written (see the module)."""
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in target_name())


def _readable_ranges() -> list[tuple[int, int]]:
    ranges = []
    with open("/proc/self/maps") as maps:
        for line in maps:
            span, perms = line.split()[:2]
            if perms.startswith("r"):
                lo, hi = (int(x, 16) for x in span.split("-"))
                ranges.append((lo, hi))
    return ranges


def _reader(ranges: list[tuple[int, int]]):
    def readable(address: int, size: int) -> bool:
        return any(lo <= address and address + size <= hi for lo, hi in ranges)

    def pointer_at(address: int) -> int | None:
        return ctypes.c_uint64.from_address(address).value if readable(address, 8) else None

    def string_is(pointer: int, expected: bytes) -> bool:
        return (
            bool(pointer)
            and readable(pointer, len(expected) + 1)
            and ctypes.string_at(pointer, len(expected) + 1) == expected + b"\0"
        )

    return pointer_at, string_is


# The CPU names LLVM gives AVX-512 (FeatureAVX512F in llvm/lib/TargetParser/X86TargetParser.cpp):
# LLVM 14's, and those of later releases, so that a newer PoCL naming its host right is left alone.
_AVX512_CPUS = frozenset(
    {
        "knl",
        "knm",
        "skylake-avx512",
        "skx",
        "cascadelake",
        "cooperlake",
        "cannonlake",
        "icelake-client",
        "icelake-server",
        "rocketlake",
        "tigerlake",
        "sapphirerapids",
        "x86-64-v4",
        "znver4",
        "znver5",
        "emeraldrapids",
        "graniterapids",
        "graniterapids-d",
        "diamondrapids",
    }
)


def needs_replacing(cpu: str, flags: set[str]) -> bool:
    """Whether LLVM's CPU name ``cpu`` cannot compile PoCL's kernel library variant for a host with
    ``flags``: ``generic`` (clang refuses it), or a CPU without AVX-512 where PoCL picks the
    avx512 variant (by ``avx512f`` alone, :data:`_KERNEL_LIBRARIES`)."""
    return cpu == "generic" or ("avx512f" in flags and cpu not in _AVX512_CPUS)


def compiler_target(device) -> tuple[str, str] | None:
    """(target triple, CPU name) of a PoCL x86-64 CPU device's compiler as PoCL reports it (the
    name before any :func:`fix_cpu_name`), else None."""
    import pyopencl as cl

    if "portable computing language" not in device.platform.name.lower() or not device.type & cl.device_type.CPU:
        return None
    hstr = device.version.partition("HSTR:")[2].strip()  # e.g. "pthread-x86_64-unknown-linux-gnu-generic"
    _, _, rest = hstr.partition("-")
    triple, sep, cpu = rest.rpartition("-")
    return (triple, cpu) if sep and triple.startswith("x86_64") else None


def fix_cpu_name(device) -> str | None:
    """Give a PoCL CPU ``device`` (a ``pyopencl.Device``) whose compiler CPU cannot compile the kernel
    library (``needs_replacing``) the library's own CPU instead, once per process; return the
    name written (or written before), None where nothing needed or could be done. Call before the
    first program build."""
    address = int(device.int_ptr)
    with _lock:
        if address in _replaced:
            return _replaced[address]
        target = compiler_target(device)
        if target is None or platform.system() != "Linux" or platform.machine() not in ("x86_64", "AMD64"):
            return None
        triple, cpu = target
        if not needs_replacing(cpu, _cpu_flags()):
            return None
        pointer_at, string_is = _reader(_readable_ranges())
        for offset in range(0, 4096, 8):
            here = pointer_at(address + offset)
            after = pointer_at(address + offset + 8)
            if here is None or after is None:
                break
            if string_is(here, triple.encode()) and string_is(after, cpu.encode()):
                name = target_name()
                libc = ctypes.CDLL(None)
                libc.strdup.restype = ctypes.c_void_p
                libc.strdup.argtypes = [ctypes.c_char_p]
                # strdup: PoCL owns the field and may free() it at exit.
                ctypes.c_uint64.from_address(address + offset + 8).value = libc.strdup(name.encode())
                _replaced[address] = name
                return name
        return None


def replaced_cpu(device) -> str | None:
    """The CPU name :func:`fix_cpu_name` gave ``device``, or None."""
    return _replaced.get(int(device.int_ptr))
