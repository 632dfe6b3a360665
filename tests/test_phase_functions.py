"""workers.optics.phases: the phase-function plug-ins, their registry and derived quantities."""

import itertools

import numpy as np
import pytest
from pydantic import ValidationError
from scipy import integrate, stats

from workers.montecarlo.renderer import phase_record
from workers.montecarlo.scattering import phase_value, scattering_angle
from workers.optics.phases.base import (
    BETA_PI_PER_BACKSCATTER,
    PHASE_FUNCTIONS,
    PhaseFunction,
    phase_named,
)
from workers.optics.phases.fournier_forand import FournierForand
from workers.optics.phases.henyey_greenstein import (
    HenyeyGreenstein,
    henyey_greenstein_backscatter,
)
from workers.optics.phases.paper import paper_phase_function
from workers.optics.phases.petzold import _TABLE as PETZOLD_TABLE
from workers.optics.phases.petzold import Petzold
from workers.optics.water import WaterOptics
from workers.render import render_arrays
from workers.settings.scene import Scene
from workers.settings.transport import Transport

SPHERE = {"epsabs": 0, "epsrel": 1e-12, "limit": 200}


def over_sphere(phase, weight=lambda theta: 1.0, low=0.0):
    """2π ∫ β̃ w sin θ dθ over [low, π] by adaptive quadrature, split at small angles."""
    total = 0.0
    edges = [low, 1e-3, 1e-2, 0.1, 1.0, np.pi]
    for a, b in itertools.pairwise(edges):
        if b <= low:
            continue
        part, _ = integrate.quad(
            lambda t: 2 * np.pi * phase.value(t) * weight(t) * np.sin(t), max(a, low), b, **SPHERE
        )
        total += part
    return total


# --- registry and settings -------------------------------------------------------------


def test_the_registry_names_every_function_and_the_settings_take_them_from_it():
    assert {"fournier_forand", "paper", "wells", "henyey_greenstein"} <= set(PHASE_FUNCTIONS)
    assert all(issubclass(f, PhaseFunction) for f in PHASE_FUNCTIONS.values())
    schema = Scene.model_json_schema()["$defs"]
    assert schema["Water"]["properties"]["phase_function"]["enum"] == sorted(PHASE_FUNCTIONS)
    spherical = sorted(n for n, f in PHASE_FUNCTIONS.items() if f.spherical)
    assert schema["Transport"]["properties"]["phase_function"]["enum"] == spherical
    assert "wells" not in spherical and "henyey_greenstein" in spherical
    with pytest.raises(KeyError, match=r"choose from .*fournier_forand"):
        phase_named("rayleigh")


def test_an_unknown_or_unsampleable_phase_function_is_refused_naming_the_field():
    with pytest.raises(ValidationError, match=r"water\.phase_function[\s\S]*choose from"):
        Scene.model_validate({"water": {"phase_function": "rayleigh"}})
    with pytest.raises(ValidationError, match=r"phase_function[\s\S]*small angles only"):
        Transport.model_validate({"phase_function": "wells"})
    with pytest.raises(ValidationError, match=r"phase_function[\s\S]*not registered"):
        Transport.model_validate({"phase_function": "rayleigh"})


# --- shared derivations against closed forms -------------------------------------------


@pytest.mark.parametrize("fraction", [0.005, 0.013, 0.044], ids=lambda b: f"B{b}")
def test_fournier_forand_closed_forms_equal_the_shared_quadrature(fraction):
    ff = FournierForand(fraction=fraction)
    numeric = PhaseFunction.backscatter_fraction(ff)  # the base class's quadrature
    np.testing.assert_allclose(ff.backscatter_fraction(), numeric, rtol=1e-9)
    np.testing.assert_allclose(ff.backscatter_fraction(), fraction, rtol=1e-8)
    shared = PhaseFunction.backscatter_pi_per_backscatter(ff)
    np.testing.assert_allclose(ff.backscatter_pi_per_backscatter(), shared, rtol=1e-7)


@pytest.mark.parametrize("fraction", [0.005, 0.0183, 0.1, 0.3], ids=lambda b: f"B{b}")
def test_henyey_greenstein_is_normalised_with_mean_cosine_g_and_its_backscatter(fraction):
    hg = HenyeyGreenstein.for_water(backscatter_fraction=fraction, theta0=0.12)
    assert 0 < hg.g < 1
    # normalisation and mean cosine = g (Henyey & Greenstein 1941), quadrature to 1e-9
    np.testing.assert_allclose(over_sphere(hg), 1.0, rtol=1e-9)
    np.testing.assert_allclose(over_sphere(hg, np.cos), hg.g, rtol=1e-9)
    # b_b/b: the closed form (1-g)/(2g) ((1+g)/sqrt(1+g²) - 1) = the water's = quadrature
    np.testing.assert_allclose(hg.backscatter_fraction(), fraction, rtol=1e-12)
    numeric = PhaseFunction.backscatter_fraction(hg)
    np.testing.assert_allclose(hg.backscatter_fraction(), numeric, rtol=1e-10)
    np.testing.assert_allclose(over_sphere(hg, low=np.pi / 2), fraction, rtol=1e-9)
    # g = 0.5: B = (1/2)(1.5/sqrt(1.25) - 1) = 0.170820... (hand value)
    np.testing.assert_allclose(henyey_greenstein_backscatter(0.5), 0.1708203932, rtol=1e-9)


