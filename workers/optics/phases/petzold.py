"""Petzold's San Diego harbour phase function, tabulated (average of his three stations).

The table is the cumulative scattering F(θ) = 2π ∫₀^θ β̃ sin θ' dθ' of the average of
Petzold's (1972) three San Diego harbour volume scattering functions at 55 angles, 0.1° to
180°, as used for the particle phase function of Mobley et al. (1993), the one whose
β̃(π) = 3.18e-3 sr⁻¹ and b_b/b = 0.0183 Mobley (1994, Table 3.10) quotes (this table
gives 1 − F(90°) = 0.0181). β̃ is taken on each cell of the table,
ΔF / (2π Δ(−cos θ)), at the cell's mid-angle, interpolated log-log between them, continued
below 0.1° as the power law that holds the table's F(0.1°) = 0.0517, and normalised over
the sphere. It has its own b_b/b: a water with it must have b_b/b within 10 % of it
(`Petzold.fractions`, the settings refuse others).

Units: phase functions in 1/sr, angles in rad.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from workers.optics.phases.base import PhaseFunction, register

__all__ = ["Petzold"]

# (θ [deg], F(θ) [1]): Petzold (1972), SIO Ref. 72-78, San Diego harbour stations
# averaged, in the cumulative form of Mobley et al. (1993), Applied Optics 32(36), 7484.
_TABLE = np.array(
    [
        (0.1, 0.051652874), (0.12589, 0.060054522), (0.15849, 0.069821983),
        (0.19953, 0.081192419), (0.25119, 0.094441427), (0.31623, 0.109850371),
        (0.39811, 0.12776086), (0.50119, 0.149388985), (0.63096, 0.174272805),
        (0.79433, 0.201157535), (1.0, 0.231175822), (1.2589, 0.264314723),
        (1.5849, 0.300499368), (1.9953, 0.339426842), (2.5119, 0.380667135),
        (3.1623, 0.423982799), (3.9811, 0.469206739), (5.0119, 0.516141642),
        (6.3096, 0.564696205), (7.9433, 0.614751195), (10.0, 0.665573029),
        (15.0, 0.754988876), (20.0, 0.812516491), (25.0, 0.852406043),
        (30.0, 0.881198952), (35.0, 0.90228374), (40.0, 0.918995596),
        (45.0, 0.932334078), (50.0, 0.943037541), (55.0, 0.951614789),
        (60.0, 0.958533073), (65.0, 0.964237741), (70.0, 0.969014693),
        (75.0, 0.97304086), (80.0, 0.976458835), (85.0, 0.979383181),
        (90.0, 0.981907707), (95.0, 0.984112926), (100.0, 0.98606095),
        (105.0, 0.987801715), (110.0, 0.989374002), (115.0, 0.990816368),
        (120.0, 0.992146354), (125.0, 0.993359088), (130.0, 0.994454409),
        (135.0, 0.995433218), (140.0, 0.99630266), (145.0, 0.997075288),
        (150.0, 0.997761819), (155.0, 0.998375098), (160.0, 0.998913961),
        (165.0, 0.999363808), (170.0, 0.99970854), (175.0, 0.999926263),
        (180.0, 1.0),
    ]
)  # fmt: skip
_SPREAD = 0.1  # relative difference of the water's b_b/b from the table's it accepts


@functools.cache
def _cells():
    """(ln mid-angle, ln β̃ there, power-law slope below the table, normalisation)."""
    theta = np.radians(_TABLE[:, 0])
    cumulative = _TABLE[:, 1]
    beta = np.diff(cumulative) / (2 * np.pi * -np.diff(np.cos(theta)))
    log_mid = np.log(0.5 * (theta[1:] + theta[:-1]))
    # below θ1: β̃1 (θ/θ1)^-m, 2π ∫₀^θ1 β̃ θ dθ = 2π β̃1 θ1² / (2 - m) = F(θ1)
    first = float(np.exp(np.interp(np.log(theta[0]), log_mid, np.log(beta))))
    slope = 2.0 - 2 * np.pi * first * theta[0] ** 2 / cumulative[0]
    return log_mid, np.log(beta), slope, theta[0], first


def _raw(theta):
    log_mid, log_beta, slope, theta1, first = _cells()
    theta = np.asarray(theta, dtype=np.float64)
    inner = np.exp(np.interp(np.log(np.maximum(theta, theta1)), log_mid, log_beta))
    below = first * (np.maximum(theta, 1e-300) / theta1) ** -slope
    return np.where(theta < theta1, below, inner)


@functools.cache
def _norm():
    theta1 = _cells()[3]
    theta = np.geomspace(theta1, np.pi, 400_001)
    inside = np.trapezoid(2 * np.pi * _raw(theta) * np.sin(theta), theta)
    return float(inside + _TABLE[0, 1])


@register
@dataclass(frozen=True, kw_only=True)
class Petzold(PhaseFunction):
    """Petzold's San Diego harbour average, tabulated (no parameter)."""

    name = "petzold"
    fractions = (0.0181 * (1 - _SPREAD), 0.0181 * (1 + _SPREAD))

    @classmethod
    def for_water(cls, *, backscatter_fraction, theta0):
        """The table itself: the water's b_b/b [1] and θ0 [rad] are not used."""
        return cls()

    @property
    def mtf_tail(self):
        """M − 1: D ∝ ψ^-(m-1) from the β̃ ∝ θ^-m core below the table [1]."""
        return _cells()[2] - 1.0

    def value(self, theta):
        """β̃(θ) [1/sr], log-log interpolated, normalised over the sphere."""
        return (_raw(theta) / _norm())[()]
