"""The paper's small-angle phase function (§4.4), s ∝ θ^-3/2 (θ0² + θ²)^-1/2.

The fast renderer transforms it as it is, on 0 < θ ≤ π (its own normalisation, Σ(0) = 1);
the Monte Carlo renderer samples it normalised over the sphere (`Paper.value`). Its
backscatter is its own: the fast renderer's gated water backscatter keeps β(π) = 0.174 b_b
(a forward-peak model says nothing reliable of β(π)).

Units: phase functions in 1/sr, angles in rad.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy import special

from workers.optics.phases.base import (
    _THETA_MIN,
    BETA_PI_PER_BACKSCATTER,
    PhaseFunction,
    register,
)

__all__ = ["Paper", "paper_phase_function"]


@functools.lru_cache(maxsize=16)
def _paper_normalisation(theta0):
    """Integral of θ^(-1/2) (θ0² + θ²)^(-1/2) over [0, π] (Legendre form, see below)."""
    return special.ellipkinc(2 * np.arctan(np.sqrt(np.pi / theta0)), 0.5) / np.sqrt(theta0)


def paper_phase_function(theta, *, theta0):
    r"""Evaluate the paper's small-angle phase function (§4.4), normalised so Σ(0) = 1.

    Parameters
    ----------
    theta : float or array_like
        Scattering angle θ > 0 [rad] (s diverges at θ = 0).
    theta0 : float
        Angular scale θ0 > 0 [rad] (paper: 0.12).

    Returns
    -------
    float or ndarray
        :math:`s(\theta) = s_0\,\theta^{-3/2}(\theta_0^2+\theta^2)^{-1/2}` on
        0 < θ ≤ π and 0 beyond [1/sr], with s0 such that
        :math:`\Sigma(0) = 2\pi\int_0^\pi s(\theta)\,\theta\,d\theta = 1`.

    Notes
    -----
    The normalising integral reduces (u = √θ) to
    :math:`\int_0^\pi \theta^{-1/2}(\theta_0^2+\theta^2)^{-1/2}d\theta
    = F\!\left(2\arctan\sqrt{\pi/\theta_0}\,\middle|\,\tfrac12\right)/\sqrt{\theta_0}`,
    an incomplete elliptic integral of the first kind (parameter m = 1/2), evaluated with
    :func:`scipy.special.ellipkinc`.

    References
    ----------
    Carmona, R., Cérou, F. & Blasco, B. (2000). Lidar imaging through the ocean surface,
    §4.4 "Scattering Computations".
    """
    theta = np.asarray(theta, dtype=np.float64)
    s0 = 1 / (2 * np.pi * _paper_normalisation(float(theta0)))
    s = s0 * theta**-1.5 / np.sqrt(theta0 * theta0 + theta * theta)
    return np.where(theta <= np.pi, s, 0.0)[()]


@functools.lru_cache(maxsize=16)
def _sphere_norm(theta0: float) -> float:
    theta = np.geomspace(_THETA_MIN * 1e-3, np.pi, 200_001)
    s = paper_phase_function(theta, theta0=theta0) * np.sin(theta)
    return float(2 * np.pi * np.trapezoid(s, theta) + 2 * np.pi * s[0] * theta[0] / 1.5)


@register
@dataclass(frozen=True, kw_only=True)
class Paper(PhaseFunction):
    r"""The paper's phase function with angular scale θ0 [rad] (paper: 0.12).

    Notes
    -----
    Its MTF exponent D is tabulated once per θ0 (~0.2 s) with
    `workers.optics.hankel.hankel_mtf_exponent` on 481 points log-spaced over
    ψ ∈ [1e-4, 1e6] and interpolated linearly in ln ψ (error below 3e-5 in D). Below the
    table D = 1 (the true deficit there is below 1e-8). Beyond it D follows the exact
    large-ψ law of this phase function, :math:`D \propto \psi^{-1/2}` (from its
    :math:`\theta^{-3/2}` core), continued from the last tabulated value; the next-order
    correction is below 0.1 % there.
    """

    name = "paper"
    mtf_tail = 0.5
    theta0: float

    @classmethod
    def for_water(cls, *, backscatter_fraction, theta0):
        """With the water's θ0 [rad]; its b_b/b [1] is not used."""
        return cls(theta0=float(theta0))

    def value(self, theta):
        r"""The paper's s(θ) normalised over the sphere [1/sr].

        :math:`s(\theta)/(2\pi\int_0^\pi s\sin\theta\,d\theta)`: the shape of
        `paper_phase_function` with the 3-D measure sin θ dθ in place of θ dθ.
        """
        return np.asarray(paper_phase_function(theta, theta0=self.theta0)) / _sphere_norm(
            self.theta0
        )

    def small_angle(self):
        """`paper_phase_function` itself, on (0, π] [1/sr]."""
        return functools.partial(paper_phase_function, theta0=self.theta0), np.pi

    def backscatter_pi_per_backscatter(self):
        """`BETA_PI_PER_BACKSCATTER` [1/sr]: β(π) is taken from the water's b_b."""
        return BETA_PI_PER_BACKSCATTER

    def cumulative(self, theta, values):
        """Trapezoid sum in ln θ, the cone below θ[0] as ∫ θ^(1/2) [1]."""
        weights = 2 * np.pi * values * np.sin(theta) * theta  # per unit ln θ
        steps = 0.5 * (weights[1:] + weights[:-1]) * np.diff(np.log(theta))
        first = 2 * np.pi * values[0] * theta[0] ** 2 / 1.5  # ∫ θ^(1/2) below θ_min
        cumulative = np.concatenate([[0.0], first + np.concatenate([[0.0], np.cumsum(steps)])])
        cumulative /= cumulative[-1]
        return cumulative
