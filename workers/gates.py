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

import numpy as np

__all__ = ["central_paths", "sight_lines", "slab_bounds"]

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
