"""How late the scattered part of a return arrives: the path stretch of small-angle paths.

A gate selects light by its time of flight. Light scattered on its way to a point and
back travels farther than the straight path, so part of a surface's return reaches the
receiver as if from deeper: `return_delays` gives that stretch's distribution, with which
`workers.fast.planes` gates each cell of the target (docs/model.md §5).
"""

from __future__ import annotations

import functools

import numpy as np

from workers.optics.water import WaterOptics

__all__ = ["return_delays"]

DELAY_PATHS = 8192
"""Paths drawn per leg for the stretch's distribution (fixed stream: a quadrature)."""

DELAY_POINTS = 16
"""Equal-probability points representing the scattered return's delay."""

_STEEPEST = 1.5
"""Largest angle to the vertical [rad] a small-angle path is taken at (beyond, its stretch
is that of 86°: the light is as good as lost to the gate)."""


@functools.lru_cache(maxsize=64)
def return_delays(
    water: WaterOptics, *, path: float, beam_radius: float, target_radius: float
) -> tuple[float, np.ndarray]:
    r"""The apparent extra depth of a return from a water path `path`, down and up.

    Parameters
    ----------
    water : WaterOptics
        The water column (its forward scattering b_f and small-angle phase function).
    path : float
        Water path from the surface to the reflecting point, one way [m].
    beam_radius : float
        1/e radius of the laser beam where it meets the sea [m].
    target_radius : float
        Radius of the target [m].

    Returns
    -------
    unscattered : float
        Share of the return that neither leg scattered [1]: it arrives on time.
    delays : ndarray
        `DELAY_POINTS` delays δ [m] of the rest, each carrying an equal share of it: light
        reflected at depth z arrives with the light of the straight path to z + δ.

    Notes
    -----
    Each leg is the small-angle path of Wells' theory (the light of a broad beam reaching
    the point, or, by reciprocity, the pixel's line traced back down): a Poisson number of
    scatterings (mean b_f ℓ) at uniform places, each turning the direction by an angle
    drawn from the water's small-angle phase function
    (`workers.optics.water.WaterOptics.small_angle_phase_function`) about a uniform azimuth. A
    stretch at angle Θ to the vertical is longer by sec Θ − 1 per unit path and moves
    sideways by tan Θ; the legs' sum is halved (a round trip: δ of depth is 2δ of path).
    A path only counts where it ends: the way down is weighted by the beam's
    irradiance where it set off, e^(−s²/a²) for a side step s (a the beam's radius), the
    way up by e^(−s²/r²) (r the target's radius: the pixel's line, traced back, must end
    on the target), so the long, steep paths that would come from outside the beam or
    miss the target do not delay its light; the unscattered paths (weight 1) are on time.
    Drawn once per water and geometry from a fixed stream (`DELAY_PATHS`, a quadrature,
    not the sample's randomness).
    """
    scattering = water.forward_scattering * path
    if scattering == 0:
        return 1.0, np.zeros(DELAY_POINTS)
    rng = np.random.default_rng(20261124)
    angles = _angle_sampler(water)
    stretch, weight = np.zeros(DELAY_PATHS), np.ones(DELAY_PATHS)
    for reach, incidence in ((beam_radius, True), (target_radius, False)):
        extra, side, tilt = _leg(rng, angles, scattering, path)
        stretch += 0.5 * extra
        weight *= np.exp(-((side / reach) ** 2)) * (np.cos(tilt) if incidence else 1.0)
    late = stretch > 0
    total = weight.sum()
    unscattered = float(weight[~late].sum() / total)
    if not late.any() or weight[late].sum() == 0:
        return 1.0, np.zeros(DELAY_POINTS)
    order = np.argsort(stretch[late])
    cumulative = np.cumsum(weight[late][order])
    probabilities = (np.arange(DELAY_POINTS) + 0.5) / DELAY_POINTS * cumulative[-1]
    return unscattered, stretch[late][order][np.searchsorted(cumulative, probabilities)]


def _angle_sampler(water: WaterOptics):
    """Inverse cumulative of the small-angle phase function on a log grid of θ [rad]."""
    function, theta_max = water.small_angle_phase_function()
    theta = np.geomspace(1e-7, min(theta_max, 0.5 * np.pi), 4096)
    density = function(theta) * theta * theta  # per unit ln θ
    cumulative = np.concatenate([[0.0], np.cumsum(0.5 * (density[1:] + density[:-1]))])
    cumulative /= cumulative[-1]
    return lambda u: np.interp(u, cumulative, theta)


def _leg(rng, angles, scattering: float, path: float):
    """Extra path, side step [m] and final tilt [rad] of `DELAY_PATHS` legs of `path` [m]."""
    counts = rng.poisson(scattering, DELAY_PATHS)
    most = max(int(counts.max()), 1)
    live = np.arange(most)[None, :] < counts[:, None]
    # a leg's own scatterings, in order; its unused columns sit at its end
    places = np.sort(np.where(live, rng.uniform(0.0, path, (DELAY_PATHS, most)), path), axis=1)
    turn = np.where(live, angles(rng.uniform(size=(DELAY_PATHS, most))), 0.0)
    azimuth = rng.uniform(0.0, 2 * np.pi, (DELAY_PATHS, most))
    tx = np.cumsum(turn * np.cos(azimuth), axis=1)
    ty = np.cumsum(turn * np.sin(azimuth), axis=1)
    tilt = np.minimum(np.hypot(tx, ty), _STEEPEST)
    lengths = np.diff(np.concatenate([places, np.full((DELAY_PATHS, 1), path)], axis=1), axis=1)
    extra = (lengths / np.cos(tilt) - lengths).sum(axis=1)
    reach = lengths * np.tan(tilt) / np.maximum(np.hypot(tx, ty), 1e-300)
    side = np.hypot((reach * tx).sum(axis=1), (reach * ty).sum(axis=1))
    return extra, side, tilt[np.arange(DELAY_PATHS), np.maximum(counts, 1) - 1] * (counts > 0)
