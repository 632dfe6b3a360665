"""workers.optics.water: Petzold IOPs, Wells' MTF, and the gated backscatter reflectance."""

import dataclasses
import functools

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy import integrate, special

from workers.optics.hankel import hankel_mtf_exponent
from workers.optics.phases.base import BETA_PI_PER_BACKSCATTER
from workers.optics.phases.fournier_forand import (
    FournierForand,
    fit_fournier_forand,
    fournier_forand,
)
from workers.optics.phases.paper import Paper, paper_phase_function
from workers.optics.phases.wells import wells_mtf_exponent, wells_phase_function
from workers.optics.water import (
    PRESETS,
    WaterOptics,
    slab_backscatter_centroid,
    slab_backscatter_reflectance,
)

THETA0 = 0.12  # paper §4.4
FEET = 0.3048

# Petzold (1972) via Mobley (1994), Light and Water, Table 3.10: a, b, c [1/m], B = b_b/b.
PETZOLD_TABLE = {
    "clear_ocean": (0.114, 0.037, 0.151, 0.044),
    "coastal": (0.179, 0.219, 0.398, 0.013),
    "turbid_harbour": (0.366, 1.824, 2.190, 0.019),
}
PRESET_NAMES = pytest.mark.parametrize("name", sorted(PETZOLD_TABLE), ids=sorted(PETZOLD_TABLE))
PHASE_FUNCTIONS = pytest.mark.parametrize("phase_function", ["paper", "wells"], ids=str)


def frequency_grid(size=96, spacing=0.02):
    """Frequency magnitude of an rfft2 grid [cycles/m]."""
    fy = np.fft.fftfreq(size, d=spacing)
    fx = np.fft.rfftfreq(size, d=spacing)
    return np.hypot(fy[:, None], fx[None, :])


# ------------------------------------------------------------------------- presets


@PRESET_NAMES
def test_presets_match_petzold_table(name):
    a, b, c, fraction = PETZOLD_TABLE[name]
    preset = PRESETS[name]
    assert_allclose(preset["absorption"], a, rtol=1e-12)
    assert_allclose(preset["scattering"], b, rtol=1e-12)
    assert_allclose(preset["backscatter"] / preset["scattering"], fraction, rtol=1e-12)
    water = WaterOptics.from_preset(name)
    assert_allclose(water.attenuation, c, rtol=1e-12)


@PRESET_NAMES
def test_derived_coefficients(name):
    water = WaterOptics.from_preset(name)
    b_b = water.backscatter
    assert_allclose(water.forward_scattering, water.scattering - b_b, rtol=1e-14)
    # K = c - b_f = a + b_b (paper §4.4: K_d = c - b_f).
    assert_allclose(water.diffuse_attenuation, water.absorption + b_b, rtol=1e-14)
    assert_allclose(water.backscatter_pi, BETA_PI_PER_BACKSCATTER * b_b, rtol=1e-14)


def test_beta_pi_ratio_from_petzold_particle_phase_function():
    # Mobley (1994) Table 3.10, average particle phase function: β̃(180°) = 3.18e-3 1/sr,
    # b̃_b = 0.0183.
    assert_allclose(BETA_PI_PER_BACKSCATTER, 3.18e-3 / 0.0183, rtol=2e-3)


def test_from_preset_overrides_and_validation():
    water = WaterOptics.from_preset("coastal", theta0=0.1, phase_function="wells")
    assert (water.theta0, water.phase_function, water.absorption) == (0.1, "wells", 0.179)
    with pytest.raises(ValueError, match="unknown water preset"):
        WaterOptics.from_preset("lagoon")
    with pytest.raises(ValueError, match="backscatter"):
        WaterOptics(absorption=0.1, scattering=0.1, backscatter=0.2)
    with pytest.raises(ValueError, match="phase_function"):
        WaterOptics(absorption=0.1, scattering=0.1, backscatter=0.01, phase_function="hg")
    with pytest.raises(dataclasses.FrozenInstanceError):
        water.absorption = 1.0


# ----------------------------------------------------------------------------- MTF


@PHASE_FUNCTIONS
@PRESET_NAMES
def test_mtf_at_zero_frequency_is_diffuse_attenuation(name, phase_function):
    # MTF(0) = exp(-(c - b_f) z) = exp(-K_d z), paper §4.4.
    water = WaterOptics.from_preset(name, phase_function=phase_function)
    for distance in (0.5, 5.0, 15.0):
        mtf = water.mtf(np.array([0.0]), distance=distance)
        assert_allclose(mtf, np.exp(-water.diffuse_attenuation * distance), rtol=1e-6)


