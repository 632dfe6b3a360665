"""Tests of workers.sea.spectra: identities, closed forms and published values."""

import dataclasses
import math

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy import optimize, special

from workers.sea.cascades import Sea
from workers.sea.described import wave_spectrum
from workers.sea.spectra import (
    GRAVITY,
    Elfouhaily,
    Jonswap,
    Phillips,
    PiersonMoskowitz,
    dispersion,
)
from workers.settings.sea import SurfaceSpec

SPECTRA = {
    "phillips": Phillips(wind_speed=5.0),
    "phillips-rotated-cutoff": Phillips(
        wind_speed=8.0, wind_direction=0.7, alpha=0.01, small_wave_cutoff=0.01
    ),
    "pierson-moskowitz": PiersonMoskowitz(wind_speed=10.0),
    "jonswap": Jonswap(wind_speed=10.0, fetch=50e3),
    "jonswap-peaked-rotated": Jonswap(wind_speed=7.0, fetch=20e3, gamma=7.0, wind_direction=-2.0),
    "elfouhaily": Elfouhaily(wind_speed=5.0),
    "elfouhaily-young-rotated": Elfouhaily(
        wind_speed=12.0, inverse_wave_age=2.5, wind_direction=2.5
    ),
}


def _polar_grid(k_min, k_max, n_k, n_phi):
    """Uniform grid in (ln k, φ) with trapezoid weights for ∫∫ f d²k = ∫∫ f k² d(ln k) dφ."""
    u = np.linspace(math.log(k_min), math.log(k_max), n_k)
    phi = np.linspace(-np.pi, np.pi, n_phi, endpoint=False)
    k = np.exp(u)[:, None]
    weight_u = np.full(n_k, u[1] - u[0])
    weight_u[[0, -1]] *= 0.5
    weights = weight_u[:, None] * (2.0 * np.pi / n_phi) * k**2
    return k, phi[None, :], weights


@pytest.mark.parametrize("spectrum", SPECTRA.values(), ids=SPECTRA.keys())
def test_directional_integrates_to_omnidirectional_variance(spectrum):
    # ∫∫ Ψ(kx, ky) dkx dky over a fine polar grid (1e-4 ≤ k ≤ 1e5 rad/m, beyond which
    # every spectrum here is negligible) must equal ∫ S(k) dk from the 1-D quadrature:
    # this checks the 1/k Jacobian and the spreading normalisation together.
    k, phi, weights = _polar_grid(1e-4, 1e5, 3000, 180)
    density = spectrum.directional(k * np.cos(phi), k * np.sin(phi))
    assert_allclose(np.sum(density * weights), spectrum.variance(), rtol=1e-6)


@pytest.mark.parametrize("spectrum", SPECTRA.values(), ids=SPECTRA.keys())
@pytest.mark.parametrize("k", [0.05, 0.3, 1.0, 10.0, 370.0, 3000.0])
def test_spreading_is_normalised(spectrum, k):
    phi = np.linspace(-np.pi, np.pi, 4096, endpoint=False)
    total = np.sum(spectrum.spreading(k, phi)) * (2.0 * np.pi / phi.size)
    assert_allclose(total, 1.0, atol=1e-9)


@pytest.mark.parametrize("spectrum", SPECTRA.values(), ids=SPECTRA.keys())
def test_wind_direction_rotates_the_spectrum(spectrum):
    rng = np.random.default_rng(3)
    kx, ky = rng.normal(scale=2.0, size=(2, 50))
    turn = 1.1
    turned = dataclasses.replace(spectrum, wind_direction=spectrum.wind_direction + turn)
    rotated_x = kx * math.cos(turn) - ky * math.sin(turn)
    rotated_y = kx * math.sin(turn) + ky * math.cos(turn)
    assert_allclose(
        turned.directional(rotated_x, rotated_y), spectrum.directional(kx, ky), rtol=1e-12
    )


@pytest.mark.parametrize("spectrum", SPECTRA.values(), ids=SPECTRA.keys())
def test_band_moments_add_up(spectrum):
    split = 3.0
    for moment in (spectrum.variance, spectrum.slope_variance):
        low = moment(k_max=split)
        high = moment(k_min=split, k_max=1e3)
        assert_allclose(low + high, moment(k_max=1e3), rtol=1e-11)


