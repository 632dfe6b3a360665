"""The Fournier–Forand phase function, fitted to the water's b_b/b and β(π) = 0.174 b_b.

The default of both renderers: the fast renderer's small-angle MTF takes its forward half
and the Monte Carlo renderer samples it (exact cumulative), so that where they differ it is
by their transport, not their water. β(π)/b_b is Petzold's average particle ratio
(`workers.optics.phases.base.BETA_PI_PER_BACKSCATTER`).

Units: phase functions in 1/sr (normalised over the sphere, 4π sr), angles in rad.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy import optimize

from workers.optics.phases.base import BETA_PI_PER_BACKSCATTER, PhaseFunction, register

__all__ = [
    "FF_FRACTIONS",
    "FournierForand",
    "fit_fournier_forand",
    "fournier_forand",
    "fournier_forand_cumulative",
]

FF_FRACTIONS = (0.002, 0.095)
"""Backscatter fractions b_b/b for which `fit_fournier_forand` has a solution (about 0.098
at most: above, no Fournier-Forand function has β̃(π) = 0.174 b_b/b with 3 < μ < 5)."""


def _ff_delta(theta, n):
    return 4.0 / (3.0 * (n - 1.0) ** 2) * np.sin(0.5 * theta) ** 2


def fournier_forand(theta, *, n, mu):
    r"""The Fournier–Forand phase function, normalised over the sphere [1/sr].

    Parameters
    ----------
    theta : float or array_like
        Scattering angle θ in (0, π] [rad].
    n : float
        Real refractive index of the particles relative to water, > 1 [1].
    mu : float
        Slope of the hyperbolic (Junge) size distribution, 3 < μ < 5 [1].

    Returns
    -------
    float or ndarray
        :math:`\tilde\beta(\theta)` with :math:`2\pi\int_0^\pi\tilde\beta\sin\theta\,d\theta = 1`.

    Notes
    -----
    .. math::
        \tilde\beta = \frac{\nu(1-\delta) - (1-\delta^\nu)
        + [\delta(1-\delta^\nu) - \nu(1-\delta)]\sin^{-2}(\theta/2)}
        {4\pi(1-\delta)^2\delta^\nu}
        + \frac{1-\delta_{180}^\nu}{16\pi(\delta_{180}-1)\delta_{180}^\nu}(3\cos^2\theta-1),

    :math:`\nu = (3-\mu)/2`, :math:`\delta = \frac{4}{3(n-1)^2}\sin^2(\theta/2)`.

    References
    ----------
    Fournier, G. R. & Jonasz, M. (1999). Computer-based underwater imaging analysis.
    Proc. SPIE 3761, 62–70. Mobley, C. D., Sundman, L. K. & Boss, E. (2002). Phase function
    effects on oceanic light fields. Applied Optics 41(6), 1035–1050, eq. (3)–(4).
    """
    theta = np.asarray(theta, dtype=np.float64)
    nu = 0.5 * (3.0 - mu)
    d = _ff_delta(theta, n)
    d180 = _ff_delta(np.pi, n)
    dn = d**nu
    half = np.sin(0.5 * theta) ** 2
    main = (nu * (1 - d) - (1 - dn) + (d * (1 - dn) - nu * (1 - d)) / half) / (
        4 * np.pi * (1 - d) ** 2 * dn
    )
    tail = (1 - d180**nu) / (16 * np.pi * (d180 - 1) * d180**nu) * (3 * np.cos(theta) ** 2 - 1)
    return (main + tail)[()]


def fournier_forand_cumulative(theta, *, n, mu):
    r"""Fraction of the Fournier–Forand scattering into angles below θ [1].

    Parameters
    ----------
    theta : float or array_like
        Scattering angle θ in [0, π] [rad].
    n, mu : float
        As for `fournier_forand`.

    Returns
    -------
    float or ndarray
        :math:`F(\theta) = 2\pi\int_0^\theta\tilde\beta\sin\theta'\,d\theta'`, exactly
        :math:`\frac{1-\delta^{\nu+1}-(1-\delta^\nu)\sin^2(\theta/2)}{(1-\delta)\delta^\nu}
        + \frac{1-\delta_{180}^\nu}{8(\delta_{180}-1)\delta_{180}^\nu}\cos\theta\sin^2\theta`;
        F(π) = 1, and 1 − F(π/2) is the backscatter fraction.

    References
    ----------
    Fournier, G. R. & Jonasz, M. (1999), as for `fournier_forand`.
    """
    theta = np.asarray(theta, dtype=np.float64)
    nu = 0.5 * (3.0 - mu)
    d = _ff_delta(theta, n)
    d180 = _ff_delta(np.pi, n)
    with np.errstate(divide="ignore", invalid="ignore"):
        dn = d**nu
        main = (1 - d ** (nu + 1) - (1 - dn) * np.sin(0.5 * theta) ** 2) / ((1 - d) * dn)
    main = np.where(theta > 0, main, 0.0)
    tail = (1 - d180**nu) / (8 * (d180 - 1) * d180**nu) * np.cos(theta) * np.sin(theta) ** 2
    return (main + tail)[()]


@functools.lru_cache(maxsize=64)
def fit_fournier_forand(backscatter_fraction: float) -> tuple[float, float]:
    r"""Fournier–Forand (n, μ) with a given backscatter fraction and β̃(π) = 0.174 B.

    Parameters
    ----------
    backscatter_fraction : float
        B = b_b/b, in [0.002, 0.095] (`FF_FRACTIONS`) [1].

    Returns
    -------
    n, mu : float
        The particles' relative refractive index and Junge slope [1], such that
        1 − F(π/2) = B and :math:`\tilde\beta(\pi)` = `BETA_PI_PER_BACKSCATTER` · B:
        the backscatter b_b and β(π) of the fast renderer (`workers.optics.water.WaterOptics`),
        so that the two renderers share both.

    Notes
    -----
    Solved by Newton's method (`scipy.optimize.fsolve`) from Mobley et al.'s (2002) fit to
    Petzold's average particle phase function, n = 1.10, μ = 3.5835 (B = 0.0183).
    """
    low, high = FF_FRACTIONS
    if not low <= backscatter_fraction <= high:
        raise ValueError(
            f"backscatter fraction b_b/b = {backscatter_fraction:.4g} is outside "
            f"[{low}, {high}], where a Fournier-Forand phase function has beta(pi) = "
            f"{BETA_PI_PER_BACKSCATTER} b_b"
        )
    target = np.log([backscatter_fraction, BETA_PI_PER_BACKSCATTER * backscatter_fraction])

    def residual(x):
        n, mu = 1.0 + np.exp(x[0]), x[1]
        back = 1.0 - fournier_forand_cumulative(0.5 * np.pi, n=n, mu=mu)
        pi = fournier_forand(np.pi, n=n, mu=mu)
        return np.log([max(back, 1e-300), max(pi, 1e-300)]) - target

    solution, _, ok, _ = optimize.fsolve(
        residual, [np.log(0.10), 3.5835], full_output=True, xtol=1e-12
    )
    n, mu = 1.0 + float(np.exp(solution[0])), float(solution[1])
    if ok != 1 or np.max(np.abs(residual(solution))) > 1e-8 or not 3.0 < mu < 5.0:
        raise ValueError(
            f"no Fournier-Forand phase function has b_b/b = {backscatter_fraction:.4g} and "
            f"β(π)/b_b = {BETA_PI_PER_BACKSCATTER}"
        )
    return n, mu


@register
@dataclass(frozen=True, kw_only=True)
class FournierForand(PhaseFunction):
    """Fournier–Forand fitted to a water's b_b/b (`fit_fournier_forand`).

    Parameters
    ----------
    fraction : float
        The water's b_b/b, in `FF_FRACTIONS` [1].
    """

    name = "fournier_forand"
    fractions = FF_FRACTIONS
    fraction: float

    @classmethod
    def for_water(cls, *, backscatter_fraction, theta0):
        """Fitted to the water's b_b/b [1]; θ0 [rad] is not used."""
        return cls(fraction=float(backscatter_fraction))

    @property
    def mtf_tail(self):
        """μ − 3: D ∝ ψ^-(μ-3) from the β̃ ∝ θ^-(5-μ) core, μ the Junge slope [1]."""
        return fit_fournier_forand(self.fraction)[1] - 3.0

    def value(self, theta):
        """`fournier_forand` with the fitted (n, μ) [1/sr]."""
        n, mu = fit_fournier_forand(self.fraction)
        return fournier_forand(theta, n=n, mu=mu)

    def backscatter_fraction(self):
        """1 − F(π/2), closed form (`fournier_forand_cumulative`) [1]."""
        n, mu = fit_fournier_forand(self.fraction)
        return 1.0 - float(fournier_forand_cumulative(0.5 * np.pi, n=n, mu=mu))

    def backscatter_pi_per_backscatter(self):
        """`BETA_PI_PER_BACKSCATTER`, which the fit meets to 1e-8 [1/sr]."""
        return BETA_PI_PER_BACKSCATTER

    def cumulative(self, theta, values):
        """The exact cumulative (`fournier_forand_cumulative`), 0 prepended [1]."""
        n, mu = fit_fournier_forand(self.fraction)
        return np.concatenate([[0.0], fournier_forand_cumulative(theta, n=n, mu=mu)])
