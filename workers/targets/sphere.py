"""The sphere (a moored mine): closed-form maps, its gated annuli, and its ray hits."""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from workers.targets.base import EPS, TargetShape, compiled, register
from workers.targets.impostor import (
    Impostor,
    disc_cover,
    gated_share,
    offsets,
    sphere_area_weights,
)

__all__ = ["Sphere", "SphereRecord"]


class SphereRecord(NamedTuple):
    """The Monte Carlo kernels' sphere: centre [m], radius [m], reflectance [1]."""

    cx: float
    cy: float
    cz: float
    radius: float
    reflectance: float


@numba.njit(cache=True)
def _distance(px, py, pz, dx, dy, dz, target):
    """`workers.targets.base.target_distance` for a sphere."""
    ox, oy, oz = px - target.cx, py - target.cy, pz - target.cz
    b = ox * dx + oy * dy + oz * dz
    c = ox * ox + oy * oy + oz * oz - target.radius * target.radius
    if c <= 0.0 or b >= 0.0:
        return np.inf
    disc = b * b - c
    if disc <= 0.0:
        return np.inf
    t = -b - math.sqrt(disc)
    return t if t > EPS else np.inf


@numba.njit(cache=True)
def _blocks(x, y, z, ux, uy, uz, length, target):
    """`workers.targets.base.target_blocks` for a sphere (from inside: heading inwards)."""
    ox, oy, oz = x - target.cx, y - target.cy, z - target.cz
    b = ox * ux + oy * uy + oz * uz
    c = ox * ox + oy * oy + oz * oz - target.radius * target.radius
    if c <= 0.0:
        return b < 0.0
    disc = b * b - c
    if disc <= 0.0 or b >= 0.0:
        return False
    t = -b - math.sqrt(disc)
    return EPS < t < length


@numba.njit(cache=True)
def _normal(x, y, z, dx, dy, dz, target):
    """`workers.targets.base.target_normal` for a sphere: radial."""
    return (
        (x - target.cx) / target.radius,
        (y - target.cy) / target.radius,
        (z - target.cz) / target.radius,
    )


compiled(SphereRecord, distance=_distance, blocks=_blocks, normal=_normal)


@register
class Sphere(TargetShape):
    """A sphere of `radius` centred at `depth` (Lambertian, or the paper's `ponder` shading)."""

    name = "sphere"
    shadings = ("lambert", "paper")

    def check(self, target) -> None:
        """The sphere must be submerged: depth > radius."""
        if target.depth <= target.radius:
            raise ValueError(
                f"a sphere of radius {target.radius} m at depth {target.depth} m breaks the "
                "surface; depth must exceed radius"
            )

    def half_height(self, target) -> float:
        """The radius [m]."""
        return float(target.radius)

    def record(self, target, centre) -> SphereRecord:
        """The kernels' sphere at `centre`, its centre at −depth."""
        return SphereRecord(
            float(centre[0]),
            float(centre[1]),
            -float(target.depth),
            float(target.radius),
            float(target.reflectance),
        )

    def impostor(self, *, grid, target, centre, refracted_nadir) -> Impostor:
        r"""The sphere's maps on the plane through its centre.

        Notes
        -----
        A cell's line meets the sphere where the perpendicular distance
        :math:`\rho_\perp` from the centre is below r. Light crossing the plane with
        horizontal irradiance E over a cell arrives on the sphere at incidence
        :math:`\cos i = \sqrt{1-\rho_\perp^2/r^2}`, so a Lambertian sphere sends back radiance
        :math:`\rho E \cos i / (\pi \cos\vartheta_t)` (`lambert`). The paper instead weights
        each cell by its hemisphere area (`ponder`) per unit plane area, which brightens the
        limb (`paper`). Both treat the laser and the receiver as sharing the mean in-water
        direction, which holds for a common boresight up to the wave slopes.
        """
        radius, reflectance = target.radius, target.reflectance
        du, along = offsets(grid, centre)
        cos_t, sin_t = np.cos(refracted_nadir), np.sin(refracted_nadir)
        across = along * cos_t
        rho = np.hypot(du, across)
        occupancy, cosine = disc_cover(
            u=du, w=across, cell_u=grid.spacing_u, cell_w=grid.spacing_v * cos_t, radius=radius
        )
        chord = np.sqrt(np.clip(radius**2 - rho**2, 0.0, None))
        # entry point along the line x = c + δ + t ŝ, ŝ = (sinϑ away, -cosϑ down)
        entry = -along * sin_t - chord
        surface_depth = grid.depth + entry * cos_t
        if target.shading == "lambert":
            weight = reflectance * cosine / cos_t
        else:
            area = sphere_area_weights(
                u=du,
                w=across,
                cell_u=grid.spacing_u,
                cell_w=grid.spacing_v * cos_t,
                radius=radius,
            )
            weight = reflectance * area / (grid.spacing_u * grid.spacing_v)
        return Impostor(
            occupancy=occupancy.astype(np.float32),
            weight=weight.astype(np.float32),
            surface_depth=np.where(occupancy > 0, surface_depth, grid.depth).astype(np.float32),
            top=grid.depth - radius,
            bottom=grid.depth + radius,
        )

    def gated_share(
        self, *, grid, target, centre, refracted_nadir, top, bottom, on, delays, shares
    ) -> np.ndarray | None:
        """The gated annuli in closed form (`workers.targets.impostor.gated_share`).

        None under the paper's shading, whose cells count whole by their line's depth.
        """
        if target.shading != "lambert":
            return None
        return gated_share(
            grid=grid,
            centre=centre,
            radius=target.radius,
            refracted_nadir=refracted_nadir,
            top=top,
            bottom=bottom,
            on=on,
            delays=delays,
            shares=shares,
        )

    def meets(self, target, centre, lines) -> np.ndarray:
        """Lines passing within the radius of the centre, ahead of their start."""
        x, y, z, dx, dy, dz = lines[:6]
        ox, oy, oz = x - centre[0], y - centre[1], z + target.depth
        b = ox * dx + oy * dy + oz * dz
        c = ox * ox + oy * oy + oz * oz - target.radius**2
        return (b * b - c > 0.0) & (b < 0.0)
