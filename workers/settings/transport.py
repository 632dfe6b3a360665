"""How light is carried through the water: the scene's `Transport` and its phase functions.

Two renderers read a scene. ``small_angle`` (the default, `workers.render`) spreads light
with Wells' small-angle transfer function and puts every return at the depth it came from.
``monte_carlo`` (`workers.montecarlo.renderer`) follows photons: multiple scattering with a full
3-D phase function, absorption, the target's 3-D Lambertian surface, and range gating by
each path's own time of flight. The phase functions it samples live here, as tables built
once per water (`phase_table`).

Units: coefficients in 1/m, phase functions in 1/sr (normalised over the sphere, 4π sr),
angles in rad.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import Field

from workers.optics.phase import fit_fournier_forand, fournier_forand, fournier_forand_cumulative
from workers.optics.water import paper_phase_function
from workers.settings.section import Section, units

__all__ = [
    "PhaseTable",
    "Transport",
    "paper_phase_function_3d",
    "phase_table",
]

_TABLE_ANGLES = 4096  # angles of the tabulated phase function, log-spaced in θ
_TABLE_QUANTILES = 8192  # equal-probability cells of the sampling table
_THETA_MIN = 1e-6  # smallest tabulated angle [rad]; the cone below holds < 1e-6 of b


class Transport(Section):
    """Which renderer carries the light through the water, and its Monte Carlo settings."""

    method: Literal["small_angle", "monte_carlo"] = Field(
        "small_angle",
        description="`small_angle`: Wells' small-angle spread, fast (docs/model.md §4); "
        "`monte_carlo`: photon transport with multiple scattering and gating by each "
        "path's time of flight (docs/model.md §9), the reference the fast renderer is held to.",
        json_schema_extra=units("1"),
    )
    photons: int = Field(
        1_000_000,
        ge=1_000,
        le=1_000_000_000,
        description="Monte Carlo only: photons launched per frame, split into `batches` "
        "(rounded up to a multiple of them).",
        json_schema_extra=units("1"),
    )
    batches: int = Field(
        16,
        ge=4,
        le=1024,
        description="Monte Carlo only: independent batches of photons; the spread of their "
        "images gives the stored standard error.",
        json_schema_extra=units("1"),
    )
    phase_function: Literal["fournier_forand", "paper"] = Field(
        "fournier_forand",
        description="Monte Carlo only: `fournier_forand` with its two parameters fitted to "
        "the water's backscatter fraction b_b/b and β(π) = 0.174 b_b (the fast renderer's); "
        "or `paper`, the paper's s(θ) with the water's theta0, normalised over the sphere.",
        json_schema_extra=units("1"),
    )
    max_scattering: int | None = Field(
        None,
        ge=1,
        le=10_000,
        description="Monte Carlo only: most scattering events a photon's path may hold "
        "(1: single scattering); null: all.",
        json_schema_extra=units("1"),
    )


def paper_phase_function_3d(theta, *, theta0):
    r"""The paper's small-angle s(θ), normalised as a phase function over the sphere [1/sr].

    Parameters
    ----------
    theta : float or array_like
        Scattering angle θ in (0, π] [rad].
    theta0 : float
        Angular scale θ0 [rad] (paper: 0.12).

    Returns
    -------
    float or ndarray
        :math:`s(\theta)/(2\pi\int_0^\pi s\sin\theta\,d\theta)`: the shape of
        `workers.optics.water.paper_phase_function` with the 3-D measure sin θ dθ in place of
        the small-angle θ dθ. Its backscatter is its own, not the water's b_b.
    """
    return np.asarray(paper_phase_function(theta, theta0=theta0)) / _paper_norm(theta0)


@functools.lru_cache(maxsize=16)
def _paper_norm(theta0: float) -> float:
    theta = np.geomspace(_THETA_MIN * 1e-3, np.pi, 200_001)
    s = paper_phase_function(theta, theta0=theta0) * np.sin(theta)
    return float(2 * np.pi * np.trapezoid(s, theta) + 2 * np.pi * s[0] * theta[0] / 1.5)


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


@functools.lru_cache(maxsize=64)
def phase_table(
    kind: str, *, backscatter_fraction: float | None = None, theta0: float | None = None
) -> PhaseTable:
    """The tabulated phase function a scene's photons sample (cached).

    Parameters
    ----------
    kind : {"fournier_forand", "paper"}
        `Transport.phase_function`.
    backscatter_fraction : float, optional
        b_b/b of the water [1] (``fournier_forand``: `fit_fournier_forand`).
    theta0 : float, optional
        The paper's angular scale [rad] (``paper``).

    Returns
    -------
    PhaseTable
        Values on 4096 angles log-spaced from 1e-6 rad to π; the inverse cumulative on
        8193 probabilities. The cumulative is exact for Fournier–Forand
        (`fournier_forand_cumulative`) and a trapezoid sum in ln θ for the paper's.
    """
    theta = np.geomspace(_THETA_MIN, np.pi, _TABLE_ANGLES)
    if kind == "fournier_forand":
        n, mu = fit_fournier_forand(float(backscatter_fraction))
        values = fournier_forand(theta, n=n, mu=mu)
        cumulative = fournier_forand_cumulative(theta, n=n, mu=mu)
        cumulative = np.concatenate([[0.0], cumulative])
    elif kind == "paper":
        values = paper_phase_function_3d(theta, theta0=theta0)
        weights = 2 * np.pi * values * np.sin(theta) * theta  # per unit ln θ
        steps = 0.5 * (weights[1:] + weights[:-1]) * np.diff(np.log(theta))
        first = 2 * np.pi * values[0] * theta[0] ** 2 / 1.5  # ∫ θ^(1/2) below θ_min
        cumulative = np.concatenate([[0.0], first + np.concatenate([[0.0], np.cumsum(steps)])])
        cumulative /= cumulative[-1]
    else:
        raise ValueError(f"unknown phase function {kind!r}")
    angles = np.concatenate([[0.0], theta])
    cumulative = np.maximum.accumulate(cumulative)
    probabilities = np.linspace(0.0, 1.0, _TABLE_QUANTILES + 1)
    quantiles = np.interp(probabilities, cumulative, angles)
    back = 1.0 - float(np.interp(0.5 * np.pi, angles, cumulative))
    return PhaseTable(
        log_theta0=float(np.log(theta[0])),
        log_step=float(np.log(theta[1] / theta[0])),
        values=values.astype(np.float64),
        quantiles=quantiles,
        backscatter_pi=float(values[-1]),
        backscatter_fraction=back,
    )
