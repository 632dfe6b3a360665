"""The Monte Carlo renderer's target light and oblique gates against brute-force estimates.

Issue #36 item 1. Two independent photon Monte Carlos found the oracle's target light
heavy-tailed off the calibrated scene: a gate whose edge cuts the sphere read 0.4-3.6 times
its mean seed to seed, nothing of it at 100 m, half of it at 20 degrees off nadir. Here,
against estimates that need neither renderer (a quadrature over each pixel's lines of sight
through a flat sea, traced here with Snell and Fresnel):

- without scattering, the gated return of a Lambertian sphere whose surface a gate cuts (at
  34 m and 100 m over nadir, and 20 degrees off nadir);
- single scattering at 20 degrees off nadir, every gate (the slant gates' background);
- with multiple scattering, the per-seed spread of the target's light in the gate that cuts
  it against the errors the renderer reports.
"""

import math

import numpy as np
import pytest
from scipy.stats import chi2
from test_montecarlo import scene

from workers.montecarlo import renderer as montecarlo
from workers.optics.fresnel import fresnel_reflectance
from workers.optics.phases.base import BETA_PI_PER_BACKSCATTER
from workers.render import render_arrays
from workers.setup.builder import scene_setup
from workers.setup.sensor import sensor_at

SPHERE = {"shape": "sphere", "radius": 0.3, "depth": 5.0, "reflectance": 0.2}
CUT = [[3.0, 4.76], [4.76, 9.0]]  # the second opens across the visible cap: (q/r)³ = 1/2 of it
GEOMETRIES = {
    "34m-nadir": {"platform": {"altitude": 34.0}},
    "100m-nadir": {"platform": {"altitude": 100.0}},
    "20deg": {"platform": {"nadir_deg": 20.0, "azimuth_deg": 30.0}},
}


class FlatSeaLines:
    """Lines of sight (= laser rays, monostatic) through S × S points of each pixel, flat sea.

    Independent of the renderers: the pinhole's tangent offsets turned by the camera's
    rotation, Snell's law at z = 0, the unpolarised Fresnel transmittance, and the Gaussian
    beam's tangent-plane density e^(-(u²+v²)/h²) / (π h²), h = tan(φ/2), of total power πa²
    (a = R0 h: the renderers' raw unit, docs/model.md §9).
    """

    def __init__(self, s, sub):
        setup = scene_setup(s)
        sensor = sensor_at(setup, 0)
        self.setup, self.sub, self.pixels = setup, sub, s.receiver.pixels
        self.n = s.water.refractive_index
        self.rotation = sensor.camera.rotation
        self.origin = np.asarray(sensor.position, dtype=float)
        h = math.tan(0.5 * sensor.laser_fov)
        half = math.tan(0.5 * math.radians(s.receiver.field_of_view_deg))
        count = self.pixels * sub
        offsets = (np.arange(count) + 0.5 - count / 2) * (2 * half / count)
        self.u, self.v = np.meshgrid(offsets, offsets)  # rows v, columns u: the images'
        self.surface, self.water, self.air, cos_air = self.trace(self.u, self.v)
        self.transmittance = 1.0 - fresnel_reflectance(cos_air, n1=1.0, n2=self.n)
        power = math.pi * (sensor.reference_range * h) ** 2
        self.power = power * np.exp(-(self.u**2 + self.v**2) / h**2) / (math.pi * h**2)
        # gates: H/cos θ + n d/cos θ_w along the central ray (docs/model.md §5), one way
        nadir = math.radians(s.platform.nadir_deg)
        cos_water = math.sqrt(1.0 - (math.sin(nadir) / self.n) ** 2)
        gates = np.asarray(setup.gates, dtype=float)
        self.paths = self.origin[2] / math.cos(nadir) + self.n * gates / cos_water

    def trace(self, u, v):
        """Surface point, unit direction in the water, air path, cos of incidence."""
        d = np.stack([u, v, np.ones_like(u)], axis=-1)
        d = (d / np.linalg.norm(d, axis=-1, keepdims=True)) @ self.rotation
        air = -self.origin[2] / d[..., 2]
        surface = self.origin + air[..., np.newaxis] * d
        horizontal = d[..., :2] / self.n
        down = -np.sqrt(1.0 - (horizontal**2).sum(axis=-1, keepdims=True))
        return surface, np.concatenate([horizontal, down], axis=-1), air, -d[..., 2]

    def cross_section(self, length):
        """Area across the rays, per unit du dv, at `length` along each in the water [m²]."""
        eps = 1e-7

        def at(du, dv):
            surface, water, _, _ = self.trace(self.u + du, self.v + dv)
            return surface + length[..., np.newaxis] * water

        pu = (at(eps, 0) - at(-eps, 0)) / (2 * eps)
        pv = (at(0, eps) - at(0, -eps)) / (2 * eps)
        return np.abs((np.cross(pu, pv) * self.water).sum(axis=-1))

    def irradiance(self, length, attenuation):
        """Beam irradiance across the ray at `length` in the water (raw units) [1/m²]."""
        return (
            self.power
            * self.transmittance
            * np.exp(-attenuation * length)
            / self.cross_section(length)
        )

    def window(self, gate):
        """Water lengths along each line that gate `gate` holds (round trip) [m]."""
        top, bottom = self.paths[gate]
        return (top - self.air) / self.n, (bottom - self.air) / self.n

    def image(self, raw):
        """Pixel means of a per-line raw value, in the scene's units."""
        p, s = self.pixels, self.sub
        return raw.reshape(p, s, p, s).mean(axis=(1, 3)) * self.setup.scale


