r"""Sea surfaces conditioned on point measurements of the elevation (conditioning by kriging).

The field of :func:`workers.surface.synthesize` is Gaussian, so a surface drawn given
measured elevations is exact and cheap: an unconditional sample plus a kriging correction
of its residual at the data (Journel & Huijbregts 1978, §V.D; Chilès & Delfiner 2012,
§7.3). With :math:`L` the data functionals, :math:`K = LCL^\top + \sigma^2 I` and
:math:`\varepsilon \sim N(0, \sigma^2 I)` drawn with the sample,

.. math::

    \eta_c(\mathbf x, t) = \eta_u(\mathbf x, t)
    + \sum_d w_d\,(C L^\top)_d(\mathbf x, t),\qquad
    \mathbf w = K^{-1}\left(\mathbf d - L\eta_u - \varepsilon\right),

has exactly the law of η given the data (with or without noise). The covariance is that of
the synthesised periodic field, not of the continuous spectrum, so the two agree to rounding:

.. math::

    C(\Delta\mathbf x, \Delta t) = \operatorname{Cov}\left(\eta(\mathbf x + \Delta\mathbf x,
    t + \Delta t), \eta(\mathbf x, t)\right)
    = \sum_{\mathbf k} a(\mathbf k)^2 \cos(\mathbf k\cdot\Delta\mathbf x - \omega\,\Delta t),

the sum over the FFT grid with a from :func:`workers.surface.surface_amplitudes` and ω from
:func:`workers.spectra.dispersion`. On the grid nodes it is one inverse FFT of
:math:`a^2 e^{-i\omega\Delta t}`; with Δt = 0 the inverse FFT of the sampled spectrum. It
holds on the nodes for the standing Nyquist modes too (sin(k·Δx) = 0 there).

A measurement is of the elevation as the renderer sees it: the bilinear interpolation of
the four grid nodes around the point (:meth:`workers.surface.Surface.sample`), at its time.
L is then exact, the data are honoured by ``Surface.sample`` (to rounding when σ = 0), and
points need not lie on nodes.
"""

from __future__ import annotations

import functools
from collections import defaultdict
from dataclasses import dataclass

import numpy as np
import scipy.fft

from workers.spectra import Spectrum, dispersion
from workers.surface import surface_amplitudes

__all__ = ["RCOND", "Kriging", "check_points", "kriging", "space_time_covariance"]

RCOND = 1e-9
"""Smallest accepted ratio of the smallest to the largest eigenvalue of K (1 / condition
number). The weights are solved in float64 to a relative error of about 2×10⁻¹⁶ over this
ratio: at the limit 2×10⁻⁷, the float32 rounding of the fields themselves."""

# Data rows per block when K is assembled (16 corner pairs per entry: 64 rows of a
# 1000-point system keep the temporaries near 8 MB).
_BLOCK = 64


def _grid(spectrum: Spectrum, grid_size: int, spacing: float):
    """a² (float64 from the synthesis's float32 a) and ω on the full FFT grid."""
    amplitude = surface_amplitudes(spectrum, grid_size=grid_size, spacing=spacing)
    power = amplitude.astype(np.float32).astype(np.float64) ** 2
    k = 2.0 * np.pi * np.fft.fftfreq(grid_size, d=spacing)
    return power, dispersion(np.hypot(k[None, :], k[:, None]))


def space_time_covariance(
    spectrum: Spectrum, *, grid_size: int, spacing: float, lag: float = 0.0
) -> np.ndarray:
    r"""Space–time covariance of the synthesised sea on the grid lags, m².

    .. math::

        C_{ij} = C(j\Delta, i\Delta, \tau)
        = \sum_{\mathbf k} a(\mathbf k)^2 \cos(k_x j\Delta + k_y i\Delta - \omega\tau)
        = \operatorname{Re}\,\mathcal F^{-1}\!\left[a^2 e^{-i\omega\tau}\right]_{ij}

    (the inverse FFT without the 1/N² factor).

    Parameters
    ----------
    spectrum : workers.spectra.Spectrum
        Directional wave spectrum.
    grid_size : int
        Number N of grid points along x and along y.
    spacing : float
        Grid spacing Δ, m.
    lag : float, optional
        Time lag τ, s: C is the covariance of η at (x + jΔ, y + iΔ, t + τ) with η at
        (x, y, t).

    Returns
    -------
    numpy.ndarray
        C, m², float64 of shape (N, N) indexed [i, j] (y lag, x lag), periodic.

    Notes
    -----
    a is taken in float32, as the synthesis draws with it, so the covariance is that of
    the sampled field to rounding. C(0, 0, τ) = Σ a² for every τ only without
    dispersion; in general the field decorrelates in time, mode by mode.

    References
    ----------
    .. [1] Chilès, J.-P., & Delfiner, P. (2012). Geostatistics: Modeling Spatial
       Uncertainty, 2nd ed., §7.3 (spectral simulation). Wiley.
    """
    power, omega = _grid(spectrum, int(grid_size), float(spacing))
    return _covariance(power, omega, lag)