def test_henyey_greenstein_table_draws_follow_its_cumulative():
    # closed-form cumulative F(θ) = (1-g²)/(2g) ((1+g²-2g cos θ)^-1/2 - 1/(1+g)); a
    # Kolmogorov-Smirnov test of 20 000 draws (fixed seed): p > 1e-3 unless the table is off
    hg = HenyeyGreenstein.for_water(backscatter_fraction=0.0183, theta0=0.12)
    g, table = hg.g, hg.table()
    u = np.random.default_rng(5).uniform(size=20_000)
    theta = np.interp(u, np.linspace(0, 1, table.quantiles.size), table.quantiles)
    cumulative = (
        (1 - g * g) / (2 * g) * ((1 + g * g - 2 * g * np.cos(theta)) ** -0.5 - 1 / (1 + g))
    )
    assert stats.kstest(cumulative, "uniform").pvalue > 1e-3
    # and the table's own tallies: β̃(π) and the backscatter fraction to the grid's accuracy
    np.testing.assert_allclose(table.backscatter_pi, hg.backscatter_pi(), rtol=1e-12)
    np.testing.assert_allclose(table.backscatter_fraction, 0.0183, rtol=1e-3)


def test_henyey_greenstein_gives_the_fast_renderer_its_beta_pi_and_mtf():
    water = WaterOptics(
        absorption=0.2, scattering=0.5, backscatter=0.01, phase_function="henyey_greenstein"
    )
    hg = water.phase()
    assert isinstance(hg, HenyeyGreenstein)
    # β(π) = b β̃(π): the water's own, not Petzold's 0.174 b_b
    np.testing.assert_allclose(water.backscatter_pi, 0.5 * hg.backscatter_pi(), rtol=1e-12)
    psi = np.geomspace(1e-3, 1e5, 60)
    d = water.mtf_exponent(psi)
    assert d[0] == pytest.approx(1.0, abs=1e-4) and np.all(np.diff(d) < 0) and d[-1] > 0


def test_a_water_henyey_greenstein_cannot_meet_is_refused_naming_the_field():
    water = {"preset": None, "absorption": 0.1, "scattering": 0.4, "backscatter": 0.2}
    match = r"water\.backscatter: b_b/b = 0\.5 .* water\.phase_function henyey_greenstein"
    with pytest.raises(ValidationError, match=match):
        Scene.model_validate({"water": {**water, "phase_function": "henyey_greenstein"}})


# --- both renderers --------------------------------------------------------------------


def small_scene(method, name, preset="coastal"):
    """A 16 px flat-sea scene rendered with phase function `name`."""
    return Scene.model_validate(
        {
            "surface": {"spectrum": "flat"},
            "receiver": {"pixels": 16},
            "radiometry": {"mode": "normalised", "white_plane_photons": 0.0},
            "water": {"preset": preset, "phase_function": name},
            "transport": {"method": method, "phase_function": name, "photons": 20_000},
        }
    )


@pytest.mark.parametrize("method", ["small_angle", "monte_carlo"])
def test_a_scene_renders_with_henyey_greenstein_in_both_renderers(method):
    image = render_arrays(small_scene(method, "henyey_greenstein"), seed=1)["expected"]
    assert np.all(np.isfinite(image)) and np.all(image >= 0) and image.sum() > 0
    if method == "small_angle":
        assert np.all(image > 0)


# --- Petzold's San Diego harbour table --------------------------------------------------


def test_petzold_is_normalised_and_holds_its_table():
    petzold = Petzold()
    np.testing.assert_allclose(over_sphere(petzold), 1.0, rtol=1e-4)  # log-log cells, 400 001
    # its cumulative at the table's angles is Petzold's F(θ) (Mobley et al. 1993), to the
    # interpolation of β̃ within cells: 1.5e-3 absolute
    theta = np.radians(PETZOLD_TABLE[:, 0])
    forward = np.array([over_sphere(petzold) - over_sphere(petzold, low=t) for t in theta[:-1]])
    np.testing.assert_allclose(forward, PETZOLD_TABLE[:-1, 1], atol=1.5e-3)
    # b_b/b = 1 - F(90°) = 0.01809; β̃(π) near Mobley's (1994, Table 3.10) 3.18e-3 sr⁻¹
    np.testing.assert_allclose(petzold.backscatter_fraction(), 0.018092, rtol=2e-3)
    np.testing.assert_allclose(petzold.backscatter_pi(), 3.18e-3, rtol=0.05)


