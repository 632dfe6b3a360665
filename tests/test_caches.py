"""The byte-bounded cache of the renderer's per-frame geometry."""

import dataclasses

import numpy as np

from workers.backends.caches import held_bytes, lru_bytes
from workers.fast import planes
from workers.render import render
from workers.settings.scene import Scene


def test_held_bytes_counts_each_array_once_through_containers():
    @dataclasses.dataclass
    class Holder:
        grid: np.ndarray
        parts: tuple

    base = np.zeros(100)  # 800 bytes
    holder = Holder(grid=base, parts=(base[:10], {"again": base}, np.ones(5, np.float32), "x"))
    assert held_bytes(holder) == 800 + 20


def test_results_are_dropped_least_recently_used_past_the_byte_limit():
    calls = []

    @lru_bytes(2000)
    def build(n):
        calls.append(n)
        return np.zeros(n)  # 8 n bytes

    build(100), build(100), build(150)  # 800 + 1200 bytes: both kept
    assert calls == [100, 150] and build.cache_info().nbytes == 2000
    build(100)  # used last: 150 is the one to go
    build(50)  # 2400 bytes: the least recently used goes
    assert build.cache_info().currsize == 2
    build(100)
    assert calls == [100, 150, 50]
    build(1000)  # alone over the limit: still kept, alone
    assert build.cache_info().currsize == 1 and build(1000) is build(1000)
    build.cache_clear()
    assert build.cache_info() == (0, 0, 0, 0)


def test_every_frame_of_a_long_sequence_stays_cached():
    # A lru_cache of 16 results cycled through the 20 frames, rebuilding every frame of
    # every sample (the paper's 26-frame example 1 rendered 20 times slower).
    scene = Scene.model_validate(
        {
            "surface": {"grid_size": 32, "spacing": 0.1, "allow_repeat": True},
            "receiver": {"pixels": 8, "gates": [[2.0, 6.0]]},
            "sequence": {"frames": 20, "interval": 0.05},
        }
    )
    planes.frame_geometry.cache_clear()
    render(scene, seed=1)
    built = planes.frame_geometry.cache_info().misses
    render(scene, seed=2)
    # the sample's frames (its target-free twin is gathered in the same pass)
    assert planes.frame_geometry.cache_info().misses == built == 20