@PHASE_FUNCTIONS
def test_mtf_decreases_to_beam_attenuation(phase_function):
    water = WaterOptics.from_preset("turbid_harbour", phase_function=phase_function)
    distance = 6.0
    frequency = np.concatenate([[0.0], np.geomspace(1e-3, 1e9, 400)])
    mtf = water.mtf(frequency, distance=distance)
    assert np.all(np.diff(mtf) <= 0)
    # MTF(∞) = exp(-c z): D → 0 as ψ → ∞.
    assert_allclose(mtf[-1], np.exp(-water.attenuation * distance), rtol=1e-3)


@PHASE_FUNCTIONS
def test_mtf_float32_grid_and_zero_distance(phase_function):
    water = WaterOptics.from_preset("coastal", phase_function=phase_function)
    frequency = frequency_grid()
    mtf = water.mtf(frequency, distance=8.0)
    assert mtf.dtype == np.float32
    assert mtf.shape == frequency.shape
    assert np.all((mtf > 0) & (mtf <= 1))
    assert np.all(water.mtf(frequency, distance=0.0) == 1)
    with pytest.raises(ValueError, match="distance"):
        water.mtf(frequency, distance=-1.0)


def test_mtf_depends_on_frequency_times_distance():
    # MTF(f; z) = exp(-c z + b_f z D(f z)), Wells (1973).
    water = WaterOptics.from_preset("coastal", phase_function="paper")
    frequency = frequency_grid()
    expected = np.exp(
        -water.attenuation * 4.0
        + water.forward_scattering
        * 4.0
        * Paper(theta0=THETA0, fraction=0.0183).mtf_exponent(frequency * 4.0)
    )
    assert_allclose(water.mtf(frequency, distance=4.0), expected, rtol=1e-6)


# ------------------------------------------------------------------- MTF exponent D


def test_wells_closed_form_matches_numerical_hankel_transform():
    psi = np.geomspace(1e-2, 1e3, 61)
    numerical = hankel_mtf_exponent(
        functools.partial(wells_phase_function, theta0=THETA0), psi, theta_max=np.inf
    )
    assert_allclose(numerical, wells_mtf_exponent(psi, theta0=THETA0), rtol=1e-4)


def test_wells_exponent_limits():
    assert wells_mtf_exponent(0.0, theta0=THETA0) == 1.0
    assert_allclose(wells_mtf_exponent(1e-12, theta0=THETA0), 1.0, rtol=1e-11)
    # D → 1/(2π θ0 ψ) for large ψ.
    assert_allclose(wells_mtf_exponent(1e6, theta0=THETA0), 1 / (2 * np.pi * THETA0 * 1e6))


@pytest.mark.parametrize("theta0", [0.05, THETA0, 0.3], ids=["0.05", "paper", "0.3"])
def test_phase_functions_are_normalised(theta0):
    # Σ(0) = 2π ∫ s θ dθ = 1 (paper §4.4); u = √θ removes the θ^(-1/2) singularity.
    paper = integrate.quad(
        lambda u: 2 * np.pi * paper_phase_function(u * u, theta0=theta0) * u**3 * 2,
        0,
        np.sqrt(np.pi),
        epsabs=1e-13,
        limit=200,
    )[0]
    wells = integrate.quad(
        lambda t: 2 * np.pi * wells_phase_function(t, theta0=theta0) * t, 0, np.inf
    )[0]
    assert_allclose([paper, wells], 1.0, rtol=1e-9)
    assert paper_phase_function(3.2, theta0=theta0) == 0.0  # support is [0, π]


def test_paper_exponent_shape():
    psi = np.concatenate([[0.0], np.geomspace(1e-6, 1e8, 3000)])
    exponent = Paper(theta0=THETA0, fraction=0.0183).mtf_exponent(psi)
    assert exponent[0] == 1.0  # D(0) = Σ(0) = 1, paper §4.4
    assert np.all((exponent > 0) & (exponent <= 1))
    assert np.all(np.diff(exponent) <= 0)


def test_paper_table_matches_direct_transform():
    # Off-grid points of the cached table against the direct Hankel transform.
    psi = np.geomspace(3.3e-3, 7.7e5, 97)
    direct = hankel_mtf_exponent(
        functools.partial(paper_phase_function, theta0=THETA0), psi, theta_max=np.pi
    )
    assert_allclose(Paper(theta0=THETA0, fraction=0.0183).mtf_exponent(psi), direct, atol=5e-5)