def sphere_quadrature(s, *, sub=24):
    """Gated images of a Lambertian sphere without scattering, shape (G, P, P).

    A pixel's raw value is π times the radiance it sees (ρ E⊥ cos θ_i / π, E⊥ the beam's
    irradiance across the ray where the line first meets the sphere), times the way up's
    transmittance T e^(-c L); the line's round trip air + n L decides the gate.
    """
    lines = FlatSeaLines(s, sub)
    setup, t = lines.setup, s.target
    c = setup.water.attenuation
    cx, cy = setup.target_centre
    o = lines.surface - np.array([cx, cy, -t.depth])
    b = (o * lines.water).sum(axis=-1)
    disc = b * b - ((o * o).sum(axis=-1) - t.radius**2)
    hit = disc > 0
    length = np.where(hit, -b - np.sqrt(np.where(hit, disc, 0.0)), 1.0)
    normal = (o + length[..., np.newaxis] * lines.water) / t.radius
    cos_in = -(normal * lines.water).sum(axis=-1)
    raw = t.reflectance * lines.irradiance(length, c) * cos_in
    raw *= lines.transmittance * np.exp(-c * length)
    images = []
    for g in range(len(lines.paths)):
        top, bottom = lines.window(g)
        inside = hit & (top <= length) & (length < bottom)
        images.append(lines.image(np.where(inside, raw, 0.0)))
    return np.array(images)


def single_scattering_quadrature(s, *, sub=4, nodes=48):
    """Gated single-scattering images of the water alone, shape (G, P, P).

    Each line's raw value is π T ∫ β(π) E⊥(L) e^(-c L) dL over the window its gate holds
    (Gauss-Legendre), β(π) = 0.174 b_b (the fitted phase function's, docs/model.md §9).
    """
    lines = FlatSeaLines(s, sub)
    c = lines.setup.water.attenuation
    beta_pi = BETA_PI_PER_BACKSCATTER * s.water.coefficients["backscatter"]  # β(π) [1/(m sr)]
    x, w = np.polynomial.legendre.leggauss(nodes)
    images = []
    for g in range(len(lines.paths)):
        top, bottom = lines.window(g)
        total = np.zeros_like(top)
        for xi, wi in zip(x, w, strict=True):
            length = 0.5 * (top + bottom) + 0.5 * (bottom - top) * xi
            total += 0.5 * (bottom - top) * wi * lines.irradiance(length, c) * np.exp(-c * length)
        images.append(lines.image(math.pi * lines.transmittance * beta_pi * total))
    return np.array(images)


