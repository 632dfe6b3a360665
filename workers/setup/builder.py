"""The scene compiled once: `scene_setup` reads a `Scene` and builds its `Setup`.

With `workers.setup.seasetup` (the sea's cascades and kriging system), the one place
below `workers.render` that reads a scene's settings; every angle is converted to
radians here. The model is in ``docs/model.md``.
"""

from __future__ import annotations

import functools
import itertools
import math
from dataclasses import replace

import numpy as np

from workers.optics.fresnel import fresnel_reflectance
from workers.optics.phases.base import phase_named
from workers.optics.water import (
    WaterOptics,
    slab_backscatter_centroid,
    slab_backscatter_reflectance,
)
from workers.receiver.radiometry import photoelectrons_per_signal, pixel_solid_angle
from workers.settings.scene import Scene
from workers.setup.compiled import Photons, Setup
from workers.setup.geometry import PinholeCamera, flat_sea_point
from workers.setup.seasetup import scene_sea, surface_kriging

__all__ = [
    "BACKSCATTER_DEPTH",
    "CALIBRATION_PHOTONS",
    "SLAB",
    "TABULATION",
    "receiver_terms",
    "scene_setup",
    "slab_setups",
    "time_resolved",
]

BACKSCATTER_DEPTH = 0.1
"""Smallest b_b z_max [1] (z_max the deepest gate's bottom) at which the fast renderer takes
transport's gains (`time_resolved`): the share of the return that Wells' attenuation loses
to backscatter over the round trip, 1 − e^(−2 b_b z), is then 18 % or more (coastal water
to 15.2 m: 0.043, no gains; the paper's Example 4 to 9 m: 0.139; turbid harbour water
from 9.8 m: 0.34)."""

SLAB = 1.0
"""Thickness of the depth slabs the gains are tabulated on [m]."""

CALIBRATION_PHOTONS = 2_000_000
"""Photons of the Monte Carlo run that tabulates a water's slab gains."""

TABULATION = {
    "receiver": {"pixels": 32, "field_of_view_deg": 6.7},
    "platform": {"altitude": 34.0, "nadir_deg": 0.0},
    "radiometry": {"mode": "normalised", "white_plane_photons": 0.0},
    "surface": {"spectrum": "flat"},
    "target": {"shape": "none"},
}
"""The view the time-resolved gains are tabulated in, whatever the scene's (`_slab_scene`)."""


def time_resolved(scene: Scene) -> bool:
    """Whether the fast renderer takes `scene`'s gate returns with time-resolved gains.

    Parameters
    ----------
    scene : Scene
        The scene.

    Returns
    -------
    bool
        True where `workers.render` takes the gate returns of `scene` with the gains
        (`workers.calibration.timegains.calibrated`) of its water (`slab_setups`): for
        the fast renderer (``transport.method: small_angle``) where the water's
        phase function is one the Monte Carlo renderer can sample (defined over the
        sphere: the gains are transport's return of the same water over the fast
        renderer's; ``transport.phase_function``, the Monte Carlo's own choice, plays no
        part), the water backscatters (b_b > 0), and either b_b z_max is at least
        `BACKSCATTER_DEPTH` (z_max the deepest gate's bottom) or
        the phase function asks for them in any water
        (`workers.optics.phases.base.PhaseFunction.transport_gains`: ``paper``).
    """
    phase = phase_named(scene.water.phase_function)
    if scene.transport.method != "small_angle" or not phase.spherical:
        return False
    if scene.water.coefficients["backscatter"] <= 0.0:
        return False  # no water return to gain
    if phase.transport_gains:
        return True
    deepest = max(bottom for _, bottom in scene.receiver.gate_depths)
    return scene.water.coefficients["backscatter"] * deepest >= BACKSCATTER_DEPTH


