"""The sea's setup layer: the objects a scene's surface section describes.

The configuration classes (`workers.sea.SurfaceSpec`, `workers.scene.Scene`) hold validated
settings and build nothing; the wave spectrum, the sea's cascades and the kriging system of
the measured elevations are built here, from them, by the scene's setup
(`workers.sensor.scene_setup`, cached by the scene) and by the validation that must build
them to check a scene (the cascades' patches against the footprint).
"""

from __future__ import annotations

import numpy as np

from workers import spectra
from workers.cascades import Sea, default_patches
from workers.conditioning import Kriging, kriging
from workers.sea import SurfaceSpec
from workers.section import SceneError

__all__ = ["scene_sea", "surface_kriging", "surface_sea", "wave_spectrum"]


def wave_spectrum(surface: SurfaceSpec) -> spectra.Spectrum | None:
    """The wave spectrum a surface section describes (None for a flat sea).

    Parameters
    ----------
    surface : workers.sea.SurfaceSpec
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


def surface_sea(surface: SurfaceSpec, *, span: float) -> Sea | None:
    """The cascades of the sea a surface section describes (None for a flat sea).

    Parameters
    ----------
    surface : workers.sea.SurfaceSpec
        The settings.
    span : float
        Longest chord of the receiver's footprint along x or y [m]
        (`workers.scene.footprint_span`), for the default spacing and patches.

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
    try:
        return Sea(spectrum=spectrum, grid_size=surface.grid_size, patches=tuple(patches))
    except ValueError as error:
        raise ValueError(
            f"surface.coarse_patches: {error} (patch 0 is grid_size x spacing)"
        ) from None


def scene_sea(scene) -> Sea | None:
    """The cascades of a scene's sea: `surface_sea` of its surface at its footprint.

    Parameters
    ----------
    scene : workers.scene.Scene
        The scene (its `surface` section and `footprint()`, m).
    """
    return surface_sea(scene.surface, span=scene.footprint())


def surface_kriging(surface: SurfaceSpec, sea: Sea | None) -> Kriging | None:
    """The kriging system of a surface's measured elevations on `sea`, or None without.

    Cached (`workers.conditioning.kriging`). Validation checks the points alone
    (`workers.conditioning.check_points`); whether their system is regular is known once
    it is built, here, to render.

    Parameters
    ----------
    surface : workers.sea.SurfaceSpec
        The settings: `conditioning.points` (m, m, m[, s]) and `conditioning.noise` (m).
    sea : workers.cascades.Sea or None
        The cascades the points condition (`surface_sea`).

    Raises
    ------
    SceneError
        For a singular or ill-conditioned system, naming ``surface.conditioning.points``.
    """
    data = surface.conditioning
    if not data.points:
        return None
    try:
        return kriging(sea, points=data.points, noise=data.noise)
    except ValueError as error:
        raise SceneError(f"surface.conditioning.points: {error}") from None
