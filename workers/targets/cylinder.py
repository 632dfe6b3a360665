r"""The horizontal cylinder (a moored or bottom mine): closed, Lambertian, any heading.

Its axis is horizontal at the target's depth, along the compass heading h (degrees
clockwise from north: 0 points the axis north-south, 90 east-west), unit vector
â = (sin h, cos h, 0) in (east, north, up); `radius` r, `length` L, flat end caps. The
fast renderer's maps are traced from the same compiled ray hits
(`workers.targets.base.SampledShape`): over a cell (u across the axis, v along it) at
nadir the line meets the side where |v| ≤ L/2 and |u| < r, at depth
:math:`z_c - \sqrt{r^2-u^2}`, with outward normal :math:`(u\,\hat u - \sqrt{r^2-u^2}\,\hat z)/r`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from workers.targets.base import EPS, SampledShape, compiled, register

__all__ = ["Cylinder", "CylinderRecord"]


class CylinderRecord(NamedTuple):
    """The kernels' cylinder: centre, radius, half-length [m]; axis (ax, ay), reflectance [1]."""

    cx: float
    cy: float
    cz: float
    radius: float
    half_length: float
    ax: float
    ay: float
    reflectance: float


@numba.njit(cache=True)
def _frame(x, y, z, target):
    """A point's axial coordinate, and its offset from the axis (ox, oy, oz) [m]."""
    ox, oy, oz = x - target.cx, y - target.cy, z - target.cz
    axial = ox * target.ax + oy * target.ay
    return axial, ox - axial * target.ax, oy - axial * target.ay, oz


@numba.njit(cache=True)
def _inside(axial, ox, oy, oz, target):
    """Whether a point (in `_frame`'s coordinates) lies within the closed cylinder."""
    return abs(axial) <= target.half_length and ox * ox + oy * oy + oz * oz <= (
        target.radius * target.radius
    )


@numba.njit(cache=True)
def _distance(px, py, pz, dx, dy, dz, target):
    """`workers.targets.base.target_distance` for a closed cylinder: side or cap entry."""
    axial, ox, oy, oz = _frame(px, py, pz, target)
    if _inside(axial, ox, oy, oz, target):
        return np.inf
    along = dx * target.ax + dy * target.ay
    qx, qy, qz = dx - along * target.ax, dy - along * target.ay, dz
    a = qx * qx + qy * qy + qz * qz
    b = ox * qx + oy * qy + oz * qz
    c = ox * ox + oy * oy + oz * oz - target.radius * target.radius
    best = np.inf
    if a > 0.0 and c > 0.0 and b < 0.0:
        disc = b * b - a * c
        if disc > 0.0:
            t = (-b - math.sqrt(disc)) / a
            if t > EPS and abs(axial + t * along) <= target.half_length:
                best = t
    if along != 0.0:
        for end in (-target.half_length, target.half_length):
            t = (end - axial) / along
            if EPS < t < best:
                rx, ry, rz = ox + t * qx, oy + t * qy, oz + t * qz
                if rx * rx + ry * ry + rz * rz <= target.radius * target.radius:
                    best = t
    return best


@numba.njit(cache=True)
def _blocks(x, y, z, ux, uy, uz, length, target):
    """`workers.targets.base.target_blocks` for a cylinder (from inside: heading inwards)."""
    axial, ox, oy, oz = _frame(x, y, z, target)
    if _inside(axial, ox, oy, oz, target):
        along = ux * target.ax + uy * target.ay
        return ox * (ux - along * target.ax) + oy * (uy - along * target.ay) + oz * uz < 0.0
    return _distance(x, y, z, ux, uy, uz, target) < length


@numba.njit(cache=True)
def _normal(x, y, z, dx, dy, dz, target):
    """`workers.targets.base.target_normal` for a cylinder: radial, or along the axis on a cap."""
    axial, ox, oy, oz = _frame(x, y, z, target)
    spoke = math.sqrt(ox * ox + oy * oy + oz * oz)
    if abs(abs(axial) - target.half_length) < abs(spoke - target.radius) or spoke == 0.0:
        sign = 1.0 if axial > 0.0 else -1.0
        return sign * target.ax, sign * target.ay, 0.0
    return ox / spoke, oy / spoke, oz / spoke


compiled(CylinderRecord, distance=_distance, blocks=_blocks, normal=_normal)


@register
class Cylinder(SampledShape):
    """A horizontal closed cylinder: `radius`, `length`, axis at `depth` along `heading_deg`."""

    name = "cylinder"
    fields = ("length", "heading_deg")

    def check(self, target) -> None:
        """The cylinder must be submerged: depth (of its axis) > radius."""
        if target.depth <= target.radius:
            raise ValueError(
                f"a cylinder of radius {target.radius} m with its axis at depth {target.depth} "
                "m breaks the surface; depth must exceed radius"
            )

    def half_height(self, target) -> float:
        """The radius [m]."""
        return float(target.radius)

    def reach(self, target) -> float:
        """Half the diagonal of its plan, √((L/2)² + r²) [m]."""
        return math.hypot(0.5 * target.length, target.radius)

    def record(self, target, centre) -> CylinderRecord:
        """The kernels' cylinder at `centre`, its axis at −depth along the heading."""
        heading = math.radians(target.heading_deg)
        return CylinderRecord(
            float(centre[0]),
            float(centre[1]),
            -float(target.depth),
            float(target.radius),
            0.5 * float(target.length),
            math.sin(heading),
            math.cos(heading),
            float(target.reflectance),
        )
