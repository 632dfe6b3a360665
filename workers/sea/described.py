"""The sea a surface section describes, as plain values: its wave spectrum and its patches.

The settings (`workers.settings.sea.SurfaceSpec`) are read by attribute, never imported: the
scene's validation calls `surface_patches` to check the cascades against the footprint
without building the sea, and the setup (`workers.setup.seasetup.surface_sea`) builds the
cascades from the same values.
"""

from __future__ import annotations

import numpy as np

from workers.sea import spectra
from workers.sea.cascades import check_patches, default_patches

__all__ = ["surface_patches", "wave_spectrum"]


def wave_spectrum(surface) -> spectra.Spectrum | None:
    """The wave spectrum a surface section describes (None for a flat sea).

    Parameters
    ----------
    surface : workers.settings.sea.SurfaceSpec
        The settings: spectrum name, wind speed [m/s] and direction [degree], fetch [m]
        (JONSWAP), inverse wave age [1] (Elfouhaily).
    """
    if surface.spectrum == "flat":
        return None
    common = {
        "wind_speed": surface.wind_speed,
        "wind_direction": np.radians(surface.wind_direction_deg),
    }
    if surface.spectrum == "elfouhaily":
        return spectra.Elfouhaily(**common, inverse_wave_age=surface.inverse_wave_age)
    if surface.spectrum == "phillips":
        return spectra.Phillips(**common)
    if surface.spectrum == "pierson_moskowitz":
        return spectra.PiersonMoskowitz(**common)
    return spectra.Jonswap(**common, fetch=surface.fetch)


def surface_patches(surface, *, span: float) -> tuple[float, ...] | None:
    """The patches of the sea's cascades a surface section describes, m (None for a flat sea).

    Parameters
    ----------
    surface : workers.settings.sea.SurfaceSpec
        The settings: spectrum, `grid_size`, `spacing`, `coarse_patches`.
    span : float
        Longest chord of the receiver's footprint along x or y [m]
        (`workers.settings.scene.footprint_span`), for the default spacing and patches.

    Returns
    -------
    tuple of float or None
        The patches, finest first, m, checked (`workers.sea.cascades.check_patches`).

    Raises
    ------
    ValueError
        For a default spacing at a footprint that reaches the horizon, or
        `coarse_patches` that do not fit the finest patch (naming the field).
    """
    spectrum = wave_spectrum(surface)
    if spectrum is None:
        return None
    spacing = surface.finest_spacing(span)
    if surface.coarse_patches is None:
        patches = default_patches(
            spectrum, grid_size=surface.grid_size, spacing=spacing, span=span
        )
    else:
        patches = (surface.grid_size * spacing, *surface.coarse_patches)
    patches = tuple(patches)
    try:
        check_patches(grid_size=surface.grid_size, patches=patches)
    except ValueError as error:
        raise ValueError(
            f"surface.coarse_patches: {error} (patch 0 is grid_size x spacing)"
        ) from None
    return patches