def gate_ratio(out, closed):
    """Ratio of the rendered gates' image sums to the closed ones, and its standard error."""
    image, error = out["expected"][0].astype(float), out["expected_stderr"][0].astype(float)
    total = closed.sum(axis=(1, 2))
    return image.sum(axis=(1, 2)) / total, np.sqrt((error**2).sum(axis=(1, 2))) / total


def test_the_single_scattering_quadrature_is_the_nadir_closed_form():
    # the quadrature itself: at nadir, pi beta(pi) ∫ e^(-2cz) (H / (H + z/n))^2 dz times the
    # beam's profile over each pixel (test_montecarlo), through the lines' own geometry
    from scipy.integrate import quad
    from test_montecarlo import ALTITUDE, N_WATER, beam_profile

    a, b, bb = 0.1, 0.3, 0.006
    gates = [[1.0, 2.0], [3.0, 6.0]]
    s = scene(
        water={"preset": None, "absorption": a, "scattering": b, "backscatter": bb},
        target={"shape": "none"},
        receiver={"pixels": 16, "gates": gates},
    )
    images = single_scattering_quadrature(s, sub=8)
    for g, (top, bottom) in enumerate(gates):
        integral = quad(
            lambda z: np.exp(-2 * (a + b) * z) * (ALTITUDE / (ALTITUDE + z / N_WATER)) ** 2,
            top,
            bottom,
        )[0]
        closed = np.pi * BETA_PI_PER_BACKSCATTER * bb * integral * beam_profile()
        # the closed form is paraxial (a line's depth is its water length, its air path the
        # central one's): it holds on the central pixels (0.04 %), not toward the corners,
        # where the lines' longer air paths open the gate shallower (7 % at 3.3 degrees)
        centre = slice(7, 9)
        np.testing.assert_allclose(images[g][centre, centre], closed[centre, centre], rtol=1e-3)


@pytest.mark.parametrize("geometry", list(GEOMETRIES), ids=list(GEOMETRIES))
def test_a_sphere_a_gate_cuts_matches_its_surface_quadrature(geometry):
    # without scattering: the light of the sphere in the gate above its edge and in the gate
    # whose top cuts its visible cap, at 34 m and 100 m over nadir and at 20 degrees
    photons = 4_000_000 if geometry == "100m-nadir" else 600_000
    s = scene(
        water={"preset": None, "absorption": 0.15, "scattering": 0.0, "backscatter": 0.0},
        target=SPHERE,
        receiver={"pixels": 32, "gates": CUT},
        transport={"photons": photons},
        **GEOMETRIES[geometry],
    )
    closed = sphere_quadrature(s)
    share = closed[1].sum() / closed.sum()
    assert 0.2 < share < 0.8, share  # the gate's edge does cut the sphere
    ratio, error = gate_ratio(render_arrays(s, seed=11), closed)
    assert np.all(error < 0.025), error
    assert np.all(np.abs(ratio - 1) < 4 * error), (ratio, error)


def test_slant_gates_single_scattering_matches_its_line_integral():
    # 20 degrees off nadir: each gate's window lies at its own water length along each
    # line (the round trip air + n L); the single-scattering return is a 1-D integral along
    # every line (the gate-5 background, 1.12 of an independent code, settled here)
    s = scene(
        water={"preset": None, "absorption": 0.05, "scattering": 0.1, "backscatter": 0.0013},
        target={"shape": "none"},
        transport={"photons": 600_000, "max_scattering": 1},
        **GEOMETRIES["20deg"],
    )
    closed = single_scattering_quadrature(s)
    ratio, error = gate_ratio(render_arrays(s, seed=5), closed)
    assert np.all(error < 0.015), error
    assert np.all(np.abs(ratio - 1) < 4 * error), (ratio, error)


