"""Wells' small-angle phase function, s ∝ θ0 (θ0² + θ²)^-3/2, with its closed-form MTF.

A small-angle model on θ ∈ [0, ∞): the fast renderer's only (the Monte Carlo renderer
cannot sample it over the sphere). The gated water backscatter keeps β(π) = 0.174 b_b.

Units: phase functions in 1/sr, angles in rad, ψ in cycles/rad.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy import special

from workers.optics.phases.base import BETA_PI_PER_BACKSCATTER, PhaseFunction, register

__all__ = ["Wells", "wells_mtf_exponent", "wells_phase_function"]


def wells_phase_function(theta, *, theta0):
    r"""Evaluate Wells' small-angle phase function, the one with a closed-form MTF exponent.

    Parameters
    ----------
    theta : float or array_like
        Scattering angle θ ≥ 0 [rad], small-angle (plane) variable on [0, ∞).
    theta0 : float
        Angular scale θ0 > 0 [rad].

    Returns
    -------
    float or ndarray
        :math:`s(\theta) = \frac{\theta_0}{2\pi(\theta_0^2+\theta^2)^{3/2}}` [1/sr],
        normalised so that :math:`2\pi\int_0^\infty s(\theta)\,\theta\,d\theta = 1`.

    References
    ----------
    Wells, W. H. (1973). Theory of small angle scattering. In *Optics of the Sea*, AGARD
    Lecture Series 61, §3.3. NATO AGARD, Neuilly-sur-Seine.
    """
    theta = np.asarray(theta, dtype=np.float64)
    return (theta0 / (2 * np.pi) * (theta0 * theta0 + theta * theta) ** -1.5)[()]


def wells_mtf_exponent(psi, *, theta0):
    r"""Closed-form MTF exponent D(ψ) of `wells_phase_function`.

    Parameters
    ----------
    psi : float or array_like
        Angular frequency ψ [cycles/rad]; the sign is ignored.
    theta0 : float
        Angular scale θ0 [rad].

    Returns
    -------
    float or ndarray
        :math:`D(\psi) = \frac{1 - e^{-2\pi\theta_0\psi}}{2\pi\theta_0\psi}` [1], with
        D(0) = 1 (evaluated as ``exprel(-2π θ0 ψ)``, no cancellation near 0).

    Notes
    -----
    Σ(ψ) = exp(−2πθ0ψ) is the Hankel transform of the phase function on θ ∈ [0, ∞).

    References
    ----------
    Wells, W. H. (1973). Theory of small angle scattering. In *Optics of the Sea*, AGARD
    Lecture Series 61, §3.3. NATO AGARD, Neuilly-sur-Seine.
    """
    psi = np.abs(np.asarray(psi, dtype=np.float64))
    return special.exprel(-2 * np.pi * theta0 * psi)[()]


@register
@dataclass(frozen=True, kw_only=True)
class Wells(PhaseFunction):
    """Wells' phase function with angular scale θ0 [rad]; small-angle only."""

    name = "wells"
    spherical = False
    theta0: float

    @classmethod
    def for_water(cls, *, backscatter_fraction, theta0):
        """With the water's θ0 [rad]; its b_b/b [1] is not used."""
        return cls(theta0=float(theta0))

    def value(self, theta):
        """Not defined over the sphere: raises `ValueError`."""
        raise ValueError(
            "the wells phase function is a small-angle model, not defined over the sphere"
        )

    def small_angle(self):
        """`wells_phase_function` on [0, ∞) [1/sr]."""
        return functools.partial(wells_phase_function, theta0=self.theta0), np.inf

    def mtf_exponent(self, psi):
        """The closed form, `wells_mtf_exponent` [1]."""
        return wells_mtf_exponent(psi, theta0=self.theta0)

    def backscatter_pi_per_backscatter(self):
        """`BETA_PI_PER_BACKSCATTER` [1/sr]: β(π) is taken from the water's b_b."""
        return BETA_PI_PER_BACKSCATTER
