"""Phase functions as plug-ins: the interface both renderers use, and the registry by name.

A phase function is one `PhaseFunction` subclass in its own module of
`workers.optics.phases`, registered by name with `register` (the package imports every
module, so the settings' choices and both renderers see it). It is built for a water
(`PhaseFunction.for_water`, from the water's b_b/b and θ0) and gives its value on the
sphere (`PhaseFunction.value`); everything else derives from that value by shared code
here, which a function may override with a closed form where it has one:

- the fast renderer's small-angle form (`PhaseFunction.small_angle`), Wells' MTF exponent
  D(ψ) (`PhaseFunction.mtf_exponent`, `workers.optics.hankel`) and β(π)/b_b
  (`PhaseFunction.backscatter_pi_per_backscatter`);
- the Monte Carlo renderer's sampling table (`PhaseFunction.table`);
- β̃(π) and the backscatter fraction b_b/b (`PhaseFunction.backscatter_pi`,
  `PhaseFunction.backscatter_fraction`).

Units: phase functions in 1/sr (normalised over the sphere, 4π sr), angles in rad.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy import integrate

from workers.optics.hankel import exponent_table, tabled_exponent

__all__ = [
    "BETA_PI_PER_BACKSCATTER",
    "PHASE_FUNCTIONS",
    "PhaseFunction",
    "PhaseTable",
    "phase_named",
    "register",
]

BETA_PI_PER_BACKSCATTER = 0.174
"""Ratio β(π)/b_b [1/sr] of Petzold's average particle phase function.

