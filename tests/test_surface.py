"""Tests of workers.sea.surface: statistics, spectral slopes, dispersion, sampling."""

import math
from dataclasses import dataclass

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from workers.sea.cascades import Sea
from workers.sea.spectra import Elfouhaily, Phillips, Spectrum, dispersion
from workers.sea.surface import Cascade
from workers.sea.surface import synthesize as draw_sea


def synthesize(spectrum, *, grid_size, spacing, **kwargs):
    """One realisation of the single-cascade sea of this grid."""
    return draw_sea(Sea(spectrum, grid_size, (grid_size * spacing,)), **kwargs)


def surface_amplitudes(spectrum, *, grid_size, spacing):
    return Sea(spectrum, grid_size, (grid_size * spacing,)).amplitudes(0)


@dataclass(frozen=True, kw_only=True)
class SingleMode(Spectrum):
    """Test-only spectrum: all of ``mode_variance`` on the grid wavevector ``mode``.

    S(k) is a box of width Δk around k₀ = |mode| holding the variance, and Φ a box of
    width Δk/k₀ around the mode's direction holding 1, so that Ψ = variance/Δk² at the
    mode and 0 at every other point of the FFT grid.
    """

    mode: tuple[float, float]
    mode_variance: float
    resolution: float

    def omnidirectional(self, k):
        k0 = math.hypot(*self.mode)
        inside = np.abs(np.asarray(k, float) - k0) < 0.5 * self.resolution
        return np.where(inside, self.mode_variance / self.resolution, 0.0)

    def spreading(self, k, phi):
        width = self.resolution / math.hypot(*self.mode)
        offset = np.angle(np.exp(1j * (phi - math.atan2(self.mode[1], self.mode[0]))))
        inside = np.abs(offset) + 0.0 * np.asarray(k, float) < 0.5 * width
        return np.where(inside, 1.0 / width, 0.0)

    def directional(self, kx, ky):
        # the grid cell of the mode, so that its integral over the cell is the variance
        half = 0.5 * self.resolution
        inside = (np.abs(np.asarray(kx) - self.mode[0]) < half) & (
            np.abs(np.asarray(ky) - self.mode[1]) < half
        )
        return np.where(inside, self.mode_variance / self.resolution**2, 0.0)


def _single_mode(n, spacing, cells, variance=1e-4):
    resolution = 2 * np.pi / (n * spacing)
    mode = (cells[0] * resolution, cells[1] * resolution)
    return SingleMode(wind_speed=1.0, mode=mode, mode_variance=variance, resolution=resolution)


def _wavenumbers(n, spacing):
    return 2 * np.pi * np.fft.fftfreq(n, d=spacing)


