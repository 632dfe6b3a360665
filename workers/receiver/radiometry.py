r"""Absolute radiometry: the photon budget of a gated imaging lidar (the lidar equation).

The renderer (`workers.render`) works in *raw signal units*: the laser's irradiance on its
beam cross-section at the reference range is J = 1 on the beam axis (`workers.setup.geometry.
LaserRays.from_platform`), each in-water plane carries that light down (Fresnel
transmittance, attenuation, spreading), a Lambertian reflector of reflectance ρ returns
ρ times the irradiance it receives, and each pixel gathers that, times its own Fresnel
transmittance and attenuation on the way up. A ρ = 1 plane just under a flat sea at nadir
thus reads :math:`t_0^2` (the two-way normal-incidence transmittance) at the image centre.

This module turns that raw signal into photoelectrons per pixel for a laser of given pulse
energy and a receiver of given aperture and efficiencies: `photoelectrons_per_signal`. The
renderer multiplies its raw images by it (``radiometry.mode: absolute``). `lidar_equation`
is the closed form the renderer must reproduce for a flat sea, nadir, no scattering.

All quantities are SI: joules, metres, steradians; efficiencies are fractions.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "PLANCK",
    "SPEED_OF_LIGHT",
    "lidar_equation",
    "photoelectrons_per_signal",
    "photon_energy",
    "pixel_solid_angle",
]

PLANCK = 6.62607015e-34
"""Planck constant h [J s] (exact, SI 2019)."""

SPEED_OF_LIGHT = 299792458.0
"""Speed of light in vacuum c [m/s] (exact)."""


def photon_energy(*, wavelength):
    r"""Energy of one photon, :math:`h c / \lambda`.

    Parameters
    ----------
    wavelength : float or array_like
        Vacuum wavelength λ [m] (532 nm for a frequency-doubled Nd:YAG laser).

    Returns
    -------
    float or ndarray
        Photon energy [J] (3.734e-19 J at 532 nm).
    """
    return PLANCK * SPEED_OF_LIGHT / np.asarray(wavelength, dtype=float)


def pixel_solid_angle(*, field_of_view, pixels):
    r"""Solid angle seen by the central pixel of a square pinhole camera.

    Parameters
    ----------
    field_of_view : float or array_like
        Full field of view α across the image [rad].
    pixels : int or array_like
        Pixels per side N [1].

    Returns
    -------
    float or ndarray
        :math:`\Omega_p = (2\tan(\alpha/2)/N)^2` [sr].

    Notes
    -----
    Pixels are square and equal on the focal plane, so off-axis pixels see
    :math:`\Omega_p\cos^3\vartheta` and, with the aperture's foreshortening, collect
    :math:`\cos^4\vartheta` of the on-axis power ("natural vignetting"). The renderer
    neglects that fall-off (1.4 % at the corners of a 6.7° field), as it neglects any
    lens vignetting; this function gives the on-axis value.
    """
    half = np.tan(0.5 * np.asarray(field_of_view, dtype=float))
    return (2.0 * half / np.asarray(pixels, dtype=float)) ** 2


def photoelectrons_per_signal(
    *,
    pulse_energy,
    wavelength,
    aperture_diameter,
    optics_transmission,
    quantum_efficiency,
    solid_angle,
    beam_half_width,
    refractive_index,
):
    r"""Photoelectrons per pixel per unit of the renderer's raw signal (the photon budget).

    Parameters
    ----------
    pulse_energy : float
        Energy Q of one laser pulse leaving the transmitter [J].
    wavelength : float
        Laser wavelength λ [m].
    aperture_diameter : float
        Diameter D of the receiver's entrance pupil [m].
    optics_transmission : float
        Fraction η_o of the light entering the aperture that reaches the photocathode
        (window, lens, narrow-band filter) [1].
    quantum_efficiency : float
        Photoelectrons per photon η_q at the photocathode [1].
    solid_angle : float
        Solid angle Ω_p of one pixel [sr] (`pixel_solid_angle`).
    beam_half_width : float
        Half-width a of the Gaussian beam, :math:`I_0 = J e^{-r^2/a^2}`, on its
        cross-section at the renderer's reference range [m] (for the renderer's laser:
        the reference range times the tangent of half the laser's field).
    refractive_index : float
        Refractive index n of the water [1].

    Returns
    -------
    float
        C such that the expected photoelectron count of a pixel is C times its raw signal
        [photoelectrons per raw unit].

    Notes
    -----
    *Transmitter.* The untruncated Gaussian beam carries :math:`\pi a^2 J` in all, so a
    pulse of :math:`N_\gamma = Q\lambda/(hc)` photons puts
    :math:`J = N_\gamma/(\pi a^2)` photons per square metre on the beam axis at the
    reference range: one raw irradiance unit is that many photons per m². The scale is
    tied to the pulse's *total* energy through this normalisation, not to the rays the
    renderer happens to trace (its square lattice carries erf(1)² = 71 % of the beam).

    *Target.* A Lambertian reflector of reflectance ρ under irradiance E has radiance
    :math:`\rho E/\pi` in the water. The raw signal is ρE (in raw units): the 1/π is here.

    *Interface.* Radiance divided by n² crossing from water into air (the n² law of
    radiance, :math:`L/n^2` is invariant), times the Fresnel transmittance, which the
    renderer applies per ray both ways (the two-way :math:`t^2`).

    *Receiver.* A pixel looking at radiance L in air collects :math:`L A_R \Omega_p`
    photons through the aperture :math:`A_R = \pi D^2/4` (the radiance theorem: the
    count does not depend on the range to the target, only on its radiance), of which
    :math:`\eta_o\eta_q` become photoelectrons. Hence

    .. math::
        C = \frac{Q\lambda}{hc}\,\frac{1}{\pi a^2}\,\frac{1}{\pi}\,\frac{1}{n^2}\,
            \frac{\pi D^2}{4}\,\Omega_p\,\eta_o\,\eta_q .

    The intensifier's gain G (counts per photoelectron, `workers.receiver.noise.shot_noise`) comes
    after: the noisy image is in counts, its expectation G times this.

    With a beam spread by range R0 and refraction, the raw signal of a flat-sea target
    carries :math:`(R_0/(H + d/n))^2`, so the product falls as :math:`1/(nH + d)^2`, the
    bathymetric lidar equation's spreading term (`lidar_equation`).

    References
    ----------
    Guenther, G. C. (1985). Airborne laser hydrography: system design and performance
    factors. NOAA Professional Paper Series, National Ocean Service (the bottom-return
    equation with :math:`(n_w H + D)^2`). Churnside, J. H. (2013). Review of profiling
    oceanographic lidar. Optical Engineering 53(5), 051405. Measures, R. M. (1984).
    Laser Remote Sensing: Fundamentals and Applications, Wiley, ch. 7 (the lidar equation).
    Mobley, C. D. (1994). Light and Water, Academic Press (the n² law of radiance).
    """
    photons = pulse_energy / photon_energy(wavelength=wavelength)
    aperture = 0.25 * np.pi * aperture_diameter**2
    return float(
        photons
        / (np.pi * beam_half_width**2)
        / np.pi
        / refractive_index**2
        * aperture
        * solid_angle
        * optics_transmission
        * quantum_efficiency
    )


def lidar_equation(
    *,
    pulse_energy,
    wavelength,
    aperture_diameter,
    optics_transmission,
    quantum_efficiency,
    solid_angle,
    beam_divergence,
    altitude,
    depth,
    reflectance,
    attenuation,
    refractive_index,
    transmittance,
):
    r"""Photoelectrons in the central pixel from a Lambertian plane under a flat sea.

    The bathymetric lidar equation for an extended target, per pixel, at nadir: a
    divergent Gaussian beam from altitude H lights a horizontal Lambertian plane at depth
    d through a flat sea, without scattering.

    Parameters
    ----------
    pulse_energy, wavelength, aperture_diameter, optics_transmission, \
