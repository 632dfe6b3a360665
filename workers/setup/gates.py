"""Range gates on slant range: the depth slab each line of sight sees through a flat sea.

A gate opens and closes on time, so on the optical path length of the round trip, not on
depth. Gates are given as depths [top, bottom] *along the central ray* under a flat sea
(at nadir: the depth slab itself, as the ML(DC) gates are specified in feet below the
surface);
each frame the delay follows the platform's altitude, as a surface-tracking receiver does.
A line of sight reaching the sea at another angle travels a different air path first, so
its gate covers other depths: at 20° nadir and 34 m altitude the gated depth changes by
about 1.2 m across a 6.7° image, at 45° by 3.6 m.

Approximation: the slab bounds are those of the flat sea. On a wavy sea a ray entering at
height η travels η/(n cos θ) further in the water within the same time, which moves the
gated depth by at most (1 − 1/n)|η| (a few centimetres), far below the gates' metres.
"""

from __future__ import annotations

import functools

import numpy as np
from array_api_compat import array_namespace, is_torch_array

from workers.optics.water import slab_backscatter_reflectance

__all__ = [
    "central_paths",
    "gate_gain",
    "gate_gains",
    "hidden_fraction",
    "sight_lines",
    "slab_bounds",
]

_NEWTON_STEPS = 8


def central_paths(*, altitude, nadir, refractive_index, gates):
    r"""Optical path lengths at which each gate opens and closes [m].

    Parameters
    ----------
    altitude : float
        Height of the platform above mean sea level H [m].
    nadir : float
        Angle of the central ray from the vertical in the air, θ [rad].
    refractive_index : float
        Refractive index n of the water [1].
    gates : array_like, shape (G, 2)
        (top, bottom) depths of the gates along the central ray [m].

    Returns
    -------
    ndarray, shape (G, 2)
        :math:`P = H/\cos\theta + n\,d/\cos\vartheta` for each bound d, with
        :math:`\sin\vartheta = \sin\theta/n` (one way; the round trip is twice it).
    """
    cos_water = np.sqrt(1.0 - (np.sin(nadir) / refractive_index) ** 2)
    return altitude / np.cos(nadir) + refractive_index * np.asarray(gates, float) / cos_water


def sight_lines(*, position, x, y, depth, refractive_index):
    r"""Air path and in-water direction of the flat-sea lines of sight to points at a depth.

    Parameters
    ----------
    position : array_like, shape (3,)
        Platform position (x, y, H) [m].
    x, y : ndarray
        World coordinates of the points [m].
    depth : float
        Depth of the points d > 0 [m].
    refractive_index : float
        Refractive index n of the water [1].

    Returns
    -------
    air : ndarray
        Length of the air path from the platform to mean sea level [m].
    cos_water : ndarray
        Cosine of the in-water angle from the vertical [1].

    Notes
    -----
    The ray at incidence θ reaches horizontal distance
    :math:`\rho = H\tan\theta + d\tan\vartheta`, :math:`\sin\vartheta = \sin\theta/n`;
    it is solved for s = sin θ by Newton's method from the paraxial guess
    :math:`s = \rho/\sqrt{\rho^2 + (H + d/n)^2}` (ρ is increasing and convex in s, so the
    iteration converges monotonically; 8 steps reach rounding).
    """
    height, n = float(position[2]), float(refractive_index)
    rho = np.hypot(np.asarray(x, float) - position[0], np.asarray(y, float) - position[1])
    s = rho / np.hypot(rho, height + depth / n)
    for _ in range(_NEWTON_STEPS):
        cos_air = np.sqrt(1.0 - s * s)
        cos_water = np.sqrt(1.0 - (s / n) ** 2)
        residual = height * s / cos_air + depth * s / (n * cos_water) - rho
        slope = height / cos_air**3 + depth / (n * cos_water**3)
        s = np.clip(s - residual / slope, 0.0, 0.999999)
    return height / np.sqrt(1.0 - s * s), np.sqrt(1.0 - (s / n) ** 2)