Mobley (1994), Table 3.10, tabulates that phase function with β̃(180°) = 3.18e-3 sr⁻¹
and backscatter fraction b̃_b = 0.0183, so β(π) = 0.174 b_b. This is 1.09 times the value
1/(2π) = 0.159 sr⁻¹ that a phase function flat over the backward hemisphere would give.
"""

_TABLE_ANGLES = 4096  # angles of the tabulated phase function, log-spaced in θ
_TABLE_QUANTILES = 8192  # equal-probability cells of the sampling table
_THETA_MIN = 1e-6  # smallest tabulated angle [rad]; the cone below holds < 1e-6 of b

PHASE_FUNCTIONS: dict[str, type[PhaseFunction]] = {}
"""The registered phase functions by name (`register`)."""


def register(function: type[PhaseFunction]) -> type[PhaseFunction]:
    """Class decorator: register the phase function `function` under its ``name``."""
    PHASE_FUNCTIONS[function.name] = function
    return function


def phase_named(name: str) -> type[PhaseFunction]:
    """The registered phase function called `name` (`KeyError` naming the choices if none)."""
    try:
        return PHASE_FUNCTIONS[name]
    except KeyError:
        choices = ", ".join(sorted(PHASE_FUNCTIONS))
        raise KeyError(f"unknown phase function {name!r}; choose from {choices}") from None


@dataclass(frozen=True)
class PhaseTable:
    r"""A phase function tabulated for the photon kernels.

    Attributes
    ----------
    log_theta0 : float
        ln of the first tabulated angle [ln rad].
    log_step : float
        Step of the angle table in ln θ [1].
    values : ndarray
        :math:`\tilde\beta` at θ = exp(log_theta0 + i·log_step) [1/sr], float64.
    quantiles : ndarray
        Scattering angles [rad] at cumulative probabilities i/(len − 1) (sampling by
        linear interpolation of the inverse cumulative), float64.
    backscatter_pi : float
        :math:`\tilde\beta(\pi)` [1/sr].
    backscatter_fraction : float
        The table's share of scattering beyond 90° [1].
    """

    log_theta0: float
    log_step: float
    values: np.ndarray
    quantiles: np.ndarray
    backscatter_pi: float
    backscatter_fraction: float


@dataclass(frozen=True, kw_only=True)
class PhaseFunction:
    """A phase function of sea water, built for one water (`for_water`).

    Class attributes: ``name`` (its registered name), ``spherical`` (whether it is defined
    over the whole sphere, so that the Monte Carlo renderer can sample it), ``fractions``
    (the closed range of the water's b_b/b it can be built for, None: any) and
    ``mtf_tail`` (the exponent a of D(ψ) ∝ ψ^-a beyond the table of `mtf_exponent`; 1 for
    a function finite at θ = 0), ``kinks`` (angles [rad] where the function jumps, added
    to the nodes of the sampling table's cumulative so that no draw crosses them) and
    ``transport_gains`` (True where the fast renderer's small-angle spread of the function
    misses transport's gated water return by more than 5 % in any water, so that its gates
    always take the Monte Carlo's gains, `workers.setup.builder.time_resolved`).
    """

    name: ClassVar[str]
    spherical: ClassVar[bool] = True
    fractions: ClassVar[tuple[float, float] | None] = None
    mtf_tail: ClassVar[float] = 1.0
    kinks: ClassVar[tuple[float, ...]] = ()
    transport_gains: ClassVar[bool] = False

    @classmethod
    def for_water(cls, *, backscatter_fraction: float, theta0: float) -> PhaseFunction:
        """The function built for a water of backscatter fraction b_b/b [1] and scale θ0 [rad]."""
        raise NotImplementedError

    def value(self, theta):
        """The phase function β̃(θ) at angles θ in (0, π] [rad], ∫ over the sphere = 1 [1/sr]."""
        raise NotImplementedError

    def small_angle(self):
        """The small-angle form Wells' spread transforms, and the end of its support.

        Returns
        -------
        function : callable
            s(θ) for an ndarray of θ [rad] [1/sr] in the small-angle measure θ dθ (any
            normalisation). By default the forward half, β̃ sin θ / θ, so that θ dθ
            integrates the sphere's sin θ dθ.
        theta_max : float
            Upper end of its support [rad] (π/2 by default: forward scattering only, the
            rate b_f = b − b_b).
        """

        def forward(theta):
            return self.value(theta) * np.sin(theta) / theta

        return forward, 0.5 * np.pi

    def mtf_exponent(self, psi):
        """Wells' MTF exponent D(ψ) of `small_angle` [1] at ψ [cycles/rad] (tabulated once).

        See `workers.optics.hankel.hankel_mtf_exponent`; beyond the table D ∝ ψ^-mtf_tail.
        """
        return tabled_exponent(_exponent_table(self), psi, tail=self.mtf_tail)

    def backscatter_pi(self) -> float:
        """β̃(π) [1/sr]."""
        return float(self.value(np.pi))

    def backscatter_fraction(self) -> float:
        """b_b/b = 2π ∫ β̃ sin θ dθ over [π/2, π] [1] (adaptive quadrature)."""
        back, _ = integrate.quad(
            lambda t: 2 * np.pi * self.value(t) * np.sin(t),
            0.5 * np.pi,
            np.pi,
            epsabs=0,
            limit=200,
        )
        return back

    def backscatter_pi_per_backscatter(self) -> float:
        """β(π)/b_b = β̃(π)/(b_b/b) [1/sr]: the fast renderer's gated water backscatter."""
        return self.backscatter_pi() / self.backscatter_fraction()

    def cumulative(self, theta, values):
        """Share of scattering into angles below 0 and each θ [1], for `table`.

        Parameters
        ----------
        theta : ndarray
            Angles log-spaced from 1e-6 rad to π [rad].
        values : ndarray
            ``self.value(theta)`` [1/sr].

        Returns
        -------
        ndarray
            len(theta) + 1 non-decreasing values, 0 first, 1 last: a trapezoid sum in ln θ,
            the cone below θ[0] continued as the power law through the first two samples.
        """
        weights = 2 * np.pi * values * np.sin(theta) * theta  # per unit ln θ
        steps = 0.5 * (weights[1:] + weights[:-1]) * np.diff(np.log(theta))
        power = np.log(weights[1] / weights[0]) / np.log(theta[1] / theta[0])
        first = weights[0] / power
        cumulative = np.concatenate([[0.0], first + np.concatenate([[0.0], np.cumsum(steps)])])
        return cumulative / cumulative[-1]

    def table(self) -> PhaseTable:
        """The table the Monte Carlo photons sample (cached per function).

        Returns
        -------
        PhaseTable
            Values on 4096 angles log-spaced from 1e-6 rad to π; the inverse cumulative
            (`cumulative`) on 8193 probabilities.
        """
        return _table(self)


@functools.lru_cache(maxsize=64)
def _exponent_table(phase: PhaseFunction):
    return exponent_table(*phase.small_angle())


@functools.lru_cache(maxsize=64)
def _table(phase: PhaseFunction) -> PhaseTable:
    theta = np.geomspace(_THETA_MIN, np.pi, _TABLE_ANGLES)
    values = phase.value(theta)
    nodes = np.union1d(theta, phase.kinks)  # the cumulative's nodes: the kinks added
    cumulative = phase.cumulative(nodes, phase.value(nodes))
    angles = np.concatenate([[0.0], nodes])
    cumulative = np.maximum.accumulate(cumulative)
    probabilities = np.linspace(0.0, 1.0, _TABLE_QUANTILES + 1)
    # no angle beyond where the cumulative first reaches its top (a function that is 0
    # over the backward hemisphere: `workers.optics.phases.paper.Paper` with b_b = 0)
    top = angles[np.searchsorted(cumulative, cumulative[-1])]
    quantiles = np.minimum(np.interp(probabilities, cumulative, angles), top)
    back = 1.0 - float(np.interp(0.5 * np.pi, angles, cumulative))
    return PhaseTable(
        log_theta0=float(np.log(theta[0])),
        log_step=float(np.log(theta[1] / theta[0])),
        values=values.astype(np.float64),
        quantiles=quantiles,
        backscatter_pi=float(values[-1]),
        backscatter_fraction=back,
    )