def test_petzold_table_draws_follow_its_cumulative():
    # 20 000 draws (seed 7): the Dvoretzky-Kiefer-Wolfowitz bound at p = 1e-3,
    # sqrt(ln(2/1e-3) / (2N)) = 0.0138, plus the table's own 1.5e-3
    table = Petzold().table()
    draws = np.interp(
        np.random.default_rng(7).uniform(size=20_000),
        np.linspace(0, 1, table.quantiles.size),
        table.quantiles,
    )
    theta = np.radians(PETZOLD_TABLE[:, 0])
    empirical = np.searchsorted(np.sort(draws), theta) / draws.size
    assert np.max(np.abs(empirical - PETZOLD_TABLE[:, 1])) < 0.0138 + 1.5e-3


def test_a_water_far_from_petzolds_backscatter_is_refused_naming_the_field():
    # coastal b_b/b = 0.013 is 28 % below the table's 0.0181; turbid harbour's 0.019 goes
    match = r"water\.backscatter: b_b/b = 0\.013.* water\.phase_function petzold"
    with pytest.raises(ValidationError, match=match):
        Scene.model_validate({"water": {"preset": "coastal", "phase_function": "petzold"}})
    Scene.model_validate({"water": {"preset": "turbid_harbour", "phase_function": "petzold"}})


@pytest.mark.parametrize("method", ["small_angle", "monte_carlo"])
def test_a_scene_renders_with_petzold_in_both_renderers(method):
    image = render_arrays(small_scene(method, "petzold", "turbid_harbour"), seed=1)["expected"]
    assert np.all(np.isfinite(image)) and np.all(image >= 0) and image.sum() > 0


# --- the paper's water (issue #40, item 1) ----------------------------------------------

PAPER_THETA0 = 0.12  # the paper's §4.4
PAPER_FRACTIONS = pytest.mark.parametrize(
    "fraction", [0.0, 0.0183, 0.0385], ids=lambda b: f"B{b}"
)  # b_b = 0 (Examples 1–2), Petzold's average, Examples 3–4 (0.0154 / 0.4)


def paper(fraction):
    return phase_named("paper").for_water(backscatter_fraction=fraction, theta0=PAPER_THETA0)


@PAPER_FRACTIONS
def test_paper_is_the_papers_forward_shape_with_the_waters_backscatter(fraction):
    # One water in both renderers: over the sphere 1, backward b_b/b, β̃(π) = 0.174 b_b/b
    # (the fast renderer's β(π) = 0.174 b_b, Mobley 1994 Table 3.10), forward ∝ s(θ).
    p = paper(fraction)
    assert over_sphere(p) == pytest.approx(1.0, rel=1e-7)
    assert over_sphere(p, low=0.5 * np.pi) == pytest.approx(fraction, rel=1e-9, abs=1e-12)
    assert p.value(np.pi) == pytest.approx(BETA_PI_PER_BACKSCATTER * fraction, rel=1e-12)
    assert p.backscatter_pi_per_backscatter() == BETA_PI_PER_BACKSCATTER
    theta = np.geomspace(1e-5, 0.5 * np.pi, 400)
    ratio = p.value(theta) / paper_phase_function(theta, theta0=PAPER_THETA0)
    np.testing.assert_allclose(ratio, ratio[0], rtol=1e-12)


@PAPER_FRACTIONS
def test_paper_table_draws_follow_the_function_and_its_backward_share(fraction):
    # The Monte Carlo's draws (its kernel `scattering_angle` on the table's quantiles, fixed
    # seed) against quadratures of `value`: each angle bin within 4σ of its binomial count
    # plus the table's interpolation (1e-4); the backward share 4σ of b_b/b, none if b_b = 0.
    p, n = paper(fraction), 400_000
    table = p.table()
    u = np.random.default_rng(40).uniform(size=n)
    theta = np.array([scattering_angle(x, table.quantiles) for x in u])
    edges = [0.0, 1e-3, 1e-2, 0.05, 0.12, 0.3, 0.7, 0.5 * np.pi, 2.0, 2.6, np.pi]
    counts = np.histogram(theta, edges)[0] / n
    expected = np.array(
        [over_sphere(p, low=a) - over_sphere(p, low=b) for a, b in itertools.pairwise(edges)]
    )
    sigma = np.sqrt(expected * (1 - expected) / n)
    np.testing.assert_array_less(np.abs(counts - expected), 4 * sigma + 1e-4)
    back = np.mean(theta > 0.5 * np.pi)
    assert abs(back - fraction) <= 4 * np.sqrt(fraction * (1 - fraction) / n)
    assert table.backscatter_pi == pytest.approx(BETA_PI_PER_BACKSCATTER * fraction, rel=1e-12)
    # the kernel's value: finite everywhere, β̃(π) at π, ~0 backward when b_b = 0
    record = phase_record(table)
    angles = np.linspace(1e-4, np.pi, 2001)
    values = [phase_value(np.cos(t), np.sin(t), record) for t in angles]
    assert np.all(np.isfinite(values))
    assert values[-1] == pytest.approx(BETA_PI_PER_BACKSCATTER * fraction, rel=1e-6, abs=1e-300)
