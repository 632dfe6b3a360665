"""Tests for workers.optics.fresnel: Fresnel reflectance and vector Snell refraction."""

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from workers.optics.fresnel import (
    fresnel_reflectance,
    fresnel_unpolarised,
    reflect,
    refract,
    snell_cos_t,
    transmitted_cosine,
)

N_WATER = 1.34  # paper §4.3
AIR_TO_WATER = {"n1": 1.0, "n2": N_WATER}
WATER_TO_AIR = {"n1": N_WATER, "n2": 1.0}
DIRECTIONS = pytest.mark.parametrize(
    "indices", [AIR_TO_WATER, WATER_TO_AIR], ids=["air_to_water", "water_to_air"]
)
CRITICAL = np.arcsin(1.0 / N_WATER)  # water → air


def transmitted_angle(theta, *, n1, n2):
    return np.arcsin(n1 / n2 * np.sin(theta))


def paper_fresnel(theta, *, n1, n2):
    """The paper's §4.3 sin/tan form (0/0 at normal incidence)."""
    theta_t = transmitted_angle(theta, n1=n1, n2=n2)
    minus, plus = theta - theta_t, theta + theta_t
    return 0.5 * (np.sin(minus) ** 2 / np.sin(plus) ** 2 + np.tan(minus) ** 2 / np.tan(plus) ** 2)


def oblique_angles(*, n1, n2, count=50):
    """Angles of incidence strictly inside (0, 90°) and below any critical angle."""
    limit = np.arcsin(n2 / n1) if n1 > n2 else np.pi / 2
    return np.linspace(0.01, limit - 0.01, count)


# --------------------------------------------------------------------------- Fresnel


@DIRECTIONS
def test_fresnel_normal_incidence(indices):
    # r(0) = ((n_w - 1)/(n_w + 1))², paper §4.3 and Mobley (1994) §4.2.
    expected = ((N_WATER - 1) / (N_WATER + 1)) ** 2
    assert_allclose(fresnel_reflectance(1.0, **indices), expected, rtol=1e-14)
    assert_allclose(fresnel_reflectance(-1.0, **indices), expected, rtol=1e-14)


@DIRECTIONS
def test_fresnel_matches_paper_sin_tan_form(indices):
    theta = oblique_angles(**indices)
    assert_allclose(
        fresnel_reflectance(np.cos(theta), **indices), paper_fresnel(theta, **indices), rtol=1e-12
    )


@DIRECTIONS
def test_fresnel_energy_conservation(indices):
    # T from the amplitude transmission coefficients (Born & Wolf §1.5.2):
    # t_s = 2 n1 cos_i / (n1 cos_i + n2 cos_t), t_p = 2 n1 cos_i / (n2 cos_i + n1 cos_t),
    # T = (n2 cos_t)/(n1 cos_i) · (t_s² + t_p²)/2.
    n1, n2 = indices["n1"], indices["n2"]
    theta = oblique_angles(**indices)
    cos_i = np.cos(theta)
    cos_t = np.cos(transmitted_angle(theta, **indices))
    t_s = 2 * n1 * cos_i / (n1 * cos_i + n2 * cos_t)
    t_p = 2 * n1 * cos_i / (n2 * cos_i + n1 * cos_t)
    transmittance = n2 * cos_t / (n1 * cos_i) * 0.5 * (t_s**2 + t_p**2)
    assert_allclose(fresnel_reflectance(cos_i, **indices) + transmittance, 1.0, rtol=1e-13)


def test_fresnel_reciprocity():
    theta_air = oblique_angles(**AIR_TO_WATER)
    theta_water = transmitted_angle(theta_air, **AIR_TO_WATER)
    assert_allclose(
        fresnel_reflectance(np.cos(theta_air), **AIR_TO_WATER),
        fresnel_reflectance(np.cos(theta_water), **WATER_TO_AIR),
        rtol=1e-12,
    )


def test_critical_angle_matches_paper():
    # "the critical incident angle of 48 deg" (paper §4.3): asin(1/1.34) = 48.27°.
    assert_allclose(np.degrees(CRITICAL), 48.0, atol=0.5)


@pytest.mark.parametrize(
    "theta",
    [CRITICAL + 1e-9, np.radians(50.0), np.radians(70.0), np.radians(89.9), np.pi / 2],
    ids=["just_beyond", "50deg", "70deg", "89.9deg", "grazing"],
)
def test_total_internal_reflection(theta):
    assert fresnel_reflectance(np.cos(theta), **WATER_TO_AIR) == 1.0


def test_reflectance_below_critical_angle():
    assert fresnel_reflectance(np.cos(CRITICAL - 1e-3), **WATER_TO_AIR) < 1.0
    # r → 1 continuously at the critical angle (cos θt → 0).
    assert_allclose(fresnel_reflectance(np.cos(CRITICAL), **WATER_TO_AIR), 1.0, atol=1e-6)