@pytest.mark.parametrize("psi", [0.1, 1.0, 10.0], ids=["psi0.1", "psi1", "psi10"])
def test_paper_exponent_against_adaptive_quadrature(psi):
    # D(ψ) = 2π ∫ s(θ) θ Λ(2πθψ) dθ, Λ(x) = (1/x) ∫₀ˣ J0 (Struve form), θ = u².
    def integrand(u):
        x = 2 * np.pi * u * u * psi
        integral_j0 = x * special.j0(x) + np.pi * x / 2 * (
            special.j1(x) * special.struve(0, x) - special.j0(x) * special.struve(1, x)
        )
        s = paper_phase_function(u * u, theta0=THETA0)
        return 2 * np.pi * s * u**3 * 2 * (integral_j0 / x if x > 0 else 1.0)

    knee = 1 / np.sqrt(2 * np.pi * psi)
    oracle = integrate.quad(
        integrand, 0, np.sqrt(np.pi), points=[knee, 2 * knee], limit=500, epsabs=1e-12
    )[0]
    assert_allclose(Paper(theta0=THETA0, fraction=0.0183).mtf_exponent(psi), oracle, rtol=5e-5)
    direct = hankel_mtf_exponent(
        functools.partial(paper_phase_function, theta0=THETA0), psi, theta_max=np.pi
    )
    assert_allclose(direct, oracle, rtol=2e-5)


def test_paper_exponent_large_psi_asymptote():
    # θ^(-3/2) core: D ≈ (2π s0/θ0) (2πψ)^(-1/2) ∫₀^∞ x^(-1/2) Λ(x) dx, and
    # ∫ x^(-1/2) Λ = 2 ∫ t^(-1/2) J0(t) dt = √2 Γ(1/4)/Γ(3/4) (DLMF 10.22.43).
    s0 = paper_phase_function(1.0, theta0=THETA0) * np.sqrt(THETA0**2 + 1.0)
    mellin = np.sqrt(2) * special.gamma(0.25) / special.gamma(0.75)
    psi = np.array([1e4, 1e5, 1e6, 1e8])
    asymptote = 2 * np.pi * s0 / THETA0 * (2 * np.pi * psi) ** -0.5 * mellin
    ratio = Paper(theta0=THETA0, fraction=0.0183).mtf_exponent(psi) / asymptote
    assert_allclose(ratio, 1.0, rtol=1e-2)
    assert np.all(np.diff(np.abs(ratio[:3] - 1)) < 0)  # converging as ψ^(-1/2)


def test_hankel_transform_ignores_normalisation_and_rejects_divergent():
    psi = np.array([0.0, 0.3, 30.0])
    wells = functools.partial(wells_phase_function, theta0=THETA0)
    assert_allclose(
        hankel_mtf_exponent(lambda t: 7.0 * wells(t), psi, theta_max=np.inf),
        hankel_mtf_exponent(wells, psi, theta_max=np.inf),
        rtol=1e-13,
    )
    assert hankel_mtf_exponent(wells, 0.0, theta_max=np.inf) == pytest.approx(1.0, abs=1e-14)
    with pytest.raises(ValueError, match="not integrable"):
        hankel_mtf_exponent(lambda t: t**-2.5, psi, theta_max=np.pi)


# ------------------------------------------------------------------ gated backscatter

GATES = pytest.mark.parametrize(
    ("top", "bottom"),
    [(12 * FEET, 32 * FEET), (25 * FEET, 40 * FEET), (40 * FEET, 50 * FEET)],
    ids=["mldc_12_32ft", "mldc_25_40ft", "mldc_40_50ft"],
)


@GATES
@PRESET_NAMES
def test_slab_reflectance_is_paper_formula_at_gate_top(name, top, bottom):
    # R = s_b/(2K) (1 - e^(-2K ΔZ)), s_b = π β(π) (paper §4.6).
    water = WaterOptics.from_preset(name)
    k = water.diffuse_attenuation
    s_b = np.pi * water.backscatter_pi
    expected = s_b / (2 * k) * (1 - np.exp(-2 * k * (bottom - top)))
    reflectance = slab_backscatter_reflectance(
        backscatter_pi=water.backscatter_pi,
        diffuse_attenuation=k,
        top=top,
        bottom=bottom,
        reference=top,
    )
    assert_allclose(reflectance, expected, rtol=1e-13)


@GATES
@pytest.mark.parametrize("k", [0.05, 0.4, 2.2], ids=["K0.05", "K0.4", "K2.2"])
def test_slab_reflectance_matches_quadrature(k, top, bottom):
    beta_pi = 2e-3
    for reference in (
        0.0,
        top,
        slab_backscatter_centroid(diffuse_attenuation=k, top=top, bottom=bottom),
    ):
        oracle = integrate.quad(
            lambda z, ref=reference: np.pi * beta_pi * np.exp(-2 * k * (z - ref)), top, bottom
        )[0]
        reflectance = slab_backscatter_reflectance(
            backscatter_pi=beta_pi,
            diffuse_attenuation=k,
            top=top,
            bottom=bottom,
            reference=reference,
        )
        assert_allclose(reflectance, oracle, rtol=1e-12)


