"""The flat horizontal disk (a panel): its maps and its ray hits."""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

from workers.targets.base import EPS, TargetShape, compiled, register
from workers.targets.impostor import Impostor, disc_cover, offsets

__all__ = ["Disk", "DiskRecord"]


class DiskRecord(NamedTuple):
    """The Monte Carlo kernels' disk: centre [m] (cz its plane), radius [m], reflectance [1]."""

    cx: float
    cy: float
    cz: float
    radius: float
    reflectance: float


@numba.njit(cache=True)
def _distance(px, py, pz, dx, dy, dz, target):
    """`workers.targets.base.target_distance` for a horizontal disk (either face)."""
    if dz != 0.0:
        t = (target.cz - pz) / dz
        if t > EPS:
            hx, hy = px + t * dx - target.cx, py + t * dy - target.cy
            if hx * hx + hy * hy <= target.radius * target.radius:
                return t
    return np.inf


@numba.njit(cache=True)
def _blocks(x, y, z, ux, uy, uz, length, target):
    """`workers.targets.base.target_blocks` for a horizontal disk, on the way up."""
    if uz > 0.0:
        t = (target.cz - z) / uz
        if EPS < t < length:
            hx, hy = x + t * ux - target.cx, y + t * uy - target.cy
            return hx * hx + hy * hy <= target.radius * target.radius
    return False


@numba.njit(cache=True)
def _normal(x, y, z, dx, dy, dz, target):
    """`workers.targets.base.target_normal` for a disk: the face the photon met."""
    return 0.0, 0.0, (1.0 if dz < 0.0 else -1.0)


compiled(DiskRecord, distance=_distance, blocks=_blocks, normal=_normal)


@register
class Disk(TargetShape):
    """A flat horizontal Lambertian disk of `radius` at `depth`."""

    name = "disk"

    def record(self, target, centre) -> DiskRecord:
        """The kernels' disk at `centre`, its plane at −depth."""
        return DiskRecord(
            float(centre[0]),
            float(centre[1]),
            -float(target.depth),
            float(target.radius),
            float(target.reflectance),
        )

    def impostor(self, *, grid, target, centre, refracted_nadir) -> Impostor:
        """The disk's maps on its own plane: its exact cover, ρ × cover, its depth."""
        du, along = offsets(grid, centre)
        occupancy, _ = disc_cover(
            u=du, w=along, cell_u=grid.spacing_u, cell_w=grid.spacing_v, radius=target.radius
        )
        weight = target.reflectance * occupancy
        depth = np.full_like(occupancy, grid.depth)
        return Impostor(
            occupancy=occupancy.astype(np.float32),
            weight=weight.astype(np.float32),
            surface_depth=depth.astype(np.float32),
            top=grid.depth,
            bottom=grid.depth,
        )

    def meets(self, target, centre, lines) -> np.ndarray:
        """Lines crossing the disk's plane, ahead of their start, within its radius."""
        x, y, z, dx, dy, dz = lines[:6]
        t = (-target.depth - z) / dz
        gap = (x + t * dx - centre[0]) ** 2 + (y + t * dy - centre[1]) ** 2
        return (t > 0) & (gap <= target.radius**2)