@pytest.mark.parametrize("spectrum", SPECTRA.values(), ids=SPECTRA.keys())
def test_zero_wavenumber_is_zero_without_warnings(spectrum):
    assert spectrum.omnidirectional(0.0) == 0.0
    assert spectrum.directional(0.0, 0.0) == 0.0
    assert_allclose(spectrum.directional(np.zeros((2, 3)), 0.0), 0.0)


def test_dispersion_relation_and_minimum_phase_speed():
    k = np.geomspace(1.0, 5000.0, 20001)
    omega = dispersion(k, gravity=9.81, surface_tension=0.074, density=1025.0)
    assert_allclose(omega**2, 9.81 * k + 0.074 / 1025.0 * k**3, rtol=1e-14)
    speed = omega / k
    # Elfouhaily et al. (1997): c_m = 0.23 m/s at k_m = 370 rad/m.
    assert_allclose(k[speed.argmin()], 370.0, rtol=0.01)
    assert_allclose(speed.min(), 0.23, rtol=0.02)


# --- Phillips -------------------------------------------------------------------------


def test_phillips_tail_is_the_saturation_range():
    # Far above the peak (kL ≫ 1) and below the cutoff (kℓ ≪ 1): S → (α/2) k⁻³.
    spectrum = Phillips(wind_speed=6.0, alpha=0.0081, small_wave_cutoff=1e-6)
    k = np.array([300.0, 1000.0, 3000.0]) / spectrum.length_scale
    assert_allclose(spectrum.omnidirectional(k) * k**3, 0.0081 / 2, rtol=2e-4)


def test_phillips_default_cutoff_and_closed_form_moments():
    spectrum = Phillips(wind_speed=7.0, alpha=0.0081)
    big = 7.0**2 / GRAVITY
    small = big / 1000.0
    assert_allclose(spectrum.cutoff_length, small, rtol=1e-15)
    # ∫ k⁻³ e^{-1/(kL)² - k²ℓ²} dk = ℓL K₁(2ℓ/L) and ∫ k⁻¹ (…) dk = K₀(2ℓ/L).
    assert_allclose(
        spectrum.variance(), 0.0081 / 2 * small * big * special.k1(2 * small / big), rtol=1e-11
    )
    mss = 0.0081 / 2 * special.k0(2 * small / big)
    assert_allclose(spectrum.slope_variance(), mss, rtol=1e-11)
    # As ℓ → 0 the variance tends to αL²/4.
    assert_allclose(
        Phillips(wind_speed=7.0, small_wave_cutoff=1e-9).variance(), 0.0081 * big**2 / 4
    )


def test_phillips_spreading_is_cos_squared():
    spectrum = Phillips(wind_speed=5.0, wind_direction=0.3)
    k = 2.0
    for angle in (0.3, 0.3 + np.pi / 2, 0.3 + np.pi, 1.0):
        ratio = spectrum.directional(k * math.cos(angle), k * math.sin(angle)) / (
            spectrum.directional(k * math.cos(0.3), k * math.sin(0.3))
        )
        assert_allclose(ratio, math.cos(angle - 0.3) ** 2, atol=1e-15)


# --- Pierson–Moskowitz and JONSWAP ----------------------------------------------------


def _peak_of(frequency_spectrum, guess):
    result = optimize.minimize_scalar(
        lambda omega: -frequency_spectrum(omega),
        bounds=(0.5 * guess, 2.0 * guess),
        method="bounded",
        options={"xatol": 1e-10 * guess},
    )
    return result.x


@pytest.mark.parametrize("wind_speed", [3.0, 10.0, 20.0])
def test_pierson_moskowitz_peak_and_variance(wind_speed):
    spectrum = PiersonMoskowitz(wind_speed=wind_speed)
    # Documented: ω_p = (0.8 β)^¼ g / U₁₉.₅, β = 0.74, U₁₉.₅ = 1.026 U₁₀ (= 0.855 g/U₁₀).
    expected = (0.8 * 0.74) ** 0.25 * GRAVITY / (1.026 * wind_speed)
    assert_allclose(spectrum.peak_frequency, expected, rtol=1e-15)
    assert_allclose(expected * wind_speed / GRAVITY, 0.855, atol=5e-4)
    assert_allclose(_peak_of(spectrum.frequency_spectrum, expected), expected, rtol=1e-6)
    # ∫ α g² ω⁻⁵ exp(-5/4 (ω_p/ω)⁴) dω = α g² / (5 ω_p⁴).
    assert_allclose(spectrum.variance(), 0.0081 * GRAVITY**2 / (5 * expected**4), rtol=1e-11)