def slab_bounds(*, paths, air, cos_water, refractive_index):
    r"""Depth bounds of a gate along lines of sight.

    Parameters
    ----------
    paths : tuple of float
        Optical path lengths (opening, closing) of the gate (`central_paths`) [m].
    air : ndarray
        Air path of each line of sight (`sight_lines`) [m].
    cos_water : ndarray
        Cosine of each line's in-water angle [1].
    refractive_index : float
        Refractive index n of the water [1].

    Returns
    -------
    top, bottom : ndarray
        :math:`d = \max(P - L_{air}, 0)\cos\vartheta / n` for each bound [m], float64;
        top = bottom = 0 where the gate closes before the light reaches the water.
    """
    scale = cos_water / refractive_index
    top = np.maximum(paths[0] - air, 0.0) * scale
    bottom = np.maximum(paths[1] - air, 0.0) * scale
    return top, bottom


def hidden_fraction(surface_depth, occupancy, *, top, bottom, diffuse_attenuation):
    """Fraction of a slab's backscatter lying behind the target along each line.

    Lines through the target's silhouette (weighted by `occupancy`) lose the part of the
    single-scattering integral deeper than the target's surface. `top` and `bottom` are
    the slab's bounds (scalars, or one per line: slant-range gates). Computed in float64,
    so a float32 depth on a gate bound stays inside the slab.
    """
    top = np.asarray(top, dtype=np.float64)
    bottom = np.maximum(np.asarray(bottom, dtype=np.float64), top)
    behind = np.clip(np.asarray(surface_depth, dtype=np.float64), top, bottom)

    def slab(upper):
        return slab_backscatter_reflectance(
            backscatter_pi=1.0,
            diffuse_attenuation=diffuse_attenuation,
            top=upper,
            bottom=bottom,
            reference=top,
        )

    part, whole = np.broadcast_arrays(slab(behind), slab(top))
    share = np.divide(part, whole, out=np.zeros(part.shape), where=whole > 0)
    return (occupancy * share).astype(np.float32)


def gate_gain(excess, *, diffuse_attenuation, refractive_index, secant, top, bottom, depth):
    r"""A laser ray's or a pixel's share of a gate's water return, from its air path.

    A gate opens and closes at fixed times, so the water it holds is set by the optical
    path: a ray that spends τ longer in the air than the central ray (`excess`), down or
    up, has τ/n less water path within the gate. With both paths so delayed, the gated
    slab rises by δ = τ cos ϑ_c / n (ϑ_c the central ray's angle in the water), and its
    single-scattering return changes by

    .. math:: F(\delta) = \frac{\int_{(t-\delta)_+}^{(b-\delta)_+}
              e^{-2K\sec\vartheta_c z}dz}{\int_t^b e^{-2K\sec\vartheta_c z}dz},

    :math:`e^{2K\tau/n}` while the slab stays under the surface, less once the gate opens
    above it (the slab is cut at the surface), 0 if it closes before light reaches the
    water. Each path carries :math:`\sqrt{F}` (exact when the down and up delays are
    equal, as for the monostatic default), times the central ray's attenuation to the
    gate's plane: the gate, not the ray's own slant path, sets how deep the light is.

    Parameters
    ----------
    excess : ndarray
        Air path less the central ray's [m] (through the wavy surface: a crest shortens
        it, and the gate then holds less water: e^(−2Kη/n) for the round trip).
    diffuse_attenuation : float
        K [1/m].
    refractive_index : float
        n of the water [1].
    secant : float
        sec ϑ_c of the central ray in the water [1].
    top, bottom : float
        The gate's depths along the central ray [m].
    depth : float
        Depth of the gate's plane [m].

    Returns
    -------
    ndarray
        The gain [1], float32, in place of the ray's own extra-path attenuation.
    """
    return gate_gains(
        excess,
        diffuse_attenuation=diffuse_attenuation,
        refractive_index=refractive_index,
        secant=secant,
        slabs=((top, bottom, depth),),
    )[0]


