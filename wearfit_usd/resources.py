"""Memory checks before large allocations: a clear error instead of the
kernel's OOM killer or numpy's "Unable to allocate"."""
from __future__ import annotations

import os

from .errors import WearfitError


class ResourceError(WearfitError):
    """The job needs more memory than the machine has available (exit code 1)."""


def available_memory() -> int | None:
    """Bytes of memory available to new allocations (Linux ``MemAvailable``),
    or None when unknown."""
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def require_memory(nbytes: float, what: str) -> None:
    """Raise :class:`ResourceError` when ``nbytes`` exceed the available memory."""
    avail = available_memory()
    if avail is not None and nbytes > avail:
        raise ResourceError(f"{what} needs about {nbytes / 2**30:.1f} GiB of memory but only "
                            f"{avail / 2**30:.1f} GiB are available")
