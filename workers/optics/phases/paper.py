"""The paper's phase function (§4.4) on the sphere: its forward shape, the water's b_b and β(π).

The paper models only small angles, s ∝ θ^-3/2 (θ0² + θ²)^-1/2, and takes the gated water
backscatter from a separate coefficient. `Paper` is the one water both renderers read: the
fast renderer transforms s as it is on 0 < θ ≤ π (`Paper.small_angle`, Σ(0) = 1) with the
rate b_f = b − b_b, and takes β(π) = 0.174 b_b (`BETA_PI_PER_BACKSCATTER`); the Monte Carlo
renderer samples `Paper.value`, which carries the same three things over the sphere: the
paper's s(θ) on the forward hemisphere holding 1 − b_b/b, and on the backward hemisphere
the lowest-order polynomial in cos θ holding b_b/b with β̃(π) = 0.174 b_b/b (`backward`).
With b_b = 0 (the paper's Examples 1–2) neither renderer scatters light backward.

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

__all__ = ["BACKWARD_CONSTANT", "BACKWARD_SLOPE", "Paper", "backward", "paper_phase_function"]

BACKWARD_SLOPE = 2 * (BETA_PI_PER_BACKSCATTER - 0.5 / np.pi)
"""γ of the backward shape α + γ |cos θ| [1/sr]: 2 (0.174 − 1/(2π)) = 0.0297 sr⁻¹."""

BACKWARD_CONSTANT = BETA_PI_PER_BACKSCATTER - BACKWARD_SLOPE
"""α of the backward shape α + γ |cos θ| [1/sr]: 1/π − 0.174 = 0.1443 sr⁻¹."""


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


def backward(theta, *, fraction):
    r"""The backward hemisphere of `Paper`: b_b/b spread as α + γ |cos θ| [1/sr].

    Parameters
    ----------
    theta : float or array_like
        Scattering angle θ [rad]; the shape is 0 below π/2.
    fraction : float
        The water's backscatter fraction B = b_b/b [1].

    Returns
    -------
    float or ndarray
        :math:`B\,(\alpha + \gamma\,|\cos\theta|)` on π/2 < θ ≤ π, 0 below.

    Notes
    -----
    The lowest-order polynomial in cos θ that meets both of the fast renderer's backward
    quantities for every B ≥ 0 (b_b = 0 included, where Fournier–Forand has no fit):
    :math:`2\pi\int_{\pi/2}^{\pi}(\alpha+\gamma|\cos\theta|)\sin\theta\,d\theta
    = 2\pi(\alpha + \gamma/2) = 1` and α + γ = 0.174 sr⁻¹ (β(π) = 0.174 b_b), so
    α = 1/π − 0.174, γ = 2 (0.174 − 1/(2π)) (`BACKWARD_CONSTANT`, `BACKWARD_SLOPE`). It
    rises from 0.144 B sr⁻¹ at 90° to 0.174 B at 180°; Fournier–Forand fitted to
    B = 0.0183 (the project's default water) runs 0.152–0.174 B over 110–180° and rises to
    0.20 B at 90° (Petzold's average particle function: 0.23 B at 90°, 0.13–0.17 B beyond
    130°, Mobley 1994 Table 3.10).
    """
    theta = np.asarray(theta, dtype=np.float64)
    shape = BACKWARD_CONSTANT - BACKWARD_SLOPE * np.cos(theta)
    return np.where(theta > 0.5 * np.pi, fraction * shape, 0.0)[()]


@functools.lru_cache(maxsize=16)
def _forward_cumulative(theta0: float):
    """(ln θ, F(θ)): the share of s sin θ below θ within the forward hemisphere, F(π/2) = 1."""
    theta = np.geomspace(_THETA_MIN * 1e-3, 0.5 * np.pi, 200_001)
    weights = paper_phase_function(theta, theta0=theta0) * np.sin(theta) * theta  # per ln θ
    steps = 0.5 * (weights[1:] + weights[:-1]) * np.diff(np.log(theta))
    first = 2 * weights[0]  # s sin θ ∝ θ^(-1/2) below the grid: ∫ θ^(1/2) d ln θ = 2 θ^(1/2)
    cumulative = first + np.concatenate([[0.0], np.cumsum(steps)])
    return np.log(theta), cumulative / cumulative[-1], float(2 * np.pi * cumulative[-1])


@register
@dataclass(frozen=True, kw_only=True)
class Paper(PhaseFunction):
    r"""The paper's phase function for a water of angular scale θ0 and backscatter fraction B.

    Parameters
    ----------
    theta0 : float
        Angular scale θ0 > 0 [rad] (paper: 0.12).
    fraction : float
        The water's b_b/b, in [0, 1] [1].

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
    kinks = (0.5 * np.pi,)
    # its θ^-3/2 tail: the small-angle spread reads 0.72-0.87 of transport's return in
    # coastal water, where Fournier-Forand's reads 0.99 (docs/model.md §10)
    transport_gains = True
    theta0: float
    fraction: float

    @classmethod
    def for_water(cls, *, backscatter_fraction, theta0):
        """With the water's b_b/b [1] and θ0 [rad]."""
        return cls(theta0=float(theta0), fraction=float(backscatter_fraction))

    def value(self, theta):
        r"""The paper's water over the sphere [1/sr].

        :math:`(1-B)\,s(\theta)/(2\pi\int_0^{\pi/2}s\sin\theta\,d\theta)` on θ ≤ π/2 (the
        shape of `paper_phase_function`), `backward` beyond: ∫ over the sphere = 1, over
        the backward hemisphere B, β̃(π) = 0.174 B.
        """
        theta = np.asarray(theta, dtype=np.float64)
        _, _, norm = _forward_cumulative(self.theta0)
        forward = (1.0 - self.fraction) / norm * paper_phase_function(theta, theta0=self.theta0)
        front = theta <= 0.5 * np.pi
        return np.where(front, forward, backward(theta, fraction=self.fraction))[()]

    def small_angle(self):
        """`paper_phase_function` itself, on (0, π] [1/sr] (the fast renderer's rate is b_f)."""
        return functools.partial(paper_phase_function, theta0=self.theta0), np.pi

    def backscatter_fraction(self):
        """B, which `value` holds on the backward hemisphere exactly [1]."""
        return self.fraction

    def backscatter_pi_per_backscatter(self):
        """`BETA_PI_PER_BACKSCATTER` [1/sr]: β̃(π)/B of `backward`."""
        return BETA_PI_PER_BACKSCATTER

    def cumulative(self, theta, values):
        """(1 − B) F(θ) forward (`_forward_cumulative`), closed form backward [1].

        Backward, 1 − B + 2π B (α μ + γ μ²/2) with μ = −cos θ.
        """
        log_theta, forward, _ = _forward_cumulative(self.theta0)
        b = self.fraction
        mu = np.maximum(-np.cos(theta), 0.0)
        back = 1.0 - b + 2 * np.pi * b * (BACKWARD_CONSTANT * mu + 0.5 * BACKWARD_SLOPE * mu * mu)
        front = (1.0 - b) * np.interp(np.log(theta), log_theta, forward)
        return np.concatenate([[0.0], np.where(theta <= 0.5 * np.pi, front, back)])