@DIRECTIONS
def test_brewster_angle(indices):
    # At Brewster's angle atan(n2/n1), r_p = 0 and θ + θt = 90°, so
    # r = r_s/2 = sin²(θ - θt)/2 (Born & Wolf §1.5.3).
    theta = np.arctan(indices["n2"] / indices["n1"])
    theta_t = transmitted_angle(theta, **indices)
    assert_allclose(theta + theta_t, np.pi / 2, rtol=1e-14)
    expected = 0.5 * np.sin(theta - theta_t) ** 2
    assert_allclose(fresnel_reflectance(np.cos(theta), **indices), expected, rtol=1e-12)


def test_fresnel_increases_with_angle_from_air():
    theta = np.linspace(0.0, np.pi / 2, 200)
    reflectance = fresnel_reflectance(np.cos(theta), **AIR_TO_WATER)
    assert np.all(np.diff(reflectance) > 0)
    assert_allclose(reflectance[-1], 1.0, atol=1e-12)


@pytest.mark.parametrize("dtype", [np.float32, np.float64], ids=["float32", "float64"])
def test_fresnel_keeps_dtype_and_shape(dtype):
    cos = np.linspace(0.0, 1.0, 12, dtype=dtype).reshape(3, 4)
    reflectance = fresnel_reflectance(cos, **WATER_TO_AIR)
    assert reflectance.dtype == dtype
    assert reflectance.shape == (3, 4)
    assert np.all(np.isfinite(reflectance))


def test_fresnel_scalar_in_scalar_out():
    assert isinstance(fresnel_reflectance(0.5, **AIR_TO_WATER), float)


# ------------------------------------------------------------------------ refraction


def random_rays(rng, count, *, going):
    """Unit incident directions (downward or upward) and upward normals tilted up to 30°."""
    direction = rng.normal(size=(count, 3))
    direction[:, 2] = -np.abs(direction[:, 2]) if going == "down" else np.abs(direction[:, 2])
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    tilt = rng.uniform(0.0, np.radians(30.0), count)
    azimuth = rng.uniform(0.0, 2 * np.pi, count)
    normal = np.stack(
        [np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), np.cos(tilt)], axis=1
    )
    return direction, normal


def sine_to_normal(vectors, normal):
    return np.linalg.norm(np.cross(vectors, normal), axis=-1)


@pytest.fixture
def rng():
    return np.random.default_rng(20000)


@pytest.mark.parametrize(
    ("indices", "going"),
    [(AIR_TO_WATER, "down"), (WATER_TO_AIR, "up")],
    ids=["air_to_water", "water_to_air"],
)
def test_refraction_obeys_snell(rng, indices, going):
    direction, normal = random_rays(rng, 2000, going=going)
    transmitted, total = refract(direction, normal, **indices)
    keep = ~total
    assert keep.sum() > 500
    assert_allclose(
        indices["n1"] * sine_to_normal(direction[keep], normal[keep]),
        indices["n2"] * sine_to_normal(transmitted[keep], normal[keep]),
        atol=1e-12,
    )
    assert_allclose(np.linalg.norm(transmitted, axis=1), 1.0, rtol=1e-13)
    # Coplanar with the incident direction and the normal.
    assert_allclose(np.einsum("ij,ij->i", np.cross(direction, normal), transmitted), 0, atol=1e-13)


@pytest.mark.parametrize("orientation", [1.0, -1.0], ids=["upward_normal", "downward_normal"])
def test_air_to_water_goes_down(rng, orientation):
    direction, normal = random_rays(rng, 2000, going="down")
    near_nadir = direction[:, 2] < -0.9  # steep facets can send grazing rays up
    transmitted, total = refract(
        direction[near_nadir], orientation * normal[near_nadir], **AIR_TO_WATER
    )
    assert not total.any()
    assert np.all(transmitted[:, 2] < 0)


@pytest.mark.parametrize("orientation", [1.0, -1.0], ids=["upward_normal", "downward_normal"])
def test_water_to_air_goes_up(rng, orientation):
    direction, normal = random_rays(rng, 2000, going="up")
    near_zenith = direction[:, 2] > 0.9  # steep facets can send grazing rays down
    transmitted, total = refract(
        direction[near_zenith], orientation * normal[near_zenith], **WATER_TO_AIR
    )
    assert np.all(transmitted[~total, 2] > 0)