def _covariance(power, omega, lag):
    if lag == 0.0:
        weights = power.astype(np.complex128)
    else:
        weights = power * np.exp(-1j * omega * lag)
    return scipy.fft.ifft2(weights, norm="forward").real


@dataclass(frozen=True, eq=False)
class Kriging:
    """The kriging system of one set of measurements on one spectrum and grid.

    Built (and cached) by :func:`kriging`; :func:`workers.surface.synthesize` applies it.
    The data are grouped by measurement time: a sample costs one inverse and one forward
    real FFT of N × N per distinct time, whatever the number of points.

    Attributes
    ----------
    spectrum : workers.spectra.Spectrum
        The spectrum of the unconditional sea.
    grid_size : int
        Number N of grid points along x and along y.
    spacing : float
        Grid spacing Δ, m.
    times : tuple of float
        The distinct measurement times, s.
    members : tuple of numpy.ndarray
        Per time, the indices of its data points.
    rows, columns : numpy.ndarray
        Grid rows (y) and columns (x) of the four nodes around each point, (D, 4) int.
    stencil : numpy.ndarray
        Bilinear weights of those nodes, (D, 4) float64.
    elevation : numpy.ndarray
        Measured elevations d, m, (D,).
    noise : float
        Measurement noise standard deviation σ, m.
    eigenvalues, eigenvectors : numpy.ndarray
        Eigen-decomposition of K (m², and orthonormal columns).
    power_half, power_mirror, omega_half : numpy.ndarray
        a²(k), a²(-k) (m²) and ω (rad/s) on the half-plane (rfft) layout.
    """

    spectrum: Spectrum
    grid_size: int
    spacing: float
    times: tuple[float, ...]
    members: tuple[np.ndarray, ...]
    rows: np.ndarray
    columns: np.ndarray
    stencil: np.ndarray
    elevation: np.ndarray
    noise: float
    eigenvalues: np.ndarray
    eigenvectors: np.ndarray
    power_half: np.ndarray
    power_mirror: np.ndarray
    omega_half: np.ndarray

    def __post_init__(self):
        for value in vars(self).values():
            for array in value if isinstance(value, tuple) else (value,):
                if isinstance(array, np.ndarray):
                    array.flags.writeable = False

    def correction(self, elevation_at, rng: np.random.Generator):
        r"""Spectral correction that conditions one unconditional realisation.

        With the synthesis's :math:`\tilde h(\mathbf k, t) = h_0(\mathbf k)e^{-i\omega t}
        + \overline{h_0(-\mathbf k)}e^{i\omega t}`, the correction
        :math:`\sum_d w_d C(\mathbf x - \mathbf x_d, t - t_d)` (bilinear stencils in
        place of the points) is of the same form with

        .. math::

            g_0(\mathbf k) = \tfrac12 a(\mathbf k)^2 \sum_g e^{i\omega t_g}
            \sum_{\text{nodes}} W_g e^{-i\mathbf k\cdot\mathbf x},

        W_g the weights of the data of time t_g spread on their nodes (Lᵀw). Adding g₀
        to h₀ conditions every frame, elevation and slopes alike, at no cost per frame.

        Parameters
        ----------
        elevation_at : callable
            ``elevation_at(t)``: the unconditional elevation on the grid at time t (s),
            an (N, N) array, m.
        rng : numpy.random.Generator
            Source of the D standard normal draws of the measurement noise ε.

        Returns
        -------
        ahead, behind : numpy.ndarray
            g₀(k) and :math:`\overline{g_0(-\mathbf k)}` on the half-plane layout, m,
            complex128 of shape (N, N//2 + 1), to add to h₀(k) and
            :math:`\overline{h_0(-\mathbf k)}`.
        """
        at_data = np.empty(self.elevation.size)
        for time, member in zip(self.times, self.members, strict=True):
            values = elevation_at(time)[self.rows[member], self.columns[member]]
            at_data[member] = np.einsum("dc,dc->d", values, self.stencil[member])
        noise = self.noise * rng.standard_normal(self.elevation.size)
        residual = self.elevation - at_data - noise
        weights = self.eigenvectors @ ((self.eigenvectors.T @ residual) / self.eigenvalues)
        n = self.grid_size
        ahead = np.zeros(self.power_half.shape, np.complex128)
        behind = np.zeros(self.power_half.shape, np.complex128)
        for time, member in zip(self.times, self.members, strict=True):
            spread = np.zeros((n, n))
            np.add.at(
                spread,
                (self.rows[member], self.columns[member]),
                weights[member, None] * self.stencil[member],
            )
            transform = scipy.fft.rfft2(spread)
            if time == 0.0:
                ahead += transform
                behind += transform
            else:
                phase = np.exp(1j * self.omega_half * time)
                ahead += phase * transform
                behind += np.conj(phase) * transform
        ahead *= 0.5 * self.power_half
        behind *= 0.5 * self.power_mirror
        return ahead, behind


