"""Absolute radiometry: the photon budget and the lidar equation the renderer must follow."""

import math

import numpy as np
import pytest
import yaml
from numpy.testing import assert_allclose
from pydantic import ValidationError

from workers.optics.fresnel import fresnel_reflectance
from workers.receiver.radiometry import (
    lidar_equation,
    photoelectrons_per_signal,
    photon_energy,
    pixel_solid_angle,
)
from workers.render import render
from workers.settings.scene import Scene

N_WATER = 1.34
T0 = 1.0 - float(fresnel_reflectance(1.0, n1=1.0, n2=N_WATER))
K = 0.1
"""Clear water without scattering: K = a = 0.1 1/m."""

SYSTEM = {
    "mode": "absolute",
    "pulse_energy": 0.1,
    "wavelength": 532e-9,
    "receiver_aperture": 0.1,
    "optics_transmission": 0.5,
    "quantum_efficiency": 0.15,
}


def test_photon_energy_at_532_nm():
    # h c / λ = 6.62607015e-34 J s × 299792458 m/s / 532e-9 m
    assert_allclose(photon_energy(wavelength=532e-9), 3.7339208e-19, rtol=1e-7)


def test_pixel_solid_angle():
    # 6.7° over 128 pixels: (2 tan 3.35° / 128)² = (2 × 0.0585352 / 128)²
    assert_allclose(
        pixel_solid_angle(field_of_view=math.radians(6.7), pixels=128), 8.3657e-7, rtol=1e-4
    )


def test_photon_budget_by_hand():
    # Q = 0.1 J at 532 nm is 2.678150e17 photons. On the axis of a Gaussian beam of 1/e
    # half-width a = 2 m they are 2.678150e17 / (π·4 m²) per m²; a white Lambertian plane
    # returns 1/π of that per sr, 1/n² = 1/1.7956 of it crosses into the air; a 10 cm
    # aperture (7.853982e-3 m²) seeing 1e-6 sr, with 0.5 × 0.2 efficiency:
    # 2.678150e17 × 7.853982e-3 × 1e-6 × 0.1 / (4π² × 1.7956) = 2.96726e6.
    value = photoelectrons_per_signal(
        pulse_energy=0.1,
        wavelength=532e-9,
        aperture_diameter=0.1,
        optics_transmission=0.5,
        quantum_efficiency=0.2,
        solid_angle=1e-6,
        beam_half_width=2.0,
        refractive_index=1.34,
    )
    assert_allclose(value, 2.96726e6, rtol=1e-5)


def closed_form(altitude, depth, reflectance, pixels):
    """The bathymetric lidar equation per pixel, written out here, for the central pixels.

    N = Qλ/(hc) η_o η_q (πD²/4) Ω_p t0² ρ e^(-2Kd) / (π² tan²(φ/2) (nH + d)²), times the
    Gaussian profile at the four central pixels' directions (u = v = tan(φ/2)/N).
    """
    half = math.tan(math.radians(6.7 / 2))
    photons = 0.1 * 532e-9 / (6.62607015e-34 * 299792458.0)
    omega = (2 * half / pixels) ** 2
    aperture = math.pi * 0.1**2 / 4
    profile = math.exp(-2 / pixels**2)
    return (
        photons
        * 0.5
        * 0.15
        * aperture
        * omega
        * T0**2
        * reflectance
        * np.exp(-2 * K * depth)
        * profile
        / (math.pi**2 * half**2 * (N_WATER * np.asarray(altitude) + depth) ** 2)
    )


