"""The scene compiled once: `scene_setup` reads a `Scene` and builds its `Setup`.

With `workers.setup.seasetup` (the sea's cascades and kriging system), the one place
below `workers.render` that reads a scene's settings; every angle is converted to
radians here. The model is in ``docs/model.md``.
"""

from __future__ import annotations

import functools
from dataclasses import replace

import numpy as np

from workers.optics.fresnel import fresnel_reflectance
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

__all__ = ["receiver_terms", "scene_setup"]


@functools.lru_cache(maxsize=32)
def scene_setup(scene: Scene) -> Setup:
    """What every frame of every sample of a scene shares (cached by the scene, hashable)."""
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
