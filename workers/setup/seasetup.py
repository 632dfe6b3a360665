"""The sea's setup layer: the objects a scene's surface section describes.

The configuration classes (`workers.settings.sea.SurfaceSpec`, `workers.settings.scene.Scene`)
hold validated settings and build nothing; the sea's cascades and the kriging system of the
measured elevations are built here, from them, by the scene's setup
(`workers.setup.builder.scene_setup`, cached by the scene). The scene's validation checks the
cascades' patches against the footprint with the plain values of `workers.sea.described`,
building nothing.
"""

from __future__ import annotations

from workers.sea.cascades import Sea
from workers.sea.conditioning import Kriging, kriging
from workers.sea.described import surface_patches, wave_spectrum
from workers.settings.sea import SurfaceSpec
from workers.settings.section import SceneError

__all__ = ["scene_sea", "surface_kriging", "surface_sea"]


def surface_sea(surface: SurfaceSpec, *, span: float) -> Sea | None:
    """The cascades of the sea a surface section describes (None for a flat sea).

    Parameters
    ----------
    surface : workers.settings.sea.SurfaceSpec
        The settings.
    span : float
        Longest chord of the receiver's footprint along x or y [m]
        (`workers.settings.scene.footprint_span`), for the default spacing and patches.

    Raises
    ------
    ValueError
        As `workers.sea.described.surface_patches`, naming the field.
    """
    patches = surface_patches(surface, span=span)
    if patches is None:
        return None
    return Sea(spectrum=wave_spectrum(surface), grid_size=surface.grid_size, patches=patches)


def scene_sea(scene) -> Sea | None:
    """The cascades of a scene's sea: `surface_sea` of its surface at its footprint.

    Parameters
    ----------
    scene : workers.settings.scene.Scene
        The scene (its `surface` section and `footprint()`, m).
    """
    return surface_sea(scene.surface, span=scene.footprint())


def surface_kriging(surface: SurfaceSpec, sea: Sea | None) -> Kriging | None:
    """The kriging system of a surface's measured elevations on `sea`, or None without.

    Cached (`workers.sea.conditioning.kriging`). Validation checks the points alone
    (`workers.sea.conditioning.check_points`); whether their system is regular is known once
    it is built, here, to render.

    Parameters
    ----------
    surface : workers.settings.sea.SurfaceSpec
        The settings: `conditioning.points` (m, m, m[, s]) and `conditioning.noise` (m).
    sea : workers.sea.cascades.Sea or None
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