def test_pierson_moskowitz_slope_variance_diverges_but_band_is_exact():
    spectrum = PiersonMoskowitz(wind_speed=8.0)
    assert spectrum.slope_variance() == math.inf
    # ∫₀^K k² S dk = (α/4) E₁(5/4 (ω_p/ω_K)⁴), ω_K = √(gK).
    k_max = 50.0
    omega_max = math.sqrt(GRAVITY * k_max)
    expected = 0.0081 / 4 * special.exp1(1.25 * (spectrum.peak_frequency / omega_max) ** 4)
    assert_allclose(spectrum.slope_variance(k_max=k_max), expected, rtol=1e-11)


def test_jonswap_fetch_laws_and_peak():
    spectrum = Jonswap(wind_speed=12.0, fetch=80e3, gamma=3.3)
    fetch = GRAVITY * 80e3 / 12.0**2
    # Hasselmann et al. (1973): α = 0.076 x̃^-0.22, f_p U/g = 3.5 x̃^-0.33.
    assert_allclose(spectrum.alpha, 0.076 * fetch**-0.22, rtol=1e-15)
    expected = 2 * np.pi * 3.5 * GRAVITY / 12.0 * fetch**-0.33
    assert_allclose(spectrum.peak_frequency, expected, rtol=1e-15)
    assert_allclose(_peak_of(spectrum.frequency_spectrum, expected), expected, rtol=1e-6)
    # The enhancement at the peak is γ.
    shape = (
        spectrum.alpha * GRAVITY**2 * expected**-5 * math.exp(-1.25)  # PM shape at ω_p
    )
    assert_allclose(spectrum.frequency_spectrum(expected), 3.3 * shape, rtol=1e-12)


def test_jonswap_with_unit_gamma_is_the_pierson_moskowitz_shape():
    spectrum = Jonswap(wind_speed=9.0, fetch=30e3, gamma=1.0)
    alpha, peak = spectrum.alpha, spectrum.peak_frequency
    omega = np.linspace(0.3 * peak, 6.0 * peak, 500)
    pm_shape = alpha * GRAVITY**2 * omega**-5 * np.exp(-1.25 * (peak / omega) ** 4)
    assert_allclose(spectrum.frequency_spectrum(omega), pm_shape, rtol=1e-13)


def test_jonswap_with_unit_gamma_matches_pierson_moskowitz_at_equal_peak():
    # Choose the fetch that puts the JONSWAP peak on the PM peak: the two spectra then
    # differ only by the ratio of their α, at every k, with the same spreading.
    pm = PiersonMoskowitz(wind_speed=10.0)
    fetch_ratio = (pm.peak_frequency * 10.0 / (2 * np.pi * 3.5 * GRAVITY)) ** (-1 / 0.33)
    jonswap = Jonswap(wind_speed=10.0, fetch=fetch_ratio * 10.0**2 / GRAVITY, gamma=1.0)
    assert_allclose(jonswap.peak_frequency, pm.peak_frequency, rtol=1e-12)
    k = np.geomspace(0.2, 50.0, 200) * pm.peak_frequency**2 / GRAVITY
    assert_allclose(
        jonswap.omnidirectional(k) / pm.omnidirectional(k), jonswap.alpha / pm.alpha, rtol=1e-12
    )
    phi = np.linspace(-np.pi, np.pi, 7)
    assert_allclose(jonswap.spreading(k[:, None], phi), pm.spreading(k[:, None], phi))


def test_frequency_spectra_spreading_points_downwind():
    spectrum = PiersonMoskowitz(wind_speed=10.0, wind_direction=1.0)
    k = spectrum.peak_frequency**2 / GRAVITY
    downwind = spectrum.directional(k * math.cos(1.0), k * math.sin(1.0))
    upwind = spectrum.directional(-k * math.cos(1.0), -k * math.sin(1.0))
    assert downwind > 1e3 * upwind