def test_amplitudes_are_cell_integrals_in_fft_order_with_no_mean_mode():
    n, spacing = 64, 0.1
    spectrum = Elfouhaily(wind_speed=6.0, wind_direction=0.4)
    amplitude = surface_amplitudes(spectrum, grid_size=n, spacing=spacing)
    assert amplitude.shape == (n, n)
    assert amplitude.dtype == np.float64
    assert amplitude[0, 0] == 0.0
    assert not amplitude[n // 2].any() and not amplitude[:, n // 2].any()  # Nyquist
    k = _wavenumbers(n, spacing)
    dk = 2 * np.pi / (n * spacing)
    # far from k = 0 and from the band's edge π/Δ: Ψ at the centre of the cell
    for i, j in [(0, 20), (3, 25), (5, 29), (40, 50)]:
        expected = math.sqrt(spectrum.directional(k[j], k[i]) * dk**2)
        assert_allclose(amplitude[i, j], expected, rtol=1e-14)
    # near k = 0: the midpoint rule on 4 x 4 points of the cell
    offsets = (np.arange(4) + 0.5) / 4 - 0.5
    for i, j in [(0, 1), (2, 63)]:
        qx, qy = k[j] + dk * offsets[None, :], k[i] + dk * offsets[:, None]
        expected = math.sqrt(spectrum.directional(qx, qy).mean() * dk**2)
        assert_allclose(amplitude[i, j], expected, rtol=1e-14)


def test_single_mode_spectrum_fills_one_grid_point():
    spectrum = _single_mode(16, 0.1, (3, -2), variance=2e-4)
    amplitude = surface_amplitudes(spectrum, grid_size=16, spacing=0.1)
    assert np.count_nonzero(amplitude) == 1
    assert_allclose(amplitude[-2, 3] ** 2, 2e-4, rtol=1e-12)


def _pair_means(amplitude, weight):
    """E|h̃(k)|² w(k) on the full grid: (a(k)² + a(-k)²)/2 · w(k)."""
    mirrored = np.roll(np.flip(amplitude, (0, 1)), 1, (0, 1))
    return 0.5 * (amplitude**2 + mirrored**2) * weight


@pytest.mark.parametrize("time", [0.0, 0.7], ids=["t0", "t0.7"])
def test_variances_over_realisations_match_the_resolved_spectrum(time):
    n, spacing, realisations = 64, 0.05, 300
    spectrum = Phillips(wind_speed=1.2, wind_direction=0.5)
    amplitude = surface_amplitudes(spectrum, grid_size=n, spacing=spacing)
    k = _wavenumbers(n, spacing)
    kx, ky = k[None, :], k[:, None]  # the Nyquist row and column hold no waves
    rng = np.random.default_rng(20240601)
    surfaces = [
        synthesize(spectrum, grid_size=n, spacing=spacing, rng=rng, times=(time,))
        for _ in range(realisations)
    ]
    for name, weight in (("elevation", 1.0), ("slope_x", kx**2), ("slope_y", ky**2)):
        means = _pair_means(amplitude, weight)
        expected = means.sum()  # Σ Ψ Δk² (times k_x², k_y² for the slopes)
        # Parseval: the spatial mean square of one realisation is Σ_k |h̃(k)|² w(k).
        # h̃(k) is circular complex Gaussian, h̃(-k) its conjugate; a pair {k, -k}
        # contributes 2|h̃(k)|² w, an exponential variable of mean 2m(k) and variance
        # (2m(k))², a self-conjugate point a χ²₁ term of variance 2m². Summed over the
        # grid, Var = 2 Σ_k m(k)². The mean over R independent realisations has
        # standard deviation √(2 Σ m² / R); the test allows 5 of them (a false alarm
        # has probability ~6e-7 for this fixed seed's population).
        sigma = math.sqrt(2.0 * np.sum(means**2) / realisations)
        effective_modes = expected**2 / np.sum(means**2)
        assert effective_modes > 20  # the statistics are not carried by a few modes
        observed = np.mean(
            [np.mean(getattr(s.cascades[0], name)[0].astype(np.float64) ** 2) for s in surfaces]
        )
        assert abs(observed - expected) < 5 * sigma, (name, observed, expected, sigma)


def test_slopes_match_centred_differences_of_a_single_mode():
    # For η = A cos(k·x + θ), the centred difference along x is ∂η/∂x · sin(kxΔ)/(kxΔ)
    # exactly, so the spectral slope is recovered to float32 rounding.
    n, spacing = 64, 0.02
    spectrum = _single_mode(n, spacing, (3, -5))
    surface = synthesize(spectrum, grid_size=n, spacing=spacing, rng=np.random.default_rng(1))
    eta = surface.elevation[0].astype(np.float64)
    kx, ky = spectrum.mode
    centred_x = (np.roll(eta, -1, axis=1) - np.roll(eta, 1, axis=1)) / (2 * spacing)
    centred_y = (np.roll(eta, -1, axis=0) - np.roll(eta, 1, axis=0)) / (2 * spacing)
    slope_x = centred_x * (kx * spacing) / math.sin(kx * spacing)
    slope_y = centred_y * (ky * spacing) / math.sin(ky * spacing)
    scale = math.hypot(kx, ky) * np.abs(eta).max()
    assert scale > 0
    assert_allclose(surface.cascades[0].slope_x[0], slope_x, atol=2e-6 * scale)
    assert_allclose(surface.cascades[0].slope_y[0], slope_y, atol=2e-6 * scale)


def test_slopes_are_the_spectral_derivative_of_the_elevation():
    n, spacing = 64, 0.03
    surface = synthesize(
        Elfouhaily(wind_speed=7.0, wind_direction=1.0),
        grid_size=n,
        spacing=spacing,
        rng=np.random.default_rng(5),
    )
    eta = surface.elevation[0].astype(np.float64)
    k = _wavenumbers(n, spacing)
    nyquist = np.arange(n) == n // 2
    transform = np.fft.fft2(eta)
    slope_x = np.fft.ifft2(1j * np.where(nyquist, 0.0, k)[None, :] * transform).real
    slope_y = np.fft.ifft2(1j * np.where(nyquist, 0.0, k)[:, None] * transform).real
    assert_allclose(surface.cascades[0].slope_x[0], slope_x, atol=1e-5 * np.abs(slope_x).max())
    assert_allclose(surface.cascades[0].slope_y[0], slope_y, atol=1e-5 * np.abs(slope_y).max())


def test_field_is_real_zero_mean_and_periodic():
    n, spacing = 32, 0.05
    surface = synthesize(
        Elfouhaily(wind_speed=5.0), grid_size=n, spacing=spacing, rng=np.random.default_rng(2)
    )
    for values in (surface.elevation, surface.cascades[0].slope_x, surface.cascades[0].slope_y):
        assert values.dtype == np.float32
        assert values.shape == (1, n, n)
        assert np.all(np.isfinite(values))
        assert abs(values.astype(np.float64).mean()) < 1e-6 * np.abs(values).max()
    x = np.array([0.013, 0.4, 1.1])
    y = np.array([0.9, 0.002, 1.5])
    period = n * spacing
    (cascade,) = surface.cascades  # the sub-grid slopes are not periodic
    here = cascade.sample(x, y)
    for shifted in (cascade.sample(x + period, y - 2 * period), cascade.sample(x - period, y)):
        for a, b in zip(here, shifted, strict=True):
            assert_allclose(a, b, rtol=1e-5, atol=1e-6 * np.abs(a).max())


@pytest.mark.parametrize("n", [32, 15], ids=["even-grid", "odd-grid"])
@pytest.mark.parametrize(
    "cells",
    [(6, 0), (-6, 0), (0, 6), (0, -6), (3, 4), (-4, 5)],  # inside |k| < π/Δ
    ids=["+x", "-x", "+y", "-y", "oblique", "oblique-upwind"],
)
def test_a_single_mode_travels_towards_its_wavevector_at_the_phase_speed(cells, n):
    spacing = 0.01
    spectrum = _single_mode(n, spacing, cells, variance=1e-6)
    k = math.hypot(*spectrum.mode)
    omega = float(dispersion(k))
    dt = 1.0 / omega  # one radian of phase: no 2π ambiguity
    surface = synthesize(
        spectrum, grid_size=n, spacing=spacing, rng=np.random.default_rng(7), times=(0.0, dt)
    )
    j = np.arange(n) * spacing
    x, y = j[None, :], j[:, None]
    carrier = np.exp(-1j * (spectrum.mode[0] * x + spectrum.mode[1] * y))
    amplitude = [np.mean(surface.elevation[t].astype(np.float64) * carrier) for t in (0, 1)]
    # η = 2|c| cos(k·x - ωt + θ): a wave moving towards +k has c(t) ∝ e^{-iωt}.
    phase_change = np.angle(amplitude[1] / amplitude[0])
    assert_allclose(-phase_change / (k * dt), omega / k, rtol=1e-5)
    assert_allclose(abs(amplitude[1]), abs(amplitude[0]), rtol=1e-5)
    # Nothing but this mode: η is exactly the travelling cosine.
    for t in (0, 1):
        wave = 2 * np.real(amplitude[t] * np.conj(carrier))
        assert_allclose(surface.elevation[t], wave, atol=1e-5 * np.abs(wave).max())


def test_same_seed_gives_the_same_bytes_and_frames_share_one_realisation():
    spectrum = Elfouhaily(wind_speed=5.0)
    grid = {"grid_size": 32, "spacing": 0.05}
    first = synthesize(spectrum, **grid, rng=np.random.default_rng(11), times=(0.0, 0.4))
    second = synthesize(spectrum, **grid, rng=np.random.default_rng(11), times=(0.0, 0.4))
    for name in ("elevation", "slope_x", "slope_y"):
        assert (
            getattr(first.cascades[0], name).tobytes()
            == getattr(second.cascades[0], name).tobytes()
        )
    x, y = np.random.default_rng(0).uniform(-5, 5, (2, 100))
    assert first.slopes_at(x, y)[0].tobytes() == second.slopes_at(x, y)[0].tobytes()
    later = synthesize(spectrum, **grid, rng=np.random.default_rng(11), times=(0.4,))
    assert later.elevation[0].tobytes() == first.elevation[1].tobytes()
    other = synthesize(spectrum, **grid, rng=np.random.default_rng(12))
    assert not np.array_equal(other.elevation[0], first.elevation[0])


def _random_surface(n, spacing, frames=2, seed=0):
    rng = np.random.default_rng(seed)
    fields = rng.normal(size=(3, frames, n, n)).astype(np.float32)
    return Cascade(
        elevation=fields[0], slope_x=fields[1], slope_y=fields[2], spacing=spacing, grid_size=n
    )


@pytest.mark.parametrize("n", [8, 6], ids=["power-of-two", "other"])
def test_sample_returns_grid_values_at_nodes(n):
    spacing = 0.0625  # a power of two: x/Δ is exact in float32
    surface = _random_surface(n, spacing)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    for frame in (0, 1):
        values = surface.sample(j * spacing, i * spacing, frame)
        for got, grid in zip(
            values, (surface.elevation, surface.slope_x, surface.slope_y), strict=True
        ):
            assert got.dtype == np.float32
            assert got.shape == (n, n)
            assert_array_equal(got, grid[frame])


def test_sample_at_nodes_with_a_general_spacing():
    n, spacing = 16, 0.016
    surface = _random_surface(n, spacing)
    j = np.arange(n)
    got = surface.sample(j * spacing, np.full(n, 3 * spacing), 1)[1]
    assert_allclose(got, surface.slope_x[1, 3], rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("n", [8, 6], ids=["power-of-two", "other"])
def test_sample_interpolates_bilinearly_and_wraps(n):
    spacing = 0.0625
    surface = _random_surface(n, spacing, seed=3)
    f = surface.elevation[0].astype(np.float64)
    t = np.array([0.25, 0.5, 0.75])
    # Along x between nodes (row 2, columns n-1 and 0: across the periodic seam).
    along = surface.sample((n - 1 + t) * spacing, np.full(3, 2 * spacing))[0]
    assert_allclose(along, (1 - t) * f[2, n - 1] + t * f[2, 0], rtol=1e-6)
    # Along y, from below the origin (negative coordinates wrap too).
    up = surface.sample(np.full(3, 4 * spacing), (t - 1) * spacing)[0]
    assert_allclose(up, (1 - t) * f[n - 1, 4] + t * f[0, 4], rtol=1e-6)
    # Cell centre: the mean of the four corners.
    centre = surface.sample(1.5 * spacing, 3.5 * spacing)[0]
    assert_allclose(centre, (f[3, 1] + f[3, 2] + f[4, 1] + f[4, 2]) / 4, rtol=1e-6)
    # Bilinear: exact on any product of linear functions of x and y.
    tx, ty = 0.3, 0.8
    corners = (1 - tx) * (1 - ty) * f[1, 1] + tx * (1 - ty) * f[1, 2]
    corners += (1 - tx) * ty * f[2, 1] + tx * ty * f[2, 2]
    assert_allclose(surface.sample((1 + tx) * spacing, (1 + ty) * spacing)[0], corners, rtol=1e-6)


def test_sample_broadcasts_and_keeps_shape():
    surface = _random_surface(8, 0.1)
    x = np.linspace(0.0, 0.7, 5)[None, :]
    y = np.linspace(0.0, 0.7, 3)[:, None]
    values = surface.sample(x, y, 1)
    assert all(v.shape == (3, 5) for v in values)
    many = np.linspace(-3.0, 3.0, 20000)  # more than one block of points
    across = 0.7 * many[::-1] + 0.1
    pieces = [
        surface.sample(a, b)[2]
        for a, b in zip(np.split(many, 20), np.split(across, 20), strict=True)
    ]
    assert_array_equal(surface.sample(many, across)[2], np.concatenate(pieces))


def test_max_elevation_rescales_the_whole_realisation():
    spectrum = Elfouhaily(wind_speed=5.0)
    grid = {"grid_size": 32, "spacing": 0.05, "times": (0.0, 0.5, 1.0)}
    plain = synthesize(spectrum, **grid, rng=np.random.default_rng(4))
    scaled = synthesize(spectrum, **grid, rng=np.random.default_rng(4), max_elevation=0.1)
    assert_allclose(np.abs(scaled.centred_elevation).max(), 0.1, rtol=1e-6)
    factor = 0.1 / np.abs(plain.centred_elevation).max()
    for name in ("elevation", "slope_x", "slope_y"):
        assert_allclose(
            getattr(scaled.cascades[0], name), factor * getattr(plain.cascades[0], name), rtol=1e-5
        )
    x, y = np.random.default_rng(0).uniform(-5, 5, (2, 100))
    assert_allclose(scaled.slopes_at(x, y), factor * np.array(plain.slopes_at(x, y)), rtol=1e-4)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"grid_size": 1},
        {"grid_size": 16.5},
        {"spacing": 0.0},
        {"times": ()},
        {"times": (0.0, math.inf)},
        {"max_elevation": -0.1},
    ],
    ids=["tiny-grid", "fractional-grid", "zero-spacing", "no-times", "infinite-time", "negative"],
)
def test_synthesize_rejects_bad_input(kwargs):
    arguments = {"grid_size": 16, "spacing": 0.05, "rng": np.random.default_rng(0), **kwargs}
    with pytest.raises(ValueError):
        synthesize(Phillips(wind_speed=3.0), **arguments)


