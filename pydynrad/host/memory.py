"""Host memory: what a new allocation can have, checked before large work starts."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["available_host_bytes"]

#: Where the cgroup (v2 first, then v1) limits of this process are read; a container sees its own.
CGROUP_ROOT = Path("/sys/fs/cgroup")
_CGROUP_FILES = (
    ("memory.max", "memory.current", "inactive_file"),
    ("memory/memory.limit_in_bytes", "memory/memory.usage_in_bytes", "total_inactive_file"),
)


def _machine_bytes() -> int:
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError):
        return 2**62


def _cgroup_bytes() -> int | None:
    """What the memory cgroup still allows: its limit less its usage, counting reclaimable
    page cache (inactive files) as free; None without a limit."""
    for limit_file, usage_file, inactive_key in _CGROUP_FILES:
        try:
            limit = (CGROUP_ROOT / limit_file).read_text().strip()
            usage = int((CGROUP_ROOT / usage_file).read_text())
        except (OSError, ValueError):
            continue
        if limit == "max":
            return None
        stat = (CGROUP_ROOT / limit_file).with_name("memory.stat")
        try:
            inactive = next(
                (int(v) for k, v in (line.split() for line in stat.read_text().splitlines()) if k == inactive_key), 0
            )
        except (OSError, ValueError):
            inactive = 0
        return max(0, int(limit) - usage + inactive)
    return None


def _address_space_bytes() -> int | None:
    """What RLIMIT_AS (``ulimit -v``) leaves above the process's current virtual size; None without one."""
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
        if soft == resource.RLIM_INFINITY:
            return None
        with open("/proc/self/status") as f:
            size = next(int(line.split()[1]) * 1024 for line in f if line.startswith("VmSize:"))
    except (ImportError, OSError, StopIteration, ValueError):
        return None
    return max(0, soft - size)


def available_host_bytes() -> int:
    """Host memory available to a new allocation: the least of the machine's (Linux
    MemAvailable, else free pages), the memory cgroup's headroom (``memory.max`` less usage)
    and the address space ``RLIMIT_AS`` leaves this process."""
    return min(b for b in (_machine_bytes(), _cgroup_bytes(), _address_space_bytes()) if b is not None)
