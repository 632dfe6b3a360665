"""The Henyey–Greenstein phase function, its asymmetry g solved from the water's b_b/b.

One parameter, the mean cosine g; no settings field: g is the one whose backscatter
fraction is the water's b_b/b (closed form below, solved by Brent's method), so that the
water's IOPs and its phase function agree by construction. β(π)/b_b is then HG's own,
β̃(π)/B (≈ 0.096 sr⁻¹ at b_b/b = 0.0156, g = 0.93), not Petzold's 0.174.

Units: phase functions in 1/sr (normalised over the sphere, 4π sr), angles in rad.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import optimize

from workers.optics.phases.base import PhaseFunction, register

__all__ = ["HenyeyGreenstein", "henyey_greenstein_backscatter"]


def henyey_greenstein_backscatter(g):
    r"""Backscatter fraction b_b/b of Henyey–Greenstein with asymmetry 0 < g < 1 [1].

    Notes
    -----
    :math:`B = 2\pi\int_{\pi/2}^{\pi}\tilde\beta\sin\theta\,d\theta
    = \frac{1-g}{2g}\left(\frac{1+g}{\sqrt{1+g^2}} - 1\right)`, from
    :math:`\int(1+g^2-2g\mu)^{-3/2}d\mu = \frac1g(1+g^2-2g\mu)^{-1/2}` over μ ∈ [−1, 0].

    References
    ----------
    Mobley, C. D. (1994). *Light and Water: Radiative Transfer in Natural Waters*.
    Academic Press, §3.8 (the one-term HG function).
    """
    return (1 - g) / (2 * g) * ((1 + g) / np.sqrt(1 + g * g) - 1)


@register
@dataclass(frozen=True, kw_only=True)
class HenyeyGreenstein(PhaseFunction):
    r"""Henyey–Greenstein with asymmetry (mean cosine) g [1].

    .. math:: \tilde\beta(\theta) = \frac{1-g^2}{4\pi(1+g^2-2g\cos\theta)^{3/2}}

    References
    ----------
    Henyey, L. G. & Greenstein, J. L. (1941). Diffuse radiation in the galaxy.
    Astrophysical Journal 93, 70–83.
    """

    name = "henyey_greenstein"
    fractions = (1e-4, 0.45)
    g: float

    @classmethod
    def for_water(cls, *, backscatter_fraction, theta0):
        """The g whose b_b/b is the water's (in `fractions`) [1]; θ0 [rad] is not used."""
        low, high = cls.fractions
        if not low <= backscatter_fraction <= high:
            raise ValueError(
                f"backscatter fraction b_b/b = {backscatter_fraction:.4g} is outside "
                f"[{low}, {high}], where a Henyey-Greenstein function is solved for it"
            )
        g = optimize.brentq(
            lambda g: henyey_greenstein_backscatter(g) - backscatter_fraction,
            1e-3,
            1 - 1e-9,
            xtol=1e-15,
            rtol=1e-15,
        )
        return cls(g=float(g))

    def value(self, theta):
        """β̃(θ) [1/sr]."""
        g = self.g
        mu = np.cos(np.asarray(theta, dtype=np.float64))
        return ((1 - g * g) / (4 * np.pi * (1 + g * g - 2 * g * mu) ** 1.5))[()]

    def backscatter_fraction(self):
        """`henyey_greenstein_backscatter` (closed form) [1]."""
        return float(henyey_greenstein_backscatter(self.g))