def _slab_scene(scene: Scene) -> Scene:
    """`scene`'s water alone, for its slab gains, in the tabulation's own geometry.

    `SLAB` gates from the surface to below the deepest gate, under `TABULATION`'s view (the
    transport reference's: 32 px over 6.7° from 34 m at nadir, the default laser, a flat
    sea, no target, one frame), rendered by the fast renderer and by transport of the same
    water (its phase function sampled by the Monte Carlo renderer); of the scene only its
    water. The gains are taken as the water's, per depth:
    the scenes of a sweep over the platform, the view, the sea or the target share one
    tabulation per water (a random design over altitude would otherwise pay one a sample).
    """
    deepest = max(bottom for _, bottom in scene.receiver.gate_depths)
    edges = SLAB * np.arange(math.ceil(deepest / SLAB) + 1)
    gates = [[float(top), float(bottom)] for top, bottom in itertools.pairwise(edges)]
    return Scene.model_validate(
        {
            **TABULATION,
            "water": scene.water.model_dump(),
            "receiver": {**TABULATION["receiver"], "gates": gates},
            "transport": {"phase_function": scene.water.phase_function},
        }
    )


def slab_setups(scene: Scene) -> tuple[Setup, Setup]:
    """The setups that tabulate the gains of `scene`'s water: fast, then transport.

    Parameters
    ----------
    scene : Scene
        A scene where `time_resolved`.

    Returns
    -------
    fast, transport : Setup
        `_slab_scene` compiled for the fast renderer and for the Monte Carlo renderer
        (`CALIBRATION_PHOTONS`), the same objects for every scene of the water (cached:
        `workers.calibration.timegains.slab_gains` keeps its gains by them).
    """
    return _slab_setups(_slab_scene(scene))


@functools.lru_cache(maxsize=16)
def _slab_setups(slabs: Scene) -> tuple[Setup, Setup]:
    """`slab_setups` of a `_slab_scene` (cached by it)."""
    transport = slabs.transport.model_copy(
        update={"method": "monte_carlo", "photons": CALIBRATION_PHOTONS}
    )
    return scene_setup(slabs), scene_setup(slabs.model_copy(update={"transport": transport}))


@functools.lru_cache(maxsize=32)
def scene_setup(scene: Scene) -> Setup:
    """What every frame of every sample of a scene shares (cached by the scene, hashable).

    Without transport's gains (`time_resolved`), which `workers.render` applies.
    """
    w, p, r, laser = scene.water, scene.platform, scene.receiver, scene.laser
    coefficients = w.coefficients
    coefficients.update(
        phase_function=w.phase_function, theta0=w.theta0, refractive_index=w.refractive_index
    )
    water = WaterOptics(**coefficients)
    gates = r.gate_depths
    nadir, azimuth = float(np.radians(p.nadir_deg)), float(np.radians(p.azimuth_deg))
    refracted_nadir = float(np.arcsin(np.sin(nadir) / w.refractive_index))
    secant = 1.0 / np.cos(refracted_nadir)
    references = tuple(
        float(
            slab_backscatter_centroid(
                diffuse_attenuation=water.diffuse_attenuation * secant, top=top, bottom=bottom
            )
        )
        for top, bottom in gates
    )
    # Seen at an angle ϑ in the water, a slab's volume return grows as 1/cos²ϑ (the normal
    # irradiance is E/cosϑ and the path through dz is dz/cosϑ) and fades as e^(-2Kz/cosϑ).
    K = water.diffuse_attenuation * secant
    reflectances = tuple(
        float(
            secant**2
            * slab_backscatter_reflectance(
                backscatter_pi=water.backscatter_pi,
                diffuse_attenuation=K,
                top=top,
                bottom=bottom,
                reference=reference,
            )
        )
        for (top, bottom), reference in zip(gates, references, strict=True)
    )
    sea = scene_sea(scene)
    transport = scene.transport
    setup = Setup(
        water=water,
        sea=sea,
        kriging=functools.partial(surface_kriging, scene.surface, sea),
        max_elevation=scene.surface.max_elevation,
        surface_spacing=None if scene.surface.spectrum == "flat" else scene.surface_spacing(),
        gates=gates,
        reference_depths=references,
        reflectances=reflectances,
        scale=_signal_scale(scene),
        refracted_nadir=refracted_nadir,
        secant=float(secant),
        altitude=p.altitude,
        nadir=nadir,
        azimuth=azimuth,
        velocity=tuple(float(v) for v in scene.sequence.velocity),
        interval=scene.sequence.interval,
        frames=scene.sequence.frames,
        pixels=r.pixels,
        field_of_view=float(np.radians(r.field_of_view_deg)),
        receiver_aperture=scene.radiometry.receiver_aperture,
        beam=laser.beam,
        laser_field_of_view=float(np.radians(laser.field_of_view_deg or r.field_of_view_deg)),
        rays=scene.laser_rays,
        pixel_pitch_rays=scene.pixel_pitch_rays,
        psf_truncation=w.psf_truncation,
        target=scene.target,
        target_centre=(np.nan, np.nan),
        photons=Photons(
            phase_function=transport.phase_function,
            photons=transport.photons,
            batches=transport.batches,
            max_scattering=transport.max_scattering,
        ),
    )
    return replace(setup, target_centre=_target_centre(scene, setup))