def test_slab_reflectance_without_attenuation():
    # K → 0: R → π β(π) ΔZ, no division by zero.
    for k in (0.0, 1e-14):
        reflectance = slab_backscatter_reflectance(
            backscatter_pi=1e-3, diffuse_attenuation=k, top=2.0, bottom=5.0, reference=2.0
        )
        assert_allclose(reflectance, np.pi * 1e-3 * 3.0, rtol=1e-12)
    with pytest.raises(ValueError, match="top <= bottom"):
        slab_backscatter_reflectance(
            backscatter_pi=1e-3, diffuse_attenuation=0.1, top=5.0, bottom=2.0, reference=2.0
        )


@GATES
@pytest.mark.parametrize(
    "k", [1e-9, 0.05, 0.4, 2.2, 500.0], ids=["K1e-9", "K0.05", "K0.4", "K2.2", "K500"]
)
def test_slab_centroid_matches_quadrature(k, top, bottom):
    centroid = slab_backscatter_centroid(diffuse_attenuation=k, top=top, bottom=bottom)
    assert top <= centroid <= 0.5 * (top + bottom)
    u_max = bottom - top  # integrate over u = z - top to keep the weights O(1)
    weight = integrate.quad(lambda u: np.exp(-2 * k * u), 0, u_max, epsabs=0, epsrel=1e-13)[0]
    moment = integrate.quad(lambda u: u * np.exp(-2 * k * u), 0, u_max, epsabs=0, epsrel=1e-13)[0]
    assert_allclose(centroid, top + moment / weight, rtol=1e-11)


def test_slab_centroid_tends_to_midpoint():
    ks = np.array([0.0, 1e-12, 1e-6, 1e-4])
    centroid = slab_backscatter_centroid(diffuse_attenuation=ks, top=3.0, bottom=9.0)
    assert_allclose(centroid, 6.0, atol=2e-3)
    assert centroid[0] == 6.0
    assert np.all(np.diff(centroid) < 0)  # moves up as K grows


@pytest.mark.parametrize("fraction", [0.013, 0.044])
def test_fournier_forand_exponent_is_the_transform_of_its_forward_half(fraction):
    # Wells' D of the forward half (θ ≤ π/2) of the Fournier-Forand function the Monte
    # Carlo renderer samples, its 3-D measure sin θ dθ written in the small-angle θ dθ:
    # the cached table against the direct transform, D(0) = 1, decreasing.
    n, mu = fit_fournier_forand(fraction)

    def forward(theta):
        return fournier_forand(theta, n=n, mu=mu) * np.sin(theta) / theta

    psi = np.geomspace(3.3e-3, 7.7e5, 61)
    direct = hankel_mtf_exponent(forward, psi, theta_max=np.pi / 2)
    table = FournierForand(fraction=fraction).mtf_exponent(psi)
    assert_allclose(table, direct, atol=5e-5)
    grid = np.concatenate([[0.0], np.geomspace(1e-6, 1e8, 2000)])
    exponent = FournierForand(fraction=fraction).mtf_exponent(grid)
    assert exponent[0] == 1.0 and np.all(np.diff(exponent) <= 0) and np.all(exponent > 0)
    # beyond the table, D ∝ ψ^-(μ-3) (the θ^-(5-μ) core), continuous at the table's end
    assert_allclose(
        FournierForand(fraction=fraction).mtf_exponent(1e7)
        / FournierForand(fraction=fraction).mtf_exponent(1e6),
        10.0 ** -(mu - 3.0),
        rtol=1e-12,
    )


def test_default_water_spreads_as_the_monte_carlo_phase_function():
    # The fast renderer's default D is the fitted Fournier-Forand one, not the paper's
    water = WaterOptics.from_preset("coastal")
    assert water.phase_function == "fournier_forand"
    psi = np.geomspace(1.0, 30.0, 4)
    fraction = water.backscatter / water.scattering
    assert_allclose(
        water.mtf_exponent(psi),
        FournierForand(fraction=fraction).mtf_exponent(psi),
        rtol=1e-12,
    )
    # narrower: coastal water's forward peak holds its light nearer the beam
    assert np.all(
        water.mtf_exponent(psi) > Paper(theta0=0.12, fraction=0.0183).mtf_exponent(psi) + 0.05
    )