quantum_efficiency, solid_angle
        As for `photoelectrons_per_signal` [J, m, m, 1, 1, sr].
    beam_divergence : float
        Half-angle tangent of the beam, :math:`\tan(\phi/2)`, so that the beam's 1/e
        half-width at range R is :math:`R\tan(\phi/2)` [1].
    altitude : float or array_like
        Height H of the lidar above the sea [m].
    depth : float or array_like
        Depth d of the plane [m].
    reflectance : float
        Lambertian reflectance ρ of the plane [1].
    attenuation : float
        Diffuse attenuation coefficient K [1/m].
    refractive_index : float
        Refractive index n of the water [1].
    transmittance : float
        Fresnel transmittance t0 of the surface at normal incidence [1] (the same both
        ways).

    Returns
    -------
    float or ndarray
        Expected photoelectrons on the beam axis [photoelectrons].

    Notes
    -----
    .. math::
        N = \frac{Q\lambda}{hc}\,\eta_o\eta_q\,\frac{\pi D^2}{4}\,\Omega_p\,
            \frac{t_0^2\,\rho\,e^{-2Kd}}{\pi^2\tan^2(\phi/2)\,(nH + d)^2}.

    Summed over the pixels that see the whole beam (:math:`\sum\Omega_p` times the
    Gaussian's :math:`\pi\tan^2(\phi/2)` weight), this is Guenther's (1985) bottom-return
    equation :math:`P\,\eta\,\rho\,A_R\,t_0^2 e^{-2Kd}/(\pi(n H + d)^2)`. Between 30 m and
    90 m altitude it falls by :math:`((90n + d)/(30n + d))^2`, about 9 for shallow
    targets.

    References
    ----------
    Guenther, G. C. (1985). Airborne laser hydrography: system design and performance
    factors. NOAA Professional Paper Series, National Ocean Service.
    """
    photons = pulse_energy / photon_energy(wavelength=wavelength)
    aperture = 0.25 * np.pi * aperture_diameter**2
    altitude = np.asarray(altitude, dtype=float)
    depth = np.asarray(depth, dtype=float)
    return (
        photons
        * optics_transmission
        * quantum_efficiency
        * aperture
        * solid_angle
        * transmittance**2
        * reflectance
        * np.exp(-2.0 * attenuation * depth)
        / (np.pi**2 * beam_divergence**2 * (refractive_index * altitude + depth) ** 2)
    )
