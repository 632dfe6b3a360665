"""Compiled photon transport (numba): the Monte Carlo renderer's loops.

One photon at a time, in sequence, from its entry through the sea surface: free paths
drawn on the scattering coefficient with the absorption carried as a weight, scattering
angles from a tabulated phase function (`workers.optics.phases.base.PhaseTable`), reflection off
the target's 3-D Lambertian surface, reflection and escape at the surface from below, a
cut on time of flight, Russian roulette. At every scattering event and every target
reflection a local (next-event) estimate goes to the pixels that see the point through
the rough surface (`_estimate`), in every gate whose window holds the path's total
optical length. Each photon draws from its own counter-keyed stream
(`workers.montecarlo.scattering.photon_state`), so its path depends on its index and the key alone,
not on the order of the loop: the loops carry no state between photons but the tallies, as
a GPU kernel with one photon a thread would. The model is in ``docs/model.md`` §9.

Array conventions: world metres, z up (mean sea level z = 0, the water below); optical
paths in metres (n times the water path); weights in the renderer's raw power units.
"""

from __future__ import annotations

import math
from pathlib import Path

import numba
import numpy as np

from workers.backends.compiled import refresh_stale
from workers.montecarlo.records import LEAF
from workers.montecarlo.scattering import (
    angle_between,
    mixture_weight,
    phase_value,
    photon_state,
    reflection_weight,
    scattering_angle,
    toward_receiver,
    turn,
    uniform,
)
from workers.montecarlo.sightlines import corner_at
from workers.optics.fresnel import fresnel_unpolarised
from workers.targets.base import EPS, target_blocks, target_distance, target_normal

__all__ = ["TALLIES", "transport"]

TALLIES = ("transmitted", "absorbed", "escaped", "target", "cut")
"""The energy tallies of `transport`, in order: transmitted = the sum of the others."""

_ROULETTE_WEIGHT = 1e-6  # roulette below this share of the launch weight (time cuts most)
_ROULETTE_SURVIVAL = 0.1  # probability of surviving the roulette
_BISECTIONS = 30  # steps locating a photon's crossing of the surface from below
_TRANSMITTED, _ABSORBED, _ESCAPED, _TARGET, _CUT = (TALLIES.index(t) for t in TALLIES)


@numba.njit(**LEAF)
def _elevation(x, y, sea):
    """Elevation η and slopes of the stored sea grid at (x, y) (flat outside it) [m], [1].

    `sea` is a `workers.montecarlo.records.Sea`.
    """
    size = sea.size
    if size == 0:
        return 0.0, 0.0, 0.0
    fx = (x - sea.x0) / sea.spacing
    fy = (y - sea.y0) / sea.spacing
    if fx < 0.0 or fy < 0.0 or fx >= size - 1 or fy >= size - 1:
        return 0.0, 0.0, 0.0
    i, j = int(fx), int(fy)
    tx, ty = fx - i, fy - j
    surface = sea.elevation
    e00, e01 = surface[j, i], surface[j, i + 1]
    e10, e11 = surface[j + 1, i], surface[j + 1, i + 1]
    eta = (e00 * (1 - tx) + e01 * tx) * (1 - ty) + (e10 * (1 - tx) + e11 * tx) * ty
    sx = ((e01 - e00) * (1 - ty) + (e11 - e10) * ty) / sea.spacing
    sy = ((e10 - e00) * (1 - tx) + (e11 - e01) * tx) / sea.spacing
    return eta, sx, sy