def disk_scene(altitude, depth=5.0, reflectance=0.5, pixels=32, radiometry=SYSTEM):
    """A flat sea, clear water without scattering, nadir, divergent beam, a wide disk."""
    return Scene.model_validate(
        {
            "surface": {"spectrum": "flat", "grid_size": 64, "spacing": 0.064},
            "water": {"preset": None, "absorption": K, "scattering": 0.0, "backscatter": 0.0},
            "laser": {"beam": "divergent"},
            "receiver": {"pixels": pixels, "gates": [[0.5, 12.0]]},
            "platform": {"altitude": altitude},
            # wider than the footprint at every altitude (half-width 0.0585 H + d/n ...)
            "target": {
                "shape": "disk",
                "radius": min(100.0, 0.1 * altitude + 2.0),
                "depth": depth,
                "reflectance": reflectance,
            },
            "radiometry": radiometry,
        }
    )


def centre(image):
    n = image.shape[-1] // 2
    return float(image[..., n - 1 : n + 1, n - 1 : n + 1].mean())


ALTITUDES = (20.0, 50.0, 100.0, 300.0)


@pytest.mark.parametrize("altitude", ALTITUDES, ids=[f"H{int(h)}" for h in ALTITUDES])
def test_flat_sea_disk_follows_the_lidar_equation(altitude):
    ds = render(disk_scene(altitude), seed=1)
    value = centre(ds.expected.values[0, 0])
    assert_allclose(value, closed_form(altitude, 5.0, 0.5, 32), rtol=0.01)
    assert ds.expected.attrs["long_name"] == "expected photoelectron count (noise-free)"
    assert ds.image.attrs["long_name"] == "photoelectron count with shot noise"
    assert ds.image.dtype.kind == "u" and ds.image.attrs["units"] == "1"


def test_module_lidar_equation_is_the_closed_form():
    value = lidar_equation(
        pulse_energy=0.1,
        wavelength=532e-9,
        aperture_diameter=0.1,
        optics_transmission=0.5,
        quantum_efficiency=0.15,
        solid_angle=pixel_solid_angle(field_of_view=math.radians(6.7), pixels=32),
        beam_divergence=math.tan(math.radians(3.35)),
        altitude=np.asarray(ALTITUDES),
        depth=5.0,
        reflectance=0.5,
        attenuation=K,
        refractive_index=N_WATER,
        transmittance=T0,
    )
    assert_allclose(value * math.exp(-2 / 32**2), closed_form(ALTITUDES, 5.0, 0.5, 32), rtol=1e-12)


def test_signal_falls_as_the_apparent_range_squared_between_30_and_90_m():
    # The flagship sweep's altitude range: ((90 n + d) / (30 n + d))² = 7.72 at d = 5 m
    # (9 at d = 0); the per-scene normalisation gives 0.86 (brighter higher up).
    low = centre(render(disk_scene(30.0), seed=1).expected.values[0, 0])
    high = centre(render(disk_scene(90.0), seed=1).expected.values[0, 0])
    assert_allclose(low / high, ((90 * N_WATER + 5.0) / (30 * N_WATER + 5.0)) ** 2, rtol=0.01)
    assert 7.5 < low / high < 8.0


def test_normalised_mode_is_unchanged():
    # A white plane just under a flat sea reads white_plane_photons, and deeper planes
    # the same fraction as before, whatever the altitude.
    normalised = {"mode": "normalised", "white_plane_photons": 200.0}
    for altitude in (30.0, 90.0):
        s = disk_scene(altitude, depth=2.0, reflectance=1.0, radiometry=normalised)
        value = centre(render(s, seed=1).expected.values[0, 0])
        spread = (altitude / (altitude + 2.0 / N_WATER)) ** 2
        assert_allclose(value, 200.0 * math.exp(-2 * K * 2.0) * spread, rtol=0.01)