@pytest.mark.parametrize(
    "kwargs",
    [
        {"wind_speed": 0.0, "fetch": 1e3},
        {"wind_speed": 5.0, "fetch": -1.0},
        {"wind_speed": 5.0, "fetch": 1e3, "gamma": 0.5},
    ],
    ids=["no-wind", "negative-fetch", "gamma-below-one"],
)
def test_jonswap_rejects_bad_parameters(kwargs):
    with pytest.raises(ValueError):
        Jonswap(**kwargs)


# --- Elfouhaily et al. (1997) ---------------------------------------------------------


def test_elfouhaily_spectrum_is_curvature_over_k_cubed():
    spectrum = Elfouhaily(wind_speed=8.0)
    k = np.geomspace(1e-2, 1e4, 50)
    assert_allclose(spectrum.omnidirectional(k), spectrum.curvature(k) / k**3, rtol=1e-15)


# Cox, C., & Munk, W. (1954). Measurement of the roughness of the sea surface from
# photographs of the sun's glitter. J. Opt. Soc. Am. 44(11), 838–850: clean surface,
# σ² = 0.003 + 5.12×10⁻³ W ± 0.004, W the wind speed at 41 ft (12.5 m) in m/s, and ± their
# rms scatter about the fit. Elfouhaily et al. (1997) built their spectrum to agree with
# these observations, so agreement can be claimed within the observations' scatter: we
# take the 95 % band, ±2 × 0.004 (absolute). W is converted from U10 with the spectrum's
# own log profile, W = U10 + (u*/κ) ln(12.5/10). Measured with this implementation (full
# band, fully developed sea): U10 = 3: 0.0229, 5: 0.0322, 7: 0.0422, 10: 0.0622, against
# Cox–Munk 0.0186, 0.0291, 0.0396, 0.0553: the model sits 0.003–0.007 above the fit.
COX_MUNK_BAND = 2 * 0.004


@pytest.mark.parametrize("wind_speed", [3.0, 5.0, 7.0, 10.0], ids=["U3", "U5", "U7", "U10"])
def test_elfouhaily_mean_square_slope_matches_cox_munk(wind_speed):
    spectrum = Elfouhaily(wind_speed=wind_speed)
    at_41_ft = wind_speed + spectrum.friction_velocity / spectrum.VON_KARMAN * np.log(1.25)
    cox_munk = 0.003 + 5.12e-3 * at_41_ft
    assert abs(spectrum.slope_variance() - cox_munk) <= COX_MUNK_BAND


@pytest.mark.parametrize("wind_speed", [7.0, 10.0, 15.0], ids=["U7", "U10", "U15"])
def test_elfouhaily_curvature_peaks_at_the_capillary_gravity_minimum(wind_speed):
    spectrum = Elfouhaily(wind_speed=wind_speed)
    k = np.geomspace(1e-3, 1e5, 100001)
    assert_allclose(k[spectrum.curvature(k).argmax()], 370.0, rtol=0.01)


def test_elfouhaily_spreading_parameters():
    spectrum = Elfouhaily(wind_speed=10.0)
    k_p = spectrum.peak_wavenumber
    assert_allclose(k_p, 0.84**2 * GRAVITY / 10.0**2, rtol=1e-15)
    # Φ(φ) = (1 + Δ cos 2φ)/(2π): Δ from the ratio of the downwind and crosswind values.
    for k, low, high in ((k_p, 0.999, 1.0), (30 * k_p, 0.17, 0.4)):
        down = spectrum.spreading(k, 0.0)
        cross = spectrum.spreading(k, np.pi / 2)
        delta = (down - cross) / (down + cross)
        assert low <= delta <= high
        # Centrosymmetric: waves up- and downwind carry the same energy.
        assert_allclose(spectrum.spreading(k, np.pi), down, rtol=1e-14)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"wind_speed": -1.0},
        {"wind_speed": math.nan},
        {"wind_speed": 5.0, "inverse_wave_age": 0.5},
        {"wind_speed": 5.0, "inverse_wave_age": 6.0},
    ],
    ids=["negative-wind", "nan-wind", "too-old", "too-young"],
)
def test_elfouhaily_rejects_bad_parameters(kwargs):
    with pytest.raises(ValueError):
        Elfouhaily(**kwargs)