def test_surface_arrays_are_read_only_and_checked():
    surface = _random_surface(8, 0.1)
    with pytest.raises(ValueError):
        surface.elevation[0, 0, 0] = 1.0
    with pytest.raises(ValueError):
        Cascade(
            elevation=np.zeros((1, 8, 8)),
            slope_x=np.zeros((1, 8, 8)),
            slope_y=np.zeros((2, 8, 8)),
            spacing=0.1,
            grid_size=8,
        )


def test_elevation_at_equals_the_elevation_of_sample():
    surface = synthesize(
        Elfouhaily(wind_speed=6.0), grid_size=64, spacing=0.02, rng=np.random.default_rng(9)
    )
    x, y = np.random.default_rng(1).uniform(-3, 3, (2, 1000))
    assert surface.elevation_at(x, y).tobytes() == surface.sample(x, y)[0].tobytes()


@pytest.mark.parametrize("n", [8, 12])
def test_elevation_at_and_slopes_at_equal_sample_across_blocks_and_wraps(n):
    rng = np.random.default_rng(4)
    fields = rng.standard_normal((3, 2, n, n)).astype(np.float32)
    surface = Cascade(
        elevation=fields[0], slope_x=fields[1], slope_y=fields[2], spacing=0.3, grid_size=n
    )
    # more points than one block, far outside the first period and negative
    x = rng.uniform(-50.0, 50.0, 70_000).astype(np.float32)
    y = rng.uniform(-50.0, 50.0, 70_000).astype(np.float32)
    eta, sx, sy = surface.sample(x, y, frame=1)
    assert_array_equal(surface.elevation_at(x, y, frame=1), eta)
    slope_x, slope_y = surface.slopes_at(x, y, frame=1)
    assert_array_equal(slope_x, sx)
    assert_array_equal(slope_y, sy)
    # bilinear on the unpadded grid, wrapped by hand
    tx, ty = x * np.float32(1 / 0.3), y * np.float32(1 / 0.3)  # as Surface locates points
    j, i = np.floor(tx).astype(int), np.floor(ty).astype(int)
    fx, fy = tx - j, ty - i
    grid = fields[0, 1]
    expected = (1 - fy) * ((1 - fx) * grid[i % n, j % n] + fx * grid[i % n, (j + 1) % n]) + fy * (
        (1 - fx) * grid[(i + 1) % n, j % n] + fx * grid[(i + 1) % n, (j + 1) % n]
    )
    assert_allclose(eta, expected, rtol=1e-5, atol=1e-5)