@pytest.mark.parametrize(
    "paper_form", ["air_incident", "water_incident"], ids=["air_incident", "water_incident"]
)
def test_refraction_matches_paper_table_2(rng, paper_form):
    # Paper Table 2 (Mobley's convention: n along the propagation, into the 2nd medium).
    n_w = N_WATER
    going = "down" if paper_form == "air_incident" else "up"
    direction, normal = random_rays(rng, 500, going=going)
    normal = np.where((np.einsum("ij,ij->i", direction, normal) < 0)[:, None], -normal, normal)
    cos = np.einsum("ij,ij->i", direction, normal)
    if paper_form == "air_incident":
        c = cos - np.sqrt(cos**2 + n_w**2 - 1)
        expected = (direction - c[:, None] * normal) / n_w
        transmitted, total = refract(direction, normal, n1=1.0, n2=n_w)
    else:
        # Root as n_w²(ξ'·n)² - n_w² + 1 (cos²θt); our copy of the paper prints n_w(ξ'·n)².
        keep = n_w**2 * cos**2 - n_w**2 + 1 > 0
        direction, normal, cos = direction[keep], normal[keep], cos[keep]
        c = n_w * cos - np.sqrt(n_w**2 * cos**2 - n_w**2 + 1)
        expected = n_w * direction - c[:, None] * normal
        transmitted, total = refract(direction, normal, n1=n_w, n2=1.0)
    assert not total.any()
    assert_allclose(transmitted, expected, atol=1e-14)


def test_total_internal_reflection_flag_is_exact():
    angles = np.radians(np.arange(0.0, 90.0, 0.25))
    angles = angles[np.abs(angles - CRITICAL) > 1e-9]
    direction = np.stack([np.sin(angles), np.zeros_like(angles), np.cos(angles)], axis=1)
    normal = np.array([0.0, 0.0, 1.0])
    transmitted, total = refract(direction, normal, **WATER_TO_AIR)
    assert_array_equal(total, angles > CRITICAL)
    # Documented choice: the reflected direction where the ray cannot leave the water.
    assert_allclose(transmitted[total], reflect(direction[total], normal), atol=1e-15)
    assert np.all(transmitted[total, 2] < 0)


@DIRECTIONS
@pytest.mark.parametrize("orientation", [1.0, -1.0], ids=["upward_normal", "downward_normal"])
def test_normal_incidence_passes_straight(indices, orientation):
    going = -1.0 if indices["n1"] < indices["n2"] else 1.0
    direction = np.array([0.0, 0.0, going])
    transmitted, total = refract(direction, orientation * np.array([0.0, 0.0, 1.0]), **indices)
    assert not total
    assert_allclose(transmitted, direction, atol=1e-15)


def test_refraction_is_reversible(rng):
    direction, normal = random_rays(rng, 1000, going="down")
    into_water, _ = refract(direction, normal, **AIR_TO_WATER)
    back, total = refract(-into_water, normal, **WATER_TO_AIR)
    assert not total.any()
    assert_allclose(back, -direction, atol=1e-13)


def test_equal_indices_leave_rays_unchanged(rng):
    direction, normal = random_rays(rng, 100, going="down")
    transmitted, total = refract(direction, normal, n1=1.34, n2=1.34)
    assert not total.any()
    assert_allclose(transmitted, direction, atol=1e-15)


def test_refract_float32_and_broadcasting(rng):
    direction, _ = random_rays(rng, 64, going="down")
    direction = direction.astype(np.float32).reshape(8, 8, 3)
    normal = np.array([0.0, 0.0, 1.0], dtype=np.float32)
    transmitted, total = refract(direction, normal, **AIR_TO_WATER)
    assert transmitted.dtype == np.float32
    assert transmitted.shape == (8, 8, 3)
    assert total.shape == (8, 8)
    assert_allclose(np.linalg.norm(transmitted, axis=-1), 1.0, rtol=1e-6)


def test_reflect_mirrors_about_the_normal(rng):
    direction, normal = random_rays(rng, 500, going="down")
    reflected = reflect(direction, normal)
    assert_allclose(np.linalg.norm(reflected, axis=1), 1.0, rtol=1e-13)
    # Angle of reflection = angle of incidence; tangential part preserved.
    cos_in = np.einsum("ij,ij->i", direction, normal)
    assert_allclose(np.einsum("ij,ij->i", reflected, normal), -cos_in, atol=1e-14)
    assert_allclose(
        reflected - np.einsum("ij,ij->i", reflected, normal)[:, None] * normal,
        direction - cos_in[:, None] * normal,
        atol=1e-14,
    )
    assert_allclose(reflect(direction, -normal), reflected, atol=1e-15)


# ------------------------------------------------ the compiled scalars and their twins

GRID = np.cos(np.radians(np.linspace(0.0, 90.0, 901)))  # 0.1° steps, through 48.27°


def scalars(function, cosines, *, n1, n2):
    """A compiled scalar function of (cos, n1, n2) over an array of cosines."""
    return np.array([function(c, n1, n2) for c in cosines])