@numba.njit(**LEAF)
def _estimate(
    x,
    y,
    z,
    vx,
    vy,
    vz,
    value,
    lambertian,
    path,
    scenery,
    target,
    image,
    state,
):
    r"""Add a point's local estimate to every pixel and gate that sees it (raw units).

    A point scattering (`lambertian` False: `value` = the photon's weight, v its
    direction) or reflecting (True: `value` = weight × ρ, v the surface's normal) sends
    the pixel whose lines of sight hold it the power into the aperture's solid angle. The
    lines (`scenery.lines`) run through the corners of S × S cells of each pixel
    (`scenery.lookup.subdivision` = S), each cell split into two triangles; a triangle of
    solid angle Ω_p/(2S²) and cross-section A⊥ at the point gives, by étendue, the solid angle
    :math:`A_R\Omega_p/(2S^2 n^2 A_\perp)` of the aperture seen from the point through
    the surface, so in raw units (`workers.receiver.radiometry`) the pixel gets `value` × phase
    (or cos/π) × T e^(−c L_up) × π / (2 S² A⊥). A point inside several triangles (a fold
    of the lines under a focusing wave) counts in each.

    The lines follow the resolved sea; the slopes below its grid (`Medium.blur_xx`...:
    their covariance's square root F, and `Medium.blur_reach` = 1 − 1/n) tilt a line's
    way in the water by about −(1 − 1/n)s, so the point is looked up displaced by
    (1 − 1/n) d F ζ, d its depth and ζ two standard normals drawn here: the unresolved
    facets' refraction on the way up, as a random blur.
    """
    medium, lines, lookup, gates = scenery.medium, scenery.lines, scenery.lookup, scenery.gates
    n_w, c = medium.refractive_index, medium.attenuation
    px, py = x, y  # the point itself, for the target's shadow on the way up
    if medium.blur_reach > 0.0:
        radius = math.sqrt(-2.0 * math.log(uniform(state)))
        angle = 2.0 * math.pi * uniform(state)
        zx, zy = radius * math.cos(angle), radius * math.sin(angle)
        reach = medium.blur_reach * max(-z, 0.0)
        x = x + reach * (medium.blur_xx * zx + medium.blur_xy * zy)
        y = y + reach * (medium.blur_yx * zx + medium.blur_yy * zy)
    s = math.floor((lookup.top - z) / lookup.thick)
    if s < 0 or s >= lookup.slabs:
        return
    buckets = lookup.buckets
    size, nbx, nby = buckets.size[s], buckets.across_x[s], buckets.across_y[s]
    bi = math.floor((x - buckets.x0[s]) / size)
    bj = math.floor((y - buckets.y0[s]) / size)
    if bi < 0 or bj < 0 or bi >= nbx or bj >= nby:
        return
    starts, items = lookup.starts, lookup.items
    bucket = buckets.first[s] + bj * nbx + bi
    sub = lookup.subdivision
    lattice = image.shape[1] * sub
    side = lattice + 1
    scale = math.pi / (2.0 * sub * sub)
    for q in range(int(starts[bucket]), int(starts[bucket + 1])):
        quad = int(items[q])
        row, col = quad // lattice, quad % lattice
        k00 = row * side + col
        k01, k10 = k00 + 1, k00 + side
        k11 = k10 + 1
        x00, y00, t00 = corner_at(k00, z, lines)
        x01, y01, t01 = corner_at(k01, z, lines)
        x10, y10, t10 = corner_at(k10, z, lines)
        x11, y11, t11 = corner_at(k11, z, lines)
        for half in range(2):
            ka, ax, ay, ta = k00, x00, y00, t00
            if half == 0:
                kb, bx, by, tb, kc, cx, cy, tc = k01, x01, y01, t01, k11, x11, y11, t11
            else:
                kb, bx, by, tb, kc, cx, cy, tc = k11, x11, y11, t11, k10, x10, y10, t10
            area2 = (bx - ax) * (cy - ay) - (cx - ax) * (by - ay)
            if area2 == 0.0:
                continue
            la = ((bx - x) * (cy - y) - (cx - x) * (by - y)) / area2
            lb = ((cx - x) * (ay - y) - (ax - x) * (cy - y)) / area2
            lc = 1.0 - la - lb
            if la < 0.0 or lb < 0.0 or lc < 0.0:
                continue
            length = la * ta + lb * tb + lc * tc
            if length < 0.0:
                continue
            air = la * lines.air[ka] + lb * lines.air[kb] + lc * lines.air[kc]
            total = path + n_w * length + air
            inside = False
            for g in range(gates.opens.size):
                if gates.opens[g] <= total < gates.closes[g]:
                    inside = True
            if not inside:
                continue
            dx = la * lines.dx[ka] + lb * lines.dx[kb] + lc * lines.dx[kc]
            dy = la * lines.dy[ka] + lb * lines.dy[kb] + lc * lines.dy[kc]
            dz = la * lines.dz[ka] + lb * lines.dz[kb] + lc * lines.dz[kc]
            norm = math.sqrt(dx * dx + dy * dy + dz * dz)
            ux, uy, uz = -dx / norm, -dy / norm, -dz / norm
            if lambertian:
                weight = value * (vx * ux + vy * uy + vz * uz) / math.pi
                if weight <= 0.0:
                    continue
            else:
                cos_t, sin_t = angle_between(vx, vy, vz, ux, uy, uz)
                weight = value * phase_value(cos_t, sin_t, scenery.phase)
            if target_blocks(px, py, z, ux, uy, uz, length, target):
                continue
            exit_t = la * lines.weight[ka] + lb * lines.weight[kb] + lc * lines.weight[kc]
            across = 0.5 * abs(area2) * uz
            contribution = weight * exit_t * math.exp(-c * length) * scale / across
            for g in range(gates.opens.size):
                if gates.opens[g] <= total < gates.closes[g]:
                    image[g, row // sub, col // sub] += contribution


@numba.njit(cache=True, nogil=True)
def transport(launch, key, first_index, scenery, target, image, tallies):
    """Carry a batch of photons through the water, adding their estimates to `image`.

    Parameters
    ----------
    launch : Rays
        Each photon after the surface (`workers.montecarlo.records.Rays`): entry point
        [m], unit direction in the water, air path [m], weight (raw power after the
        Fresnel transmittance).
    key : uint64
        The frame's photon key; photon i draws from ``photon_state(key, first_index + i)``.
    first_index : int
        Index of the batch's first photon in the frame.
    scenery : Scenery
        The frame's water, phase function, limits, pinhole, sea, lines of sight, their
        lookup and gates (`workers.montecarlo.records.Scenery`).
    target : NamedTuple
        The target's record (`workers.targets.base.TargetShape.record`): the kernel
        specialises on its type, each shape's ray hit and normal compiled in.
    image : ndarray, shape (G, P, P)
        Raw signal, float64, added to.
    tallies : ndarray, shape (5,)
        `TALLIES`, added to (raw power).
    """
    medium, phase, limits, sea = scenery.medium, scenery.phase, scenery.limits, scenery.sea
    n_w, a, b = medium.refractive_index, medium.absorption, medium.scattering
    longest, air_back = limits.longest, limits.air_back
    lowest, highest = limits.lowest, limits.highest
    most = limits.most
    bias, reflect = limits.bias, limits.reflection_bias
    state = np.empty(1, dtype=np.uint64)
    for i in range(launch.x.size):
        w = launch.weight[i]
        if w <= 0.0:
            continue
        tallies[_TRANSMITTED] += w
        floor = w * _ROULETTE_WEIGHT
        state[0] = photon_state(key, first_index + i)
        x, y, z = launch.x[i], launch.y[i], launch.z[i]
        dx, dy, dz = launch.dx[i], launch.dy[i], launch.dz[i]
        path = launch.air[i]
        events = 0
        while True:
            step = -math.log(uniform(state)) / b if b > 0.0 else np.inf
            hit = target_distance(x, y, z, dx, dy, dz, target)
            reach = min(step, hit)
            surfaced = False
            if dz > 0.0:
                if reach == np.inf:
                    reach = (highest - z) / dz + EPS
                ex, ey, ez = x + reach * dx, y + reach * dy, z + reach * dz
                if ez >= _elevation(ex, ey, sea)[0]:
                    lo, hi = 0.0, reach
                    for _ in range(_BISECTIONS):
                        mid = 0.5 * (lo + hi)
                        mx, my, mz = x + mid * dx, y + mid * dy, z + mid * dz
                        if mz >= _elevation(mx, my, sea)[0]:
                            hi = mid
                        else:
                            lo = mid
                    reach = lo
                    surfaced = True
            if reach == np.inf:
                tallies[_CUT] += w  # down for ever in clear water: nothing more to gate
                break
            kept = math.exp(-a * reach)
            tallies[_ABSORBED] += w * (1.0 - kept)
            w *= kept
            x, y, z = x + reach * dx, y + reach * dy, z + reach * dz
            path += n_w * reach
            if path + n_w * max(lowest - z, 0.0) + air_back >= longest:
                tallies[_CUT] += w
                break
            if surfaced:
                eta, sx, sy = _elevation(x, y, sea)
                norm = 1.0 / math.sqrt(1.0 + sx * sx + sy * sy)
                nx, ny, nz = -sx * norm, -sy * norm, norm
                cos_i = dx * nx + dy * ny + dz * nz
                if cos_i <= 0.0:
                    nx, ny, nz, cos_i = 0.0, 0.0, 1.0, dz
                reflectance = fresnel_unpolarised(cos_i, n_w, 1.0)
                tallies[_ESCAPED] += w * (1.0 - reflectance)
                w *= reflectance
                dx, dy, dz = dx - 2 * cos_i * nx, dy - 2 * cos_i * ny, dz - 2 * cos_i * nz
                z = min(z, eta) - EPS
            elif hit <= step:
                rho = target.reflectance
                nx, ny, nz = target_normal(x, y, z, dx, dy, dz, target)
                _estimate(
                    x,
                    y,
                    z,
                    nx,
                    ny,
                    nz,
                    w * rho,
                    True,
                    path,
                    scenery,
                    target,
                    image,
                    state,
                )
                tallies[_TARGET] += w * (1.0 - rho)
                w *= rho
                # Lambertian, or (share reflect) about the way to the receiver, weighted
                ax, ay, az = toward_receiver(x, y, z, scenery.camera, n_w)
                if uniform(state) < reflect:
                    theta = scattering_angle(uniform(state), phase.quantiles)
                    cos_t, sin_t = math.cos(theta), math.sin(theta)
                    ux, uy, uz = ax, ay, az
                else:
                    cos_t = math.sqrt(uniform(state))
                    sin_t = math.sqrt(max(1.0 - cos_t * cos_t, 0.0))
                    ux, uy, uz = nx, ny, nz
                dx, dy, dz = turn(ux, uy, uz, cos_t, sin_t, 2.0 * math.pi * uniform(state))
                old = w
                w *= reflection_weight(nx, ny, nz, ax, ay, az, dx, dy, dz, phase, reflect)
                tallies[_CUT] -= w - old
                if w <= 0.0:
                    break  # drawn into the target: its weight is in the cut tally
            else:
                _estimate(
                    x,
                    y,
                    z,
                    dx,
                    dy,
                    dz,
                    w,
                    False,
                    path,
                    scenery,
                    target,
                    image,
                    state,
                )
                events += 1
                if events >= most:
                    tallies[_CUT] += w
                    break
                ax, ay, az = toward_receiver(x, y, z, scenery.camera, n_w)
                biased = uniform(state) < bias
                theta = scattering_angle(uniform(state), phase.quantiles)
                phi = 2.0 * math.pi * uniform(state)
                cos_t, sin_t = math.cos(theta), math.sin(theta)
                if biased:
                    nx, ny, nz = turn(ax, ay, az, cos_t, sin_t, phi)
                else:
                    nx, ny, nz = turn(dx, dy, dz, cos_t, sin_t, phi)
                old = w
                w *= mixture_weight(dx, dy, dz, ax, ay, az, nx, ny, nz, phase, bias)
                tallies[_CUT] -= w - old
                dx, dy, dz = nx, ny, nz
            if w < floor:
                if uniform(state) < _ROULETTE_SURVIVAL:
                    tallies[_CUT] -= w * (1.0 / _ROULETTE_SURVIVAL - 1.0)
                    w /= _ROULETTE_SURVIVAL
                else:
                    tallies[_CUT] += w
                    break


_HERE = Path(__file__).resolve().parent
INLINED = (
    *_HERE.glob("*.py"),
    *(_HERE.parent / "targets").glob("*.py"),
    _HERE.parent / "optics" / "fresnel.py",
)
"""Every source the kernels below compile in: this package, the target shapes, Fresnel."""

refresh_stale((_elevation, _estimate, transport), sources=INLINED)