def gate_gains(excess, *, diffuse_attenuation, refractive_index, secant, slabs):
    """`gate_gain` for several gates at once: the terms they share are computed once.

    Parameters
    ----------
    excess : array_like or torch.Tensor
        Air path less the central ray's [m]: host values, or a torch tensor, whose gains
        are computed on its device (`_device_gains`).
    diffuse_attenuation, refractive_index, secant : float
        K [1/m], n [1], sec ϑ_c [1], as in `gate_gain`.
    slabs : sequence of tuple
        ``(top, bottom, depth)`` of each gate [m], as in `gate_gain`.

    Returns
    -------
    list of ndarray or torch.Tensor
        The gain of each gate [1], float32, where `excess` is.
    """
    k, n = diffuse_attenuation, refractive_index
    if is_torch_array(excess):
        return _device_gains(excess, k, n, secant, slabs)
    excess = np.asarray(excess, dtype=np.float32)
    lift = np.exp(np.float32(k / n) * excess)
    rise = excess * np.float32(1.0 / (n * secant))
    return [_gain(lift.copy(), rise, k, secant, *slab) for slab in slabs]


def _device_gains(excess, k, n, secant, slabs):
    r"""`gate_gains` of a torch tensor on its device: nothing is read back to the host.

    Every ray and gate is evaluated at once (a gate axis), where the host computes only
    the rays whose slab the surface cuts (`_gain`); the cut is taken by a ``where``. The
    slab's share is :math:`\int_{(t-\delta)_+}^{(b-\delta)_+} e^{-2K'z}dz =
    -\mathrm{expm1}(-2K'\Delta)\,e^{-2K'(t-\delta)_+}/(2K')` in float64 on the device
    (K' = K sec ϑ_c, Δ the cut slab's thickness; Δ itself at K' = 0), over the whole slab's
    (`_slab_terms`): the gains agree with the host's to float32 rounding.
    """
    xp = array_namespace(excess)
    attenuation = k * secant
    tops, top_floats, bottoms, wholes, units = _slab_terms(
        xp, excess.device, tuple(tuple(slab) for slab in slabs), attenuation, k, secant
    )
    excess = xp.astype(excess, xp.float32)
    lift = xp.exp(np.float32(k / n) * excess)
    rise = excess * np.float32(1.0 / (n * secant))
    shifted = xp.astype(rise, xp.float64)
    upper = xp.clip(tops - shifted, min=0.0)
    thickness = xp.clip(bottoms - shifted, min=0.0) - upper
    share = thickness
    if attenuation > 0.0:
        share = xp.expm1((-2.0 * attenuation) * thickness) * xp.exp((-2.0 * attenuation) * upper)
        share = share * (-0.5 / attenuation)
    cut = xp.astype(xp.sqrt(share / wholes), xp.float32)
    # the host compares the float32 rises with each top taken to float32
    gains = xp.where(rise > top_floats, cut, lift) * units
    return [gains[g] for g in range(len(slabs))]


@functools.lru_cache(maxsize=64)
def _slab_terms(xp, device, slabs, attenuation, k, secant):
    """The gates' constants of `_device_gains` on `device`, shape (gate, 1), made once.

    The tops (float64 and float32), the bottoms, the whole slab's single-scattering
    integral (`workers.optics.water.slab_backscatter_reflectance` with πβ(π) = 1, from the
    top) and the central ray's attenuation to each gate's plane, float32, as `_gain`'s.
    """
    tops, bottoms, depths = (np.array([[slab[i]] for slab in slabs]) for i in range(3))
    wholes = slab_backscatter_reflectance(
        backscatter_pi=1 / np.pi,
        diffuse_attenuation=attenuation,
        top=tops,
        bottom=bottoms,
        reference=0.0,
    )
    units = np.exp(-k * depths * (secant - 1.0)).astype(np.float32)
    return tuple(
        xp.asarray(values, device=device)
        for values in (tops, tops.astype(np.float32), bottoms, wholes, units)
    )


def _gain(gain, rise, k, secant, top, bottom, depth):
    """`gate_gain` from e^(Kτ/n) (`gain`, changed in place) and the slab's rise δ."""
    cut = np.flatnonzero(rise > top)
    if cut.size:
        shifted = rise[cut].astype(np.float64)

        def slab(upper, lower):
            return slab_backscatter_reflectance(
                backscatter_pi=1 / np.pi,
                diffuse_attenuation=k * secant,
                top=upper,
                bottom=lower,
                reference=0.0,
            )

        share = slab(np.maximum(top - shifted, 0.0), np.maximum(bottom - shifted, 0.0))
        gain[cut] = np.sqrt(share / slab(top, bottom))
    gain *= np.float32(np.exp(-k * depth * (secant - 1.0)))
    return gain
