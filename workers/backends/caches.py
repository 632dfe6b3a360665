"""A least-recently-used cache bounded by the bytes of the arrays its results hold.

`functools.lru_cache` bounds the number of results; the renderer's per-frame geometry
ranges from a few MB (128 pixels) to about 90 MB (512 pixels) a frame, and a sequence of
26 frames needs all of its frames kept or every sample rebuilds them all. So the bound
here is on bytes.
"""

from __future__ import annotations

import dataclasses
import functools
import sys
import threading
from collections import OrderedDict
from typing import NamedTuple

import numpy as np

__all__ = ["clear_all", "held_bytes", "lru_bytes"]


class CacheInfo(NamedTuple):
    """What a `lru_bytes` cache holds: hits, misses, results held and their bytes."""

    hits: int
    misses: int
    currsize: int
    nbytes: int


def held_bytes(value, _seen: set | None = None) -> int:
    """Bytes of the numpy arrays `value` holds, through containers and object attributes.

    Each array (and each base an array views) is counted once; what is not an array,
    a container, a dataclass or an object with attributes counts nothing.
    """
    seen = set() if _seen is None else _seen
    if id(value) in seen or value is None or isinstance(value, (str, bytes, int, float)):
        return 0
    seen.add(id(value))
    if isinstance(value, np.ndarray):
        base = value
        while isinstance(base.base, np.ndarray):
            base = base.base
        if base is not value:
            return held_bytes(base, seen)
        return value.nbytes
    if isinstance(value, dict):
        children = list(value.values())
    elif isinstance(value, (list, tuple, set, frozenset)):
        children = list(value)
    elif dataclasses.is_dataclass(value):
        children = [getattr(value, f.name) for f in dataclasses.fields(value)]
    elif hasattr(value, "__dict__"):
        children = list(vars(value).values())
    else:
        return 0
    return sum(held_bytes(child, seen) for child in children)


def lru_bytes(limit: int):
    """Cache a function's results by its (hashable) arguments, up to `limit` bytes.

    When the arrays the results hold (`held_bytes`) pass `limit`, the least recently used
    results are dropped; the newest is always kept. The wrapped function has
    ``cache_clear()`` and ``cache_info()`` as `functools.lru_cache`'s have. Safe to call
    from several threads (two may build the same result at once; one is kept).

    Parameters
    ----------
    limit : int
        Most bytes of arrays held [bytes].
    """

    def decorate(function):
        results: OrderedDict = OrderedDict()  # key -> (result, bytes)
        lock = threading.Lock()
        counts = {"hits": 0, "misses": 0}

        @functools.wraps(function)
        def cached(*args, **kwargs):
            key = (args, tuple(sorted(kwargs.items())))
            with lock:
                if key in results:
                    counts["hits"] += 1
                    results.move_to_end(key)
                    return results[key][0]
                counts["misses"] += 1
            result = function(*args, **kwargs)
            size = held_bytes(result)
            with lock:
                results[key] = (result, size)
                results.move_to_end(key)
                while len(results) > 1 and sum(s for _, s in results.values()) > limit:
                    results.popitem(last=False)
            return result

        def cache_clear() -> None:
            with lock:
                results.clear()
                counts.update(hits=0, misses=0)

        def cache_info() -> CacheInfo:
            with lock:
                held = sum(size for _, size in results.values())
                return CacheInfo(counts["hits"], counts["misses"], len(results), held)

        cached.cache_clear, cached.cache_info = cache_clear, cache_info
        return cached

    return decorate


def clear_all() -> None:
    """Empty every cache of the renderer: the next render sets its scene up from scratch.

    Every function of a loaded ``workers.*`` module that has ``cache_clear``
    (`functools.lru_cache`, `functools.cache`, `lru_bytes`). numba's compiled kernels are
    no such cache: they stay compiled.
    """
    for module in list(sys.modules.values()):
        if getattr(module, "__name__", "").startswith("workers."):
            for value in list(vars(module).values()):
                if callable(getattr(value, "cache_clear", None)):
                    value.cache_clear()