def check_points(points, *, grid_size: int, spacing: float) -> np.ndarray:
    """Measured points checked without building anything: finite, on the patch, each once.

    Parameters
    ----------
    points : sequence of sequence of float
        Measurements (x, y, elevation) or (x, y, elevation, time), as `kriging` takes them.
    grid_size : int
        Number N of grid points along x and along y.
    spacing : float
        Grid spacing Δ, m.

    Returns
    -------
    numpy.ndarray
        The points as rows (x, y, elevation, time), float64 of shape (D, 4).

    Raises
    ------
    ValueError
        For no point, a value not finite, a point outside the patch (with its periodic
        equivalent inside), or two points at the same place and time.
    """
    n, spacing = int(grid_size), float(spacing)
    data = np.array([(*p[:3], p[3] if len(p) > 3 else 0.0) for p in points], dtype=np.float64)
    if data.ndim != 2 or data.shape[0] == 0:
        raise ValueError("conditioning needs at least one point [x, y, elevation(, time)]")
    if not np.all(np.isfinite(data)):
        raise ValueError("conditioning points must be finite numbers")
    period = n * spacing
    for index, (x, y) in enumerate(data[:, :2]):
        if not (0.0 <= x < period and 0.0 <= y < period):
            raise ValueError(
                f"point {index} (x={x:g} m, y={y:g} m) lies off the surface grid, which "
                f"covers [0, {period:g}) m in x and y and repeats with that period; the same "
                f"place on the grid is x={x % period:g} m, y={y % period:g} m"
            )
    seen: dict[tuple[float, float, float], int] = {}
    for index, (x, y, _, t) in enumerate(data):
        first = seen.setdefault((x, y, t), index)
        if first != index:
            raise ValueError(
                f"points {first} and {index} are both at x={x:g} m, y={y:g} m, t={t:g} s; "
                "give each place and time once"
            )
    return data


