"""Process tuning for rendering: keep glibc from returning memory to the OS per array.

A sample allocates many temporaries of a few hundred kilobytes. Above glibc's mmap
threshold each one is a fresh mapping whose pages fault in one by one (about 2.5 µs a page
on the machines measured), which costs a quarter of the render time. Raising the mmap and
trim thresholds keeps those blocks on the heap and reuses them. Elsewhere than glibc this
does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools

__all__ = ["ALLOCATOR_ENVIRONMENT", "tune_allocator"]

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 32 * 2**20
"""glibc's largest allowed mmap threshold on 64-bit systems [bytes]."""
TRIM_THRESHOLD = 256 * 2**20

ALLOCATOR_ENVIRONMENT = {
    "MALLOC_MMAP_THRESHOLD_": str(MMAP_THRESHOLD),
    "MALLOC_TRIM_THRESHOLD_": str(TRIM_THRESHOLD),
}
"""The same settings as environment variables, for processes started by dask's nanny."""


@functools.cache
def tune_allocator() -> bool:
    """Raise glibc's mmap and trim thresholds in this process (once).

    Returns
    -------
    bool
        Whether the allocator accepted the settings (False off glibc).
    """
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(
        mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD)
    )
