"""No target (``shape: none``): the record the Monte Carlo kernels carry in its place."""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

from workers.targets.base import TargetShape, compiled, register

__all__ = ["Absent", "AbsentRecord"]


class AbsentRecord(NamedTuple):
    """The kernels' absent target: nothing to meet, nothing reflected."""

    reflectance: float


@numba.njit(cache=True)
def _distance(px, py, pz, dx, dy, dz, target):
    """Never met."""
    return np.inf


@numba.njit(cache=True)
def _blocks(x, y, z, ux, uy, uz, length, target):
    """Never in the way."""
    return False


@numba.njit(cache=True)
def _normal(x, y, z, dx, dy, dz, target):
    """Never asked (no hit); up."""
    return 0.0, 0.0, 1.0


compiled(AbsentRecord, distance=_distance, blocks=_blocks, normal=_normal)


@register
class Absent(TargetShape):
    """The scene's target-free twin (`workers.settings.scene.Scene.without_target`)."""

    name = "none"
    shadings = ("lambert", "paper")

    def half_height(self, target) -> float:
        """No extent."""
        return 0.0

    def reach(self, target) -> float:
        """No extent."""
        return 0.0

    def record(self, target, centre) -> AbsentRecord:
        """The kernels' absent target."""
        return AbsentRecord(0.0)

    def meets(self, target, centre, lines) -> np.ndarray:
        """No line."""
        return np.zeros(np.shape(lines[0]), dtype=bool)