@DIRECTIONS
def test_the_numpy_twins_equal_the_compiled_scalars(indices):
    # Fresnel and Snell are written once each as a numba scalar (the Monte Carlo kernels)
    # and once as an array twin (the fast renderer, the interface): equal on a 0.1° grid,
    # total internal reflection included (water to air, 48.3° to 90°: 418 angles)
    r = scalars(fresnel_unpolarised, GRID, **indices)
    cos_t = scalars(snell_cos_t, GRID, **indices)
    assert_allclose(fresnel_reflectance(GRID, **indices), r, rtol=0, atol=1e-12)
    assert_allclose(transmitted_cosine(GRID, **indices), cos_t, rtol=0, atol=1e-12)
    beyond = np.arccos(GRID) > np.arcsin(min(indices["n2"] / indices["n1"], 1.0))
    assert beyond.sum() == (418 if indices["n1"] > indices["n2"] else 0)
    assert np.all(r[beyond] == 1.0) and np.all(cos_t[beyond] == 0.0)


@DIRECTIONS
def test_the_torch_twins_equal_the_compiled_scalars(indices):
    # the interface's torch path (workers.setup.interface over the array API) runs the
    # same array twins: float64 tensors against the scalars, to 1e-12
    torch = pytest.importorskip("torch")
    cosines = torch.asarray(GRID, dtype=torch.float64)
    r = fresnel_reflectance(cosines, **indices)
    cos_t = transmitted_cosine(cosines, **indices)
    assert isinstance(r, torch.Tensor) and r.dtype == torch.float64
    assert_allclose(r.numpy(), scalars(fresnel_unpolarised, GRID, **indices), atol=1e-12)
    assert_allclose(cos_t.numpy(), scalars(snell_cos_t, GRID, **indices), atol=1e-12)


def test_the_scalar_fresnel_at_normal_incidence():
    # r(0) = ((n - 1)/(n + 1))² (Mobley 1994 §4.2): 0.02037 for n = 1.333 air to water,
    # 0.02006 for n = 1.33; the same from below (water to air)
    for n, published in ((1.333, 0.020373), (1.33, 0.020059)):
        closed = ((n - 1) / (n + 1)) ** 2
        assert abs(closed - published) < 1e-6
        assert_allclose(fresnel_unpolarised(1.0, 1.0, n), closed, rtol=1e-14)
        assert_allclose(fresnel_unpolarised(1.0, n, 1.0), closed, rtol=1e-14)


@DIRECTIONS
def test_the_scalar_fresnel_at_brewsters_angle(indices):
    # at tan θ = n2/n1, r_p = 0 and r_s = (n1² - n2²)/(n1² + n2²) (Born & Wolf §1.5.3)
    n1, n2 = indices["n1"], indices["n2"]
    cos_b = n1 / np.hypot(n1, n2)
    r_s = (n1**2 - n2**2) / (n1**2 + n2**2)
    assert_allclose(fresnel_unpolarised(cos_b, n1, n2), 0.5 * r_s**2, rtol=1e-12)
    assert_allclose(snell_cos_t(cos_b, n1, n2), n2 / np.hypot(n1, n2), rtol=1e-14)


def test_the_scalar_snell_law_and_total_internal_reflection():
    # n1 sin θi = n2 sin θt below the critical angle asin(n2/n1); beyond it (from below)
    # no ray leaves: cos θt = 0 and r = 1 exactly
    n1, n2 = 1.333, 1.0
    critical = np.arcsin(n2 / n1)
    for theta in np.linspace(0.0, critical - 1e-6, 50):
        cos_t = snell_cos_t(np.cos(theta), n1, n2)
        assert_allclose(n1 * np.sin(theta), n2 * np.sqrt(1 - cos_t**2), atol=1e-12)
        assert fresnel_unpolarised(np.cos(theta), n1, n2) < 1.0
    for theta in np.linspace(critical + 1e-9, np.pi / 2, 50):
        assert snell_cos_t(np.cos(theta), n1, n2) == 0.0
        assert fresnel_unpolarised(np.cos(theta), n1, n2) == 1.0


def test_refract_reflects_at_exactly_the_critical_angle():
    # n1 = 1.25, n2 = 1, sin θ = 0.8: (n1/n2)² sin²θ = 1 exactly in float64, the ray would
    # graze the surface and Fresnel gives r = 1: refract flags it and reflects it, as the
    # scalars say (before, it returned the grazing ray as transmitted)
    direction, normal = np.array([0.8, 0.0, 0.6]), np.array([0.0, 0.0, 1.0])
    assert snell_cos_t(0.6, 1.25, 1.0) == 0.0
    assert fresnel_unpolarised(0.6, 1.25, 1.0) == 1.0
    assert fresnel_reflectance(0.6, n1=1.25, n2=1.0) == 1.0
    transmitted, total = refract(direction, normal, n1=1.25, n2=1.0)
    assert total
    assert_array_equal(transmitted, [0.8, 0.0, -0.6])