@functools.lru_cache(maxsize=16)
def kriging(
    spectrum: Spectrum,
    *,
    grid_size: int,
    spacing: float,
    points: tuple[tuple[float, ...], ...],
    noise: float,
) -> Kriging:
    r"""Build and check the kriging system of measured elevations.

    Parameters
    ----------
    spectrum : workers.spectra.Spectrum
        Directional wave spectrum of the unconditional sea.
    grid_size : int
        Number N of grid points along x and along y.
    spacing : float
        Grid spacing Δ, m.
    points : tuple of tuple of float
        Measurements (x, y, elevation) or (x, y, elevation, time): x and y in the
        surface patch [0, NΔ), m; elevation, m; time, s, on the clock of the frames
        (default 0, the first frame).
    noise : float
        Measurement noise standard deviation σ, m (≥ 0).

    Returns
    -------
    Kriging
        The system, with :math:`K = LCL^\top + \sigma^2 I` decomposed.

    Raises
    ------
    ValueError
        For a point outside the patch (with its periodic equivalent inside), two
        points at the same place and time, or a singular or ill-conditioned K
        (smallest/largest eigenvalue below :data:`RCOND`), naming the points that
        the nearly-null combination involves.

    Notes
    -----
    K is assembled from the covariance grids of :func:`space_time_covariance`, one
    inverse FFT per distinct time lag between measurements (C(Δx, -τ) = C(-Δx, τ)
    halves them): a snapshot needs one, measurements at G irregular times up to
    G(G + 1)/2. The result is cached (16 systems).

    References
    ----------
    .. [1] Journel, A. G., & Huijbregts, C. J. (1978). Mining Geostatistics, §V.D
       (conditional simulations). Academic Press.
    .. [2] Chilès, J.-P., & Delfiner, P. (2012). Geostatistics: Modeling Spatial
       Uncertainty, 2nd ed., §7.3.1 (conditioning by kriging). Wiley.
    """
    n, spacing = int(grid_size), float(spacing)
    data = check_points(points, grid_size=n, spacing=spacing)
    if not (np.isfinite(noise) and noise >= 0):
        raise ValueError(f"noise must be a non-negative number of metres, got {noise}")

    scaled = data[:, :2] / spacing
    corner = np.floor(scaled)
    fraction = scaled - corner
    corner = corner.astype(np.intp)
    offsets = np.array([[0, 0], [0, 1], [1, 0], [1, 1]])  # (dy, dx) of the four nodes
    rows = (corner[:, 1, None] + offsets[:, 0]) % n
    columns = (corner[:, 0, None] + offsets[:, 1]) % n
    fx, fy = fraction[:, 0, None], fraction[:, 1, None]
    stencil = np.where(offsets[:, 1] == 1, fx, 1.0 - fx) * np.where(
        offsets[:, 0] == 1, fy, 1.0 - fy
    )

    groups: dict[float, list[int]] = defaultdict(list)
    for index, t in enumerate(data[:, 3]):
        groups[float(t)].append(index)
    times = tuple(groups)
    members = tuple(np.asarray(groups[t], dtype=np.intp) for t in times)

    power, omega = _grid(spectrum, n, spacing)
    covariances: dict[float, np.ndarray] = {}
    matrix = np.empty((len(data), len(data)))
    for g, first in enumerate(members):
        for h in range(g, len(members)):
            lag = times[g] - times[h]
            if lag not in covariances:
                covariances[lag] = _covariance(power, omega, lag)
            block = _block(covariances[lag], n, rows, columns, stencil, first, members[h])
            matrix[np.ix_(first, members[h])] = block
            matrix[np.ix_(members[h], first)] = block.T
    matrix[np.diag_indices_from(matrix)] += noise**2
    eigenvalues, eigenvectors = np.linalg.eigh(matrix)
    largest = eigenvalues[-1]
    if not eigenvalues[0] > RCOND * largest:
        null = eigenvectors[:, 0]
        involved = np.flatnonzero(np.abs(null) >= 0.2 * np.abs(null).max())[:6]
        names = ", ".join(
            f"{i} ({data[i, 0]:g}, {data[i, 1]:g} m, t={data[i, 3]:g} s)" for i in involved
        )
        raise ValueError(
            f"the data covariance is singular or ill-conditioned (smallest/largest "
            f"eigenvalue {max(eigenvalues[0], 0.0) / largest:.1e} < {RCOND:g}): points "
            f"{names} are nearly redundant at this spectrum and grid; remove some of them "
            "or raise the noise"
        )

    half = n // 2 + 1
    mirror_rows = (-np.arange(n)) % n
    mirror_columns = (-np.arange(half)) % n
    return Kriging(
        spectrum=spectrum,
        grid_size=n,
        spacing=spacing,
        times=times,
        members=members,
        rows=rows,
        columns=columns,
        stencil=stencil,
        elevation=data[:, 2].copy(),
        noise=float(noise),
        eigenvalues=eigenvalues,
        eigenvectors=eigenvectors,
        power_half=power[:, :half].copy(),
        power_mirror=power[np.ix_(mirror_rows, mirror_columns)],
        omega_half=omega[:, :half].copy(),
    )


def _block(covariance, n, rows, columns, stencil, first, second):
    """(L C Lᵀ) between the points `first` and `second`, from a lag-grid of C."""
    out = np.empty((first.size, second.size))
    for start in range(0, first.size, _BLOCK):
        these = first[start : start + _BLOCK]
        dy = (rows[these, :, None, None] - rows[second][None, None]) % n
        dx = (columns[these, :, None, None] - columns[second][None, None]) % n
        out[start : start + _BLOCK] = np.einsum(
            "ac,acbe,be->ab", stencil[these], covariance[dy, dx], stencil[second]
        )
    return out
