"""Compiled kernels kept true to their sources on disk: `refresh_stale`.

numba caches a compiled kernel (``cache=True``) under a key of its own file's time stamp
and size alone. A kernel that inlines functions from other files (the Monte Carlo's
`workers.montecarlo.photons.transport` inlines the scattering draws, Fresnel's scalar and
every target shape's hit and normal) would keep running the old code of those files after
they change, until its own file changes: an edit, a ``git pull`` into an editable install or
a restored mutation then renders with the previous physics, silently. `refresh_stale`
keeps, beside each such kernel's cache, the digest of every source it inlines, and flushes
the kernel's cache when the digest differs, so that it is compiled again.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

__all__ = ["refresh_stale", "sources_digest"]


def sources_digest(sources) -> str:
    """SHA-256 of the named source files' paths and bytes, in sorted order (hex)."""
    digest = hashlib.sha256()
    for path in sorted(Path(source).resolve() for source in sources):
        digest.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def refresh_stale(dispatchers, *, sources) -> list[str]:
    """Flush the on-disk caches of `dispatchers` whose inlined `sources` changed.

    Parameters
    ----------
    dispatchers : iterable of numba dispatchers
        Kernels compiled with ``cache=True`` (others, e.g. under ``NUMBA_DISABLE_JIT``,
        are skipped).
    sources : iterable of path-like
        Every source file the kernels' compiled code depends on.

    Returns
    -------
    list of str
        The qualified names of the kernels whose cache was flushed.

    Notes
    -----
    The digest is kept in a file beside each kernel's cache index
    (``<module>.<name>.sources``). Flushing empties the index: the next call compiles the
    kernel again and caches it anew. A cache directory that cannot be written keeps numba's
    own behaviour (numba then caches elsewhere or not at all).
    """
    digest = sources_digest(sources)
    flushed = []
    for dispatcher in dispatchers:
        cache = getattr(dispatcher, "_cache", None)
        if cache is None or not hasattr(cache, "flush"):
            continue
        function = dispatcher.py_func
        name = f"{function.__module__}.{function.__qualname__}"
        stamp = Path(cache._cache_path) / f"{name}.sources"
        try:
            if stamp.read_text() == digest:
                continue
        except OSError:
            pass
        try:
            cache.flush()
            stamp.parent.mkdir(parents=True, exist_ok=True)
            stamp.write_text(digest)
        except OSError:  # a cache numba cannot write either: its own behaviour stands
            continue
        flushed.append(name)
    return flushed