def _target_centre(scene: Scene, setup: Setup) -> tuple[float, float]:
    """World (x, y) of the target's centre: as given, or on the central ray at t = 0 [m]."""
    t = scene.target
    if t.x is not None and t.y is not None:
        return float(t.x), float(t.y)
    origin = setup.platform_position(0.0)
    rotation = PinholeCamera(
        position=tuple(origin),
        nadir=setup.nadir,
        azimuth=setup.azimuth,
        field_of_view=setup.field_of_view,
        pixels=setup.pixels,
    ).rotation
    centre = flat_sea_point(
        origin=origin,
        direction=rotation[2],
        depth=t.depth,
        refractive_index=setup.water.refractive_index,
    )
    return float(centre[0]), float(centre[1])


def receiver_terms(scene: Scene) -> dict:
    """The lidar equation's instrument terms of `scene`, by their keyword names.

    Pulse energy [J], wavelength [m], receiver aperture diameter [m], optics transmission
    and quantum efficiency [1], and one pixel's solid angle [sr], as
    `workers.receiver.radiometry.lidar_equation` and `photoelectrons_per_signal` take them.
    """
    r = scene.radiometry
    return {
        "pulse_energy": r.pulse_energy,
        "wavelength": r.wavelength,
        "aperture_diameter": r.receiver_aperture,
        "optics_transmission": r.optics_transmission,
        "quantum_efficiency": r.quantum_efficiency,
        "solid_angle": pixel_solid_angle(
            field_of_view=np.radians(scene.receiver.field_of_view_deg),
            pixels=scene.receiver.pixels,
        ),
    }


def _signal_scale(scene: Scene) -> float:
    """The factor taking the raw signal to photoelectrons (or to white-plane units).

    Absolute: the lidar equation's photon budget for the Gaussian beam's whole pulse
    energy, whose 1/e half-width at the reference range (`frame_geometry`'s, the slant
    range at the first frame) is that range times tan(laser field/2). Normalised: a ρ = 1
    plane just under a flat sea at nadir, which reads t0² (two-way normal-incidence
    Fresnel transmittance), gives `white_plane_photons` (1 when that is 0).
    """
    r, n_w = scene.radiometry, scene.water.refractive_index
    if r.mode == "normalised":
        t0 = 1.0 - float(fresnel_reflectance(1.0, n1=1.0, n2=n_w))
        return (r.white_plane_photons or 1.0) / t0**2
    p = scene.platform
    reference_range = p.altitude / np.cos(np.radians(p.nadir_deg))
    laser_fov = np.radians(scene.laser.field_of_view_deg or scene.receiver.field_of_view_deg)
    return photoelectrons_per_signal(
        **receiver_terms(scene),
        beam_half_width=reference_range * np.tan(0.5 * laser_fov),
        refractive_index=n_w,
    )