def test_normalised_mode_is_range_free_off_nadir():
    # docs/model.md §7: normalised images drop the range, not only the altitude: a white
    # plane seen at 20° off nadir reads what the plane at nadir reads from the same
    # (slant) range, times the oblique view's own factors: the two Fresnel crossings
    # T(θ)²/t0², the beam's irradiance on a horizontal plane, cos θ, and the slant path's
    # attenuation and spread. Issue #36 read the definition as "the plane at nadir from
    # the same altitude", which is cos²θ = 0.88 of this at 20°: 0.83 where this gives 0.94.
    normalised = {"mode": "normalised", "white_plane_photons": 200.0}
    altitude, depth, nadir = 90.0, 1.0, math.radians(20.0)
    flat = disk_scene(altitude, depth=depth, reflectance=1.0, radiometry=normalised)
    oblique = flat.model_copy(
        update={"platform": flat.platform.model_copy(update={"nadir_deg": 20.0})}
    )
    values = [centre(render(s, seed=1).expected.values[0, 0]) for s in (flat, oblique)]
    inside = math.asin(math.sin(nadir) / N_WATER)
    t = 1.0 - float(fresnel_reflectance(math.cos(nadir), n1=1.0, n2=N_WATER))
    slant, path = altitude / math.cos(nadir), depth / math.cos(inside)
    spread = (slant / (slant + path / N_WATER)) ** 2 / (
        altitude / (altitude + depth / N_WATER)
    ) ** 2
    expected = t**2 / T0**2 * math.cos(nadir) * math.exp(-2 * K * (path - depth)) * spread
    assert_allclose(values[1] / values[0], expected, rtol=0.01)
    assert abs(values[1] / values[0] - expected * math.cos(nadir) ** 2) > 0.1


def test_units_follow_the_mode_and_gain():
    s = disk_scene(50.0)
    s = Scene.model_validate({**s.model_dump(), "noise": {"gain": 10.0, "excess_noise": 1.0}})
    gained = render(s, seed=1)
    # CF units are "1" throughout; the long name says what is counted
    assert gained.image.attrs["long_name"].startswith("ICCD output count")
    assert gained.image.dtype == np.float32  # gain: not whole photoelectrons
    assert gained.expected.attrs["long_name"] == "expected photoelectron count (noise-free)"
    quiet = disk_scene(50.0, radiometry={"mode": "normalised", "white_plane_photons": 0})
    ds = render(quiet, seed=1)
    assert ds.image.attrs["units"] == ds.expected.attrs["units"] == gained.image.attrs["units"]
    assert ds.image.attrs["units"] == "1" and ds.image.dtype == np.float32
    assert "white plane" in ds.image.attrs["long_name"]


@pytest.mark.parametrize(
    ("radiometry", "fragment"),
    [
        ({"mode": "normalised"}, "white_plane_photons"),
        ({"mode": "absolute", "white_plane_photons": 10.0}, "white_plane_photons"),
        ({"pulse_energy": 0.0}, "pulse_energy"),
        ({"quantum_efficiency": 1.5}, "quantum_efficiency"),
    ],
    ids=["normalised-needs-photons", "absolute-refuses-photons", "no-energy", "qe-above-1"],
)
def test_inconsistent_radiometry_is_refused(radiometry, fragment):
    with pytest.raises(ValidationError, match=fragment):
        Scene.model_validate({"radiometry": radiometry})


def test_old_noise_photons_names_its_new_place():
    with pytest.raises(ValidationError, match=r"radiometry\.white_plane_photons"):
        Scene.model_validate({"noise": {"photons": 13.0}})


def test_default_is_absolute_and_the_flagship_config_uses_it():
    from pathlib import Path

    assert Scene().radiometry.mode == "absolute"
    root = Path(__file__).resolve().parents[1]
    flagship = yaml.safe_load((root / "configs" / "mldc-detection.yaml").read_text())
    assert Scene.model_validate(flagship["scene"]).radiometry.mode == "absolute"
    assert "platform.altitude" in flagship["sweep"]["parameters"]
    for path in sorted((root / "configs" / "paper").glob("*.yaml")):
        paper = yaml.safe_load(path.read_text())
        assert Scene.model_validate(paper["scene"]).radiometry.mode == "normalised", path.name
