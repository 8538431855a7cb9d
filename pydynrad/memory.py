"""Host memory: what a new allocation can have, checked before large work starts."""

from __future__ import annotations

import os

__all__ = ["available_host_bytes"]


def available_host_bytes() -> int:
    """Host memory available to a new allocation (Linux MemAvailable, else free pages)."""
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
