"""The sea's sections of a scene: the surface (spectrum, grid, conditioning) and the water.

Validated settings only, building nothing: the physics they describe is in
`workers.sea.spectra`, `workers.sea.surface`, `workers.sea.conditioning` and
`workers.optics.water`, and the objects are built from them by `workers.setup.seasetup` (the
spectrum, the cascades, the kriging system) and `workers.setup.builder.scene_setup`. Every
field declares its unit as data (`workers.settings.section.units`). The target's section is
`workers.settings.target`.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from workers.optics.phases.base import PHASE_FUNCTIONS
from workers.optics.water import PRESETS
from workers.sea.cascades import MAX_CASCADES, check_patches
from workers.settings.section import Section, units

__all__ = ["Conditioning", "SurfaceSpec", "Water"]

PositiveFloat = Annotated[float, Field(gt=0.0, allow_inf_nan=False)]

Measurement = Annotated[
    tuple[Annotated[float, Field(allow_inf_nan=False)], ...], Field(min_length=3, max_length=4)
]


class Conditioning(Section):
    """Measured elevations every surface of the scene honours (conditioning by kriging).

    A measurement is of the elevation the renderer sees at (x, y): the sum of the
    cascades' bilinear interpolations. Points lie on the coarsest cascade's patch [0, L)
    in x and y (`workers.setup.seasetup.scene_sea`; a point elsewhere is refused). Sweep files may
    give
    ``file: points.csv`` instead of ``points``; the service reads it (see
    `service.measurements`). See `workers.sea.conditioning`.
    """

    points: tuple[Measurement, ...] | None = Field(
        None,
        max_length=1000,
        description="Measured points [x, y, elevation] or [x, y, elevation, time], time "
        "on the frames' clock (default 0, the first frame), in m, m, m and s; null: no "
        "conditioning.",
        json_schema_extra=units("m, m, m, s"),
    )
    noise: float = Field(
        0.0,
        ge=0.0,
        le=10.0,
        description="Measurement noise standard deviation.",
        json_schema_extra=units("m"),
    )


class SurfaceSpec(Section):
    """Sea surface: the wave spectrum and the periodic grid it is synthesised on."""

    spectrum: Literal["elfouhaily", "phillips", "pierson_moskowitz", "jonswap", "flat"] = Field(
        "elfouhaily",
        description="Directional wave spectrum; `flat` is a mirror-flat sea.",
        json_schema_extra=units("1"),
    )
    wind_speed: float = Field(
        5.0,
        ge=0.5,
        le=30.0,
        description="Wind speed 10 m above the sea, U10.",
        json_schema_extra=units("m/s"),
    )
    wind_direction_deg: float = Field(
        0.0,
        ge=-360.0,
        le=360.0,
        description="Direction the wind blows towards, counter-clockwise from +x (east).",
        json_schema_extra=units("degree"),
    )
    fetch: float = Field(
        1.0e5,
        gt=0.0,
        le=1.0e7,
        description="Fetch, used by `jonswap` only.",
        json_schema_extra=units("m"),
    )
    inverse_wave_age: float = Field(
        0.84,
        ge=0.84,
        le=5.0,
        description="Inverse wave age U10/c_p, used by `elfouhaily` only (0.84: fully "
        "developed sea).",
        json_schema_extra=units("1"),
    )
    grid_size: int = Field(
        256,
        ge=16,
        le=4096,
        description="Points per side of the periodic surface grid.",
        json_schema_extra=units("1"),
    )
    spacing: float | None = Field(
        None,
        ge=1e-4,
        le=10.0,
        description="Grid spacing of the sea's finest cascade; null: the receiver's "
        "footprint span over grid_size, so that the finest patch covers the footprint "
        "(docs/model.md §1).",
        json_schema_extra=units("m"),
    )
    max_elevation: float | None = Field(
        None,
        gt=0.0,
        le=20.0,
        description="Optional rescaling (the paper's knob): max |elevation| over the frames, "
        "on the stored surface grid (around the first frame's footprint). Off by default; it "
        "breaks the spectrum's variance.",
        json_schema_extra=units("m"),
    )
    conditioning: Conditioning = Conditioning()
    coarse_patches: tuple[PositiveFloat, ...] | None = Field(
        None,
        max_length=MAX_CASCADES - 1,
        description="Periodic patches of the coarser cascades of the multi-scale sea, each "
        "sampled by grid_size points, increasing, each at most grid_size/16 times the one "
        "before, the first after the finest grid_size x spacing; null: chosen from the "
        "footprint and the spectrum (docs/model.md §1); []: the finest patch alone.",
        json_schema_extra=units("m"),
    )
    allow_repeat: bool = Field(
        False,
        description="Render even if the receiver's footprint on the sea is wider than the "
        "coarsest cascade's periodic patch, so that the same waves repeat inside the "
        "image; refused otherwise.",
        json_schema_extra=units("1"),
    )

    @model_validator(mode="after")
    def _even_grid(self) -> SurfaceSpec:
        if self.grid_size % 2:
            raise ValueError("grid_size must be even (FFT synthesis)")
        return self

    @model_validator(mode="after")
    def _cascades(self) -> SurfaceSpec:
        if self.coarse_patches and self.spacing is not None:
            try:
                check_patches(
                    grid_size=self.grid_size,
                    patches=[self.grid_size * self.spacing, *self.coarse_patches],
                )
            except ValueError as error:
                raise ValueError(
                    f"coarse_patches: {error} (patch 0 is grid_size x spacing)"
                ) from None
        return self

    @model_validator(mode="after")
    def _conditioning(self) -> SurfaceSpec:
        if not self.conditioning.points:
            return self
        if self.spectrum == "flat":
            raise ValueError("conditioning: a flat sea cannot honour measured elevations")
        if self.max_elevation is not None:
            raise ValueError(
                "conditioning: max_elevation would rescale the measured elevations away; "
                "leave it null"
            )
        return self

    def finest_spacing(self, span: float) -> float:
        """`spacing`, or by default the footprint's span over `grid_size` [m].

        Parameters
        ----------
        span : float
            Longest chord of the receiver's footprint along x or y [m] (`footprint_span`).
        """
        if self.spacing is not None:
            return self.spacing
        if not math.isfinite(span):
            raise ValueError(
                "surface.spacing: the footprint reaches the horizon, so the default spacing "
                "(footprint over grid_size) is undefined; give surface.spacing"
            )
        return span / self.grid_size


class Water(Section):
    """Inherent optical properties of the water column.

    A `preset` (Petzold 1972, via Mobley 1994, table 3.10) gives absorption, scattering and
    backscattering; any of the three given explicitly overrides it. With ``preset: null``
    all three are required.
    """

    preset: Literal["clear_ocean", "coastal", "turbid_harbour"] | None = Field(
        "coastal",
        description="Petzold water type, or null for explicit coefficients.",
        json_schema_extra=units("1"),
    )
    absorption: float | None = Field(
        None,
        ge=0.0,
        le=20.0,
        description="Absorption coefficient a.",
        json_schema_extra=units("1/m"),
    )
    scattering: float | None = Field(
        None,
        ge=0.0,
        le=50.0,
        description="Scattering coefficient b.",
        json_schema_extra=units("1/m"),
    )
    backscatter: float | None = Field(
        None,
        ge=0.0,
        le=5.0,
        description="Backscattering coefficient b_b.",
        json_schema_extra=units("1/m"),
    )
    phase_function: str = Field(
        "fournier_forand",
        description="The fast renderer's phase function, a registered one "
        "(`workers.optics.phases`, docs/model.md): `fournier_forand` (the forward half of "
        "the Fournier-Forand function fitted to b_b/b, the one the Monte Carlo renderer "
        "samples by default; needs 0.002 <= b_b/b <= 0.095), `paper` "
        "(s ∝ θ^-3/2 (θ0²+θ²)^-1/2, θ0 = theta0), `wells` (closed-form MTF exponent) "
        "or any other registered one.",
        json_schema_extra={**units("1"), "enum": sorted(PHASE_FUNCTIONS)},
    )
    theta0: float = Field(
        0.12,
        gt=0.0,
        le=1.0,
        description="Phase-function angular scale θ0 (paper: 0.12) of the `paper` and "
        "`wells` phase functions (and of the Monte Carlo's `paper`); the default "
        "`fournier_forand` has none (it is fitted to b_b/b) and ignores it.",
        json_schema_extra=units("rad"),
    )
    refractive_index: float = Field(
        1.34,
        ge=1.0,
        le=2.0,
        description="Refractive index of sea water (paper: 1.34).",
        json_schema_extra=units("1"),
    )
    psf_truncation: float | None = Field(
        None,
        ge=0.5,
        lt=1.0,
        description="Share of the scattered light at which the point-spread function is "
        "cut off, light scattered further being dropped (the paper cuts at 0.95); null: "
        "the whole function.",
        json_schema_extra=units("1"),
    )

    @field_validator("phase_function")
    @classmethod
    def _registered(cls, name: str) -> str:
        if name not in PHASE_FUNCTIONS:
            choices = ", ".join(sorted(PHASE_FUNCTIONS))
            raise ValueError(f"not a registered phase function; choose from {choices}")
        return name

    @model_validator(mode="after")
    def _complete(self) -> Water:
        if self.preset is None:
            missing = [
                name
                for name in ("absorption", "scattering", "backscatter")
                if getattr(self, name) is None
            ]
            if missing:
                raise ValueError(f"with preset null, set {', '.join(missing)} explicitly")
        coefficients = self.coefficients
        if coefficients["backscatter"] > coefficients["scattering"]:
            raise ValueError(
                f"backscatter {coefficients['backscatter']} 1/m exceeds scattering "
                f"{coefficients['scattering']} 1/m (backscattering is part of scattering)"
            )
        return self

    @property
    def coefficients(self) -> dict[str, float]:
        """Absorption, scattering and backscatter [1/m]: the preset with overrides."""
        values = dict(PRESETS[self.preset]) if self.preset is not None else {}
        for name in ("absorption", "scattering", "backscatter"):
            if getattr(self, name) is not None:
                values[name] = getattr(self, name)
        return values