def _scene_wind_range():
    """The wind speeds a scene accepts, (min, max) in m/s, read from its schema."""
    constraints = SurfaceSpec.model_fields["wind_speed"].metadata
    least = next(c.ge for c in constraints if hasattr(c, "ge"))
    greatest = next(c.le for c in constraints if hasattr(c, "le"))
    return least, greatest


SCENE_WINDS = np.geomspace(*_scene_wind_range(), 15)
"""U10 from the scene's least to its greatest allowed wind (0.5 to 30 m/s), log-spaced."""

SCENE_SPECTRA = {
    "elfouhaily": {"spectrum": "elfouhaily"},
    "elfouhaily-young": {"spectrum": "elfouhaily", "inverse_wave_age": 5.0},
    "phillips": {"spectrum": "phillips"},
    "pierson-moskowitz": {"spectrum": "pierson_moskowitz"},
    "jonswap": {"spectrum": "jonswap"},
    "jonswap-short-fetch": {"spectrum": "jonswap", "fetch": 1.0},
}
"""Every spectrum a scene can name, at its default settings and the extremes of its knobs."""


@pytest.mark.parametrize("settings", SCENE_SPECTRA.values(), ids=SCENE_SPECTRA.keys())
@pytest.mark.parametrize("wind_speed", SCENE_WINDS, ids=[f"U{u:.2f}" for u in SCENE_WINDS])
def test_every_scene_spectrum_is_finite_and_non_negative(settings, wind_speed):
    # Issue #9, item 8: below U10 ≈ 2.7 m/s the short-wave term of Elfouhaily et al. went
    # negative (eq. 44 extrapolated), so sqrt(Ψ Δk²) was NaN and so was the sample.
    spectrum = wave_spectrum(SurfaceSpec(**settings, wind_speed=wind_speed))
    k, phi, _ = _polar_grid(1e-4, 1e5, 2001, 72)
    density = spectrum.directional(k * np.cos(phi), k * np.sin(phi))
    assert np.isfinite(density).all() and (density >= 0).all()
    omnidirectional = spectrum.omnidirectional(k[:, 0])
    assert np.isfinite(omnidirectional).all() and (omnidirectional >= 0).all()
    # the scene grids: the default and the finest spacing of the shipped configs
    for grid_size, spacing in ((256, 0.016), (64, 0.004)):
        amplitude = Sea(spectrum, grid_size, (grid_size * spacing,)).amplitudes(0)
        assert np.isfinite(amplitude).all()


def test_elfouhaily_short_wave_equilibrium_is_eq_44_while_positive_and_zero_below():
    # Eq. (44) of Elfouhaily et al. (1997): α_m = 0.01 [1 + ln(u*/c_m)] for u* ≤ c_m,
    # 0.01 [1 + 3 ln(u*/c_m)] above; it crosses 0 at u* = c_m/e.
    def law(spectrum):
        ratio = spectrum.friction_velocity / spectrum.C_M
        return 0.01 * (1 + (1 if ratio <= 1 else 3) * np.log(ratio))

    threshold = optimize.brentq(
        lambda u: Elfouhaily(wind_speed=u).friction_velocity - Elfouhaily.C_M / np.e, 0.5, 10.0
    )
    assert_allclose(threshold, 2.678, atol=1e-3)
    for wind_speed in (0.5, 1.0, 2.0, 0.999 * threshold):
        assert Elfouhaily(wind_speed=wind_speed).short_wave_equilibrium == 0.0
    for wind_speed in (1.001 * threshold, 3.0, 5.0, 12.0, 30.0):
        spectrum = Elfouhaily(wind_speed=wind_speed)
        assert spectrum.short_wave_equilibrium > 0
        assert spectrum.short_wave_equilibrium == law(spectrum)
    # continuous at the threshold: 0.1 % above it α_m is still ~1e-5
    assert Elfouhaily(wind_speed=1.001 * threshold).short_wave_equilibrium < 1e-4  # 0.01 at c_m


def test_moments_reject_a_reversed_band():
    with pytest.raises(ValueError):
        Phillips(wind_speed=5.0).variance(k_min=2.0, k_max=1.0)