SEEDS = 8


@pytest.fixture(scope="module")
def cut_sphere_seeds():
    """The coastal sphere's gate-cut light over `SEEDS` seeds: values and reported errors."""
    s = scene(
        water={"preset": "coastal"},
        target=SPHERE,
        receiver={"pixels": 16, "gates": [[3.7, 9.8], [4.9, 11.0]]},  # ML(DC) gates 1-2
        transport={"photons": 400_000},
    )
    outs = [render_arrays(s, seed=seed) for seed in range(SEEDS)]
    mask = outs[0]["target_mask"][0].astype(bool)
    values = np.array([o["expected"][0][:, mask] for o in outs], dtype=float)
    errors = np.array([o["expected_stderr"][0][:, mask] for o in outs], dtype=float)
    return values, errors


def test_the_target_light_a_gate_cuts_has_the_spread_its_errors_report(cut_sphere_seeds):
    # Scattering after the target's Lambertian reflection: a photon reflected almost
    # straight at the receiver gave the next scattering's estimate the phase function's
    # forward peak (about theta^-0.93): heavy-tailed, most seeds read low, a few far high,
    # the batches' spread did not see it. Over the mask's pixels and the seeds, the squared
    # deviations from the seeds' mean in units of each seed's reported error average
    # (SEEDS - 1)/SEEDS * 15/13 (16 batches: Student's t with 15 degrees of freedom) if the
    # errors explain the spread; the bound leaves four standard deviations of that mean
    # (t² has variance 3.4 at 15 degrees of freedom), counting the pixels of one seed as
    # one sample (they share photons).
    values, errors = cut_sphere_seeds
    z2 = ((values - values.mean(axis=0)) / errors) ** 2
    expected = (SEEDS - 1) / SEEDS * 15 / 13
    bound = expected + 4 * math.sqrt(3.4 / SEEDS)
    for g in range(values.shape[1]):
        assert z2[:, g].mean() < bound, (g, z2[:, g].mean(), bound)


def test_the_target_light_a_gate_cuts_converges(cut_sphere_seeds):
    # the gate cutting the sphere: its mask's light within 5 % at 3.2 million photons
    # (8 seeds of 400 000), and its seeds' median within the median's own error of their
    # mean (a heavy tail puts the median far below the mean: most seeds miss the tail)
    values, errors = cut_sphere_seeds
    light = values[:, 1].sum(axis=1)
    mean, spread = light.mean(), light.std(ddof=1)
    assert spread / math.sqrt(SEEDS) < 0.05 * mean, (spread, mean)
    median_error = 1.2533 * spread / math.sqrt(SEEDS)
    assert abs(np.median(light) - mean) < 3 * median_error, (np.median(light), mean)
    # and the seeds' spread is what their errors say (chi-square, SEEDS - 1 degrees of
    # freedom, 0.1 % either side), pixels summed as if independent
    reported = np.sqrt((errors[:, 1] ** 2).sum(axis=1))
    ratio = spread**2 / (reported**2).mean()
    low, high = chi2.ppf([0.001, 0.999], SEEDS - 1) / (SEEDS - 1)
    assert low < ratio < high, (ratio, low, high)


