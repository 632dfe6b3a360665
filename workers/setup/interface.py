"""The air–water interface of the rays: where each meets the sea, and how it goes on.

Rays from the platform (laser rays, pixels' lines of sight) are intersected with the real
surface, refracted by Snell's law at the local facet and weighted by the Fresnel
transmittance (`through_surface`); in the water they are straight lines, kept as affine
functions of the depth of the plane they cross (`Projected`). The rays' arrays are of any
array API namespace (numpy, or torch on its device: `workers.backends.backend`); the arithmetic is
the same, so numpy's bytes are those of plain numpy code.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from array_api_compat import array_namespace
from array_api_compat import device as device_of

from workers.optics.fresnel import fresnel_reflectance, transmitted_cosine
from workers.sea.surface import Surface
from workers.setup.geometry import PlaneGrid

__all__ = [
    "SURFACE_ITERATIONS",
    "SURFACE_TOLERANCE",
    "Projected",
    "Transmitted",
    "ray_components",
    "surface_hit",
    "through_surface",
    "through_surface_and_resolved",
]

SURFACE_ITERATIONS = 8
"""Fixed-point steps of each ray's hit on the wavy surface (start at z = 0), at most.

Measured (`surface_hit`'s notes): the shipped configurations' seas at nadir converge in
1–3 steps, seas of 0.5–15 m/s seen from 40° off nadir in at most 6; at 60° the eighth
step still moves some hits by 1–41 mm.
"""

SURFACE_TOLERANCE = 1e-3
"""Largest height change [m] over the rays at which the surface hits have converged."""


@dataclass(frozen=True)
class Transmitted:
    """Rays after the surface: entry point, in-water slopes, Fresnel transmittance."""

    air: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    tan_x: np.ndarray
    tan_y: np.ndarray
    secant: np.ndarray
    transmittance: np.ndarray

    def on_axes(self, grid: PlaneGrid, diffuse_attenuation: float) -> Projected:
        """The rays in the horizontal axes of `grid`, ready to be crossed with any depth.

        Parameters
        ----------
        grid : PlaneGrid
            Any plane of the frame: they all share the image's axes.
        diffuse_attenuation : float
            K [1/m].

        Returns
        -------
        Projected
        """
        (u0, u1), (v0, v1) = grid.axis_u, grid.axis_v
        slope_u = self.tan_x * u0 + self.tan_y * u1
        slope_v = self.tan_x * v0 + self.tan_y * v1
        base_u = self.x * u0 + self.y * u1 + self.z * slope_u
        base_v = self.x * v0 + self.y * v1 + self.z * slope_v
        k = -diffuse_attenuation
        return Projected(
            base_u=base_u,
            slope_u=slope_u,
            base_v=base_v,
            slope_v=slope_v,
            log_extra=(k * self.z) * self.secant,
            log_extra_slope=k * (self.secant - 1.0),
        )


@dataclass(frozen=True)
class Projected:
    r"""Rays after the surface, as affine functions of the depth z of a plane [m].

    On a plane at depth z a ray that entered at height η with in-water slopes
    (tan_x, tan_y) is at ``base + z·slope`` along each of the image's horizontal axes u
    and v [m] (its entry point moved down by z + η along the slopes). The MTF of a plane
    at depth z already attenuates by exp(-Kz); the ray travels (z + η)/cos ϑ, so it is
    further attenuated by :math:`e^{-K((z + \eta)/\cos\vartheta - z)}
    = \exp(\mathrm{log\_extra} + z\,\mathrm{log\_extra\_slope})`.
    """

    base_u: np.ndarray
    slope_u: np.ndarray
    base_v: np.ndarray
    slope_v: np.ndarray
    log_extra: np.ndarray
    log_extra_slope: np.ndarray

    @property
    def lines(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(base_u, slope_u, base_v, slope_v)``, for `workers.backends.kernels`."""
        return self.base_u, self.slope_u, self.base_v, self.slope_v

    def extra(self, depth: float):
        """Attenuation of each ray's extra slant path to a plane at `depth` [1], float32."""
        extra = self.log_extra_slope * float(np.float32(depth))
        extra += self.log_extra
        return array_namespace(extra).exp(extra)


def ray_components(origins, directions):
    """Rays as six contiguous float32 components (ox, oy, oz, dx, dy, dz).

    An origin shared by every ray (a divergent beam, the pinhole) is kept as three
    float32 scalars, which broadcast.
    """
    origins = np.asarray(origins, dtype=np.float32).reshape(-1, 3)
    directions = np.asarray(directions, dtype=np.float32).reshape(-1, 3)
    if origins.shape[0] == 1 or np.all(origins == origins[0]):
        o = tuple(np.float32(v) for v in origins[0])
    else:
        o = tuple(np.ascontiguousarray(origins[:, i]) for i in range(3))
    return (*o, *(np.ascontiguousarray(directions[:, i]) for i in range(3)))


def surface_hit(rays, surface, frame):
    """Where each ray meets the surface: its parameter there and the elevation.

    Parameters
    ----------
    rays : tuple
        ``(ox, oy, oz, dx, dy, dz)``, as for `through_surface`.
    surface : Surface or None
        The sea surface (None: flat), or any object with its ``elevation_at``.
    frame : int
        Frame index into the surface.

    Returns
    -------
    travel, eta : array
        The ray's parameter t at its hit ``o + t·d`` (the rays' dtype) and the surface's
        elevation η there [m].

    Notes
    -----
    Fixed-point iteration from z = 0: ``t = (η − oz)/dz`` with η the elevation under the
    ray's previous point; it contracts by |slope · tan(view)| per step. A step moves every
    ray; the first step after which no ray's elevation changed by `SURFACE_TOLERANCE` or
    more is the last (at most `SURFACE_ITERATIONS`), so the hit is within about the
    tolerance of the exact one. A `Surface` takes its steps in one kernel
    (`Surface.hits`: numba's stops there, torch's takes them all as below); any other sea
    with an ``elevation_at`` takes all `SURFACE_ITERATIONS` steps with array operations,
    every ray held where it is once they have all converged (a flag, no read on the
    host): the values of stopping there.
    """
    ox, oy, oz, dx, dy, dz = rays
    xp = array_namespace(dz)
    if surface is None:
        travel = -oz / dz
        return travel, xp.zeros_like(travel)
    if isinstance(surface, Surface):
        return surface.hits(
            rays, frame, iterations=SURFACE_ITERATIONS, tolerance=SURFACE_TOLERANCE
        )
    travel = -oz / dz
    eta = surface.elevation_at(ox + travel * dx, oy + travel * dy, frame)
    going = xp.ones((), dtype=xp.bool, device=device_of(dz))
    for _ in range(SURFACE_ITERATIONS):
        step = (eta - oz) / dz
        height = surface.elevation_at(ox + step * dx, oy + step * dy, frame)
        converged = xp.max(xp.abs(height - eta)) < SURFACE_TOLERANCE
        travel = xp.where(going, step, travel)
        eta = xp.where(going, height, eta)
        going = going & ~converged
    return travel, eta


def through_surface(rays, surface, frame, refractive_index):
    r"""Intersect rays with the surface, refract them and get their Fresnel transmittance.

    Parameters
    ----------
    rays : tuple
        ``(ox, oy, oz, dx, dy, dz)`` from `ray_components` [m], [1]: float32 arrays of
        one backend (numpy, or torch tensors on one device), an origin shared by every
        ray as scalars.
    surface : Surface or None
        The sea surface (None: flat), its fields on the rays' backend.
    frame : int
        Frame index into the surface.
    refractive_index : float
        Refractive index of the water [1].

    Returns
    -------
    Transmitted

    Notes
    -----
    The hit is `surface_hit`'s; the slopes are sampled there.

    The interface is refracted as `workers.optics.fresnel.refract` does, specialised to
    air → water (n1 = 1 < n2, no total internal reflection), and weighted by
    `workers.optics.fresnel.fresnel_reflectance`: with the upward normal
    :math:`n = (-s_x, -s_y, 1)/\sqrt{1 + s^2}`, cos i = -ξ·n and cos t its refracted
    cosine (`workers.optics.fresnel.transmitted_cosine`), the transmitted direction is
    :math:`\xi/n_w + (\cos i/n_w - \cos t)\,n`. Rays meeting a facet that faces
    away from them (cos i <= 0), and rays the surface would send back up, transmit
    nothing.
    """
    travel, eta = surface_hit(rays, surface, frame)
    x, y = rays[0] + travel * rays[3], rays[1] + travel * rays[4]
    if surface is None:
        slopes = (eta, eta)
    else:
        slopes = surface.slopes_at(x, y, frame)
    return _refracted(rays, (travel, x, y, eta), slopes, refractive_index)


def through_surface_and_resolved(rays, surface, frame, refractive_index):
    """`through_surface` of a sea, and of its resolved part (no sub-grid slopes).

    Parameters
    ----------
    rays : tuple
        As for `through_surface`.
    surface : Surface
        The sea surface, with its sub-grid slopes.
    frame : int
        Frame index into the surface.
    refractive_index : float
        Refractive index of the water [1].

    Returns
    -------
    full, resolved : Transmitted
        Through `surface`, and through it without its ``subgrid``: the bytes of
        `through_surface` of each. They share the hits (the sub-grid slopes do not move
        the elevation) and the cascades' slopes, found once.
    """
    travel, eta = surface_hit(rays, surface, frame)
    x, y = rays[0] + travel * rays[3], rays[1] + travel * rays[4]
    slope_x, slope_y = dataclasses.replace(surface, subgrid=None).slopes_at(x, y, frame)
    more_x, more_y = surface.subgrid.at(x, y, frame)
    hit = (travel, x, y, eta)
    full = _refracted(rays, hit, (slope_x + more_x, slope_y + more_y), refractive_index)
    return full, _refracted(rays, hit, (slope_x, slope_y), refractive_index)


def _refracted(rays, hit, slopes, refractive_index):
    """The rays refracted at their hits ``(travel, x, y, eta)`` on facets of `slopes`."""
    dx, dy, dz = rays[3:]
    travel, x, y, eta = hit
    sx, sy = slopes
    xp = array_namespace(dx)
    ratio = 1.0 / refractive_index
    inverse_norm = 1.0 / xp.sqrt(1.0 + sx * sx + sy * sy)
    cos_incidence = (dx * sx + dy * sy - dz) * inverse_norm
    cos_i = xp.clip(cos_incidence, 0.0, 1.0)
    cos_t = transmitted_cosine(cos_i, n1=1.0, n2=refractive_index)
    coefficient = (ratio * cos_i - cos_t) * inverse_norm
    down = -(ratio * dz + coefficient)
    facing = (cos_incidence > 0) & (down > 0)
    secant = 1.0 / xp.where(facing, down, 1.0)  # 1 where not facing
    transmittance = 1.0 - fresnel_reflectance(cos_i, n1=1.0, n2=refractive_index)

    def single(values):
        return xp.astype(values, xp.float32, copy=False)

    return Transmitted(
        air=single(travel),
        x=single(x),
        y=single(y),
        z=single(eta),
        tan_x=single(xp.where(facing, (ratio * dx - coefficient * sx) * secant, 0.0)),
        tan_y=single(xp.where(facing, (ratio * dy - coefficient * sy) * secant, 0.0)),
        secant=single(secant),
        transmittance=single(xp.where(facing, transmittance, 0.0)),
    )
