"""How light is carried through the water: the scene's `Transport` and its phase functions.

Two renderers read a scene. ``small_angle`` (the default, `workers.render`) spreads light
with Wells' small-angle transfer function and puts every return at the depth it came from.
``monte_carlo`` (`workers.montecarlo.renderer`) follows photons: multiple scattering with a full
3-D phase function, absorption, the target's 3-D Lambertian surface, and range gating by
each path's own time of flight. The phase function it samples is a registered one
(`workers.optics.phases`) defined over the whole sphere.

Units: coefficients in 1/m.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator

from workers.optics.phases.base import PHASE_FUNCTIONS
from workers.settings.section import Section, units

__all__ = ["SPHERICAL", "Transport"]

SPHERICAL = sorted(name for name, f in PHASE_FUNCTIONS.items() if f.spherical)
"""Names of the registered phase functions the Monte Carlo renderer can sample."""


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
    phase_function: str = Field(
        "fournier_forand",
        description="Monte Carlo only: a registered phase function defined over the sphere "
        "(`workers.optics.phases`, docs/model.md): `fournier_forand` with its two "
        "parameters fitted to the water's backscatter fraction b_b/b and β(π) = 0.174 b_b "
        "(the fast renderer's); `paper`, the paper's s(θ) with the water's theta0 forward, "
        "the water's b_b/b and β(π) = 0.174 b_b backward; or any other registered one. "
        "Set it to `water.phase_function` for the water the fast renderer renders (whose "
        "gains from transport, where it takes them, are of the water's own function).",
        json_schema_extra={**units("1"), "enum": SPHERICAL},
    )
    max_scattering: int | None = Field(
        None,
        ge=1,
        le=10_000,
        description="Monte Carlo only: most scattering events a photon's path may hold "
        "(1: single scattering); null: all.",
        json_schema_extra=units("1"),
    )

    @field_validator("phase_function")
    @classmethod
    def _sampled(cls, name: str) -> str:
        if name not in SPHERICAL:
            why = "defined at small angles only" if name in PHASE_FUNCTIONS else "not registered"
            raise ValueError(
                f"{name!r} is {why}: the Monte Carlo renderer samples a phase function over "
                f"the sphere; choose from {', '.join(SPHERICAL)}"
            )
        return name