def test_the_way_to_the_receiver_refracts_into_it():
    # the biasing's aim (scatterings and the target's reflection): from a point in the
    # water, the direction whose refraction at a flat sea passes through the pinhole
    from workers.montecarlo.records import Point
    from workers.montecarlo.scattering import toward_receiver

    n, camera = 1.34, np.array([3.0, -2.0, 34.0])
    rng = np.random.default_rng(2)
    points = rng.uniform([-15, -15, 0.5], [15, 15, 20], size=(20, 3))
    for x, y, depth in points:
        ux, uy, uz = toward_receiver(x, y, -depth, Point(*camera), n)
        assert uz > 0
        along = depth / uz
        surface = np.array([x + along * ux, y + along * uy])
        sin_water = math.hypot(ux, uy)
        lateral = camera[:2] - surface
        sin_air = np.linalg.norm(lateral) / math.hypot(np.linalg.norm(lateral), camera[2])
        np.testing.assert_allclose(n * sin_water, sin_air, rtol=1e-9, atol=1e-12)
        # and toward the camera: the horizontal way up and on through the air line up
        cross = (ux * lateral[1] - uy * lateral[0]) / max(np.linalg.norm(lateral), 1e-12)
        assert abs(cross) < 1e-9


def test_the_reflections_biased_draw_is_weighted_back_to_lambert():
    # the target's reflection draws a direction from (1 - e) cos/pi + e p(a.u) (about the
    # way a to the receiver) and weights it by (cos/pi) / mixture: for any function f of
    # the direction, E[weight f] is the Lambertian integral of f. Here f = p(a'.u), the
    # next scattering's estimate toward a receiver a' 2 mrad off a (the forward peak that
    # the biasing is for), and f = 1 (all the reflected light), against quadrature.
    from workers.montecarlo.scattering import reflection_weight, turn

    table = scene_setup(scene(water={"preset": "coastal"})).phase_table()
    phase = montecarlo.phase_record(table)
    share, count = montecarlo.TARGET_BIAS, 400_000
    normal = np.array([0.6, 0.0, 0.8])
    aim = np.array([0.0, 0.0, 1.0])
    other = np.array([np.sin(0.002), 0.0, np.cos(0.002)])
    rng = np.random.default_rng(1)
    biased = rng.random(count) < share
    theta = np.where(
        biased,
        np.interp(rng.random(count), np.linspace(0, 1, table.quantiles.size), table.quantiles),
        np.arccos(np.sqrt(rng.random(count))),
    )
    phi = 2 * np.pi * rng.random(count)
    angles = table.log_theta0 + table.log_step * np.arange(table.values.size)

    def phase_at(psi):  # the table, log-linear in ln θ (as the kernels read it)
        psi = np.maximum(psi, np.exp(angles[0]))
        return np.exp(np.interp(np.log(psi), angles, np.log(table.values)))

    directions = np.empty((count, 3))
    weights = np.empty(count)
    for i in range(count):
        axis = aim if biased[i] else normal
        directions[i] = turn(*axis, np.cos(theta[i]), np.sin(theta[i]), phi[i])
        weights[i] = reflection_weight(*normal, *aim, *directions[i], phase, share)
    off = np.arctan2(np.linalg.norm(np.cross(directions, other), axis=-1), directions @ other)
    values = np.stack([weights, weights * phase_at(off)], axis=-1)
    mean = values.mean(axis=0)
    error = values.std(axis=0, ddof=1) / np.sqrt(count)
    # Lambert: ∫ cos/pi dΩ = 1; ∫ cos/pi p(a'.u) dΩ over the hemisphere about the normal,
    # in polar angle about a' (the peak resolved on a log grid)
    psi = np.geomspace(1e-7, np.pi, 4001)
    azimuth = np.linspace(0, 2 * np.pi, 721)[:-1]
    e1 = np.cross(other, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(other, e1)
    ring = np.cos(azimuth)[:, None, None] * e1 + np.sin(azimuth)[:, None, None] * e2
    dirs = np.cos(psi)[None, :, None] * other + np.sin(psi)[None, :, None] * ring
    lam = np.maximum(dirs @ normal, 0) / np.pi
    inner = lam.mean(axis=0) * 2 * np.pi * np.sin(psi) * phase_at(psi)
    closed = np.trapezoid(inner, psi)
    np.testing.assert_allclose(mean[0], 1.0, atol=4 * error[0])
    assert error[1] < 0.01 * closed, (error[1], closed)
    np.testing.assert_allclose(mean[1], closed, atol=4 * error[1])
