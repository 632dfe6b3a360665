r"""Sea surfaces conditioned on point measurements of the elevation (conditioning by kriging).

The field of :func:`workers.sea.surface.draw` is Gaussian, so a surface drawn given measured
elevations is exact and cheap: an unconditional sample plus a kriging correction of its
residual at the data (Journel & Huijbregts 1978, §V.D; Chilès & Delfiner 2012, §7.3). With
:math:`L` the data functionals, :math:`K = LCL^\top + \sigma^2 I` and
:math:`\varepsilon \sim N(0, \sigma^2 I)` drawn with the sample,

.. math::

    \eta_c(\mathbf x, t) = \eta_u(\mathbf x, t)
    + \sum_d w_d\,(C L^\top)_d(\mathbf x, t),\qquad
    \mathbf w = K^{-1}\left(\mathbf d - L\eta_u - \varepsilon\right),

has exactly the law of η given the data (with or without noise). Conditioning is composed
on top of the synthesis, as GSTools' conditioned fields are: :meth:`Kriging.condition` takes
the drawn modes and returns corrected ones, and the synthesis knows nothing of it.

The sea is a sum of independent cascades (:class:`workers.sea.cascades.Sea`), so the
covariance of the summed field is the sum of the cascades' covariances, each that of the
synthesised periodic field, not of the continuous spectrum (the two agree to rounding):

.. math::

    C(\Delta\mathbf x, \Delta t) = \sum_c C_c(\Delta\mathbf x, \Delta t),\qquad
    C_c = \sum_{\mathbf k} a_c(\mathbf k)^2 \cos(\mathbf k\cdot\Delta\mathbf x - \omega\,\Delta t),

the inner sum over cascade c's FFT grid with a_c from
:meth:`workers.sea.cascades.Sea.amplitudes` and ω from :func:`workers.sea.spectra.dispersion`. On
the grid nodes it is one inverse FFT of :math:`a_c^2 e^{-i\omega\Delta t}`.

A measurement is of the elevation as the renderer sees it: the sum over cascades of the
bilinear interpolation of the four nodes around the point
(:meth:`workers.sea.surface.Surface.elevation_at`), at its time. L is then exact, the data are
honoured (to rounding when σ = 0), and points need not lie on nodes. The correction of a
cascade is a spectral one of its modes (:meth:`Kriging.correction`), so it conditions every
frame, elevation and slopes alike; the sub-grid slopes are not conditioned.
"""

from __future__ import annotations

import functools
from collections import defaultdict
from dataclasses import dataclass, replace

import numpy as np
import scipy.fft

from workers.sea.cascades import Sea
from workers.sea.spectra import dispersion
from workers.sea.surface import Modes

__all__ = ["RCOND", "Kriging", "check_points", "kriging", "space_time_covariance"]

RCOND = 1e-9
"""Smallest accepted ratio of the smallest to the largest eigenvalue of K (1 / condition
number). The weights are solved in float64 to a relative error of about 2×10⁻¹⁶ over this
ratio: at the limit 2×10⁻⁷, the float32 rounding of the fields themselves."""

# Data rows per block when K is assembled (16 corner pairs per entry: 64 rows of a
# 1000-point system keep the temporaries near 8 MB).
_BLOCK = 64


def _grid(sea: Sea, cascade: int):
    """a² (float64 from the synthesis's float32 a) and ω on a cascade's full FFT grid."""
    power = sea.amplitudes(cascade).astype(np.float32).astype(np.float64) ** 2
    k = sea.wavenumbers(cascade)
    return power, dispersion(np.hypot(k[None, :], k[:, None]))


def space_time_covariance(sea: Sea, *, cascade: int = 0, lag: float = 0.0) -> np.ndarray:
    r"""Space–time covariance of one synthesised cascade on its grid lags, m².

    .. math::

        C_{ij} = C_c(j\Delta_c, i\Delta_c, \tau)
        = \sum_{\mathbf k} a_c(\mathbf k)^2 \cos(k_x j\Delta_c + k_y i\Delta_c - \omega\tau)
        = \operatorname{Re}\,\mathcal F^{-1}\!\left[a_c^2 e^{-i\omega\tau}\right]_{ij}

    (the inverse FFT without the 1/N² factor).

    Parameters
    ----------
    sea : workers.sea.cascades.Sea
        The layout.
    cascade : int, optional
        Index of the cascade, finest first.
    lag : float, optional
        Time lag τ, s: C is the covariance of η_c at (x + jΔ, y + iΔ, t + τ) with η_c at
        (x, y, t).

    Returns
    -------
    numpy.ndarray
        C, m², float64 of shape (N, N) indexed [i, j] (y lag, x lag), periodic.

    Notes
    -----
    a is taken in float32, as the synthesis draws with it, so the covariance is that of
    the sampled field to rounding. The field decorrelates in time, mode by mode.

    References
    ----------
    .. [1] Chilès, J.-P., & Delfiner, P. (2012). Geostatistics: Modeling Spatial
       Uncertainty, 2nd ed., §7.3 (spectral simulation). Wiley.
    """
    power, omega = _grid(sea, cascade)
    return _covariance(power, omega, lag)


def _covariance(power, omega, lag):
    if lag == 0.0:
        weights = power.astype(np.complex128)
    else:
        weights = power * np.exp(-1j * omega * lag)
    return scipy.fft.ifft2(weights, norm="forward").real


@dataclass(frozen=True, eq=False)
class _Stencil:
    """The four nodes around each datum on one cascade's grid and their bilinear weights."""

    rows: np.ndarray  # (D, 4) int
    columns: np.ndarray  # (D, 4) int
    weights: np.ndarray  # (D, 4) float64
    power_half: np.ndarray  # a²(k) on the half-plane, m²
    power_mirror: np.ndarray  # a²(-k) on the half-plane, m²
    omega_half: np.ndarray  # ω on the half-plane, rad/s


def _stencil(sea: Sea, cascade: int, data: np.ndarray) -> _Stencil:
    n, spacing = sea.grid_size, sea.spacing(cascade)
    scaled = data[:, :2] / spacing
    corner = np.floor(scaled)
    fraction = scaled - corner
    corner = corner.astype(np.intp)
    offsets = np.array([[0, 0], [0, 1], [1, 0], [1, 1]])  # (dy, dx) of the four nodes
    rows = (corner[:, 1, None] + offsets[:, 0]) % n
    columns = (corner[:, 0, None] + offsets[:, 1]) % n
    fx, fy = fraction[:, 0, None], fraction[:, 1, None]
    weights = np.where(offsets[:, 1] == 1, fx, 1.0 - fx) * np.where(
        offsets[:, 0] == 1, fy, 1.0 - fy
    )
    power, omega = _grid(sea, cascade)
    half = n // 2 + 1
    mirror_rows, mirror_columns = (-np.arange(n)) % n, (-np.arange(half)) % n
    return _Stencil(
        rows=rows,
        columns=columns,
        weights=weights,
        power_half=power[:, :half].copy(),
        power_mirror=power[np.ix_(mirror_rows, mirror_columns)],
        omega_half=omega[:, :half].copy(),
    )


@dataclass(frozen=True, eq=False)
class Kriging:
    """The kriging system of one set of measurements on one sea.

    Built (and cached) by :func:`kriging`; :meth:`condition` applies it to drawn modes.
    The data are grouped by measurement time: a sample costs, per cascade, one inverse
    and one forward real FFT of N × N per distinct time, whatever the number of points.

    Attributes
    ----------
    sea : workers.sea.cascades.Sea
        The layout of the unconditional sea.
    times : tuple of float
        The distinct measurement times, s.
    members : tuple of numpy.ndarray
        Per time, the indices of its data points.
    stencils : tuple of _Stencil
        Per cascade, the data's bilinear nodes and weights and the cascade's a² and ω.
    elevation : numpy.ndarray
        Measured elevations d, m, (D,).
    noise : float
        Measurement noise standard deviation σ, m.
    eigenvalues, eigenvectors : numpy.ndarray
        Eigen-decomposition of K (m², and orthonormal columns).
    """

    sea: Sea
    times: tuple[float, ...]
    members: tuple[np.ndarray, ...]
    stencils: tuple[_Stencil, ...]
    elevation: np.ndarray
    noise: float
    eigenvalues: np.ndarray
    eigenvectors: np.ndarray

    def condition(self, modes: Modes, rng: np.random.Generator) -> Modes:
        """Modes conditioned on the data: `modes` plus their kriging correction.

        Parameters
        ----------
        modes : workers.sea.surface.Modes
            An unconditional draw on this system's sea.
        rng : numpy.random.Generator
            Source of the D standard normal draws of the measurement noise ε.

        Returns
        -------
        workers.sea.surface.Modes
            The corrected modes (same sub-grid key).
        """
        if modes.sea != self.sea:
            raise ValueError("conditioning was built for another sea")
        corrections = self.correction(modes.elevation_grid, rng)
        ahead = tuple(a + c[0] for a, c in zip(modes.ahead, corrections, strict=True))
        behind = tuple(b + c[1] for b, c in zip(modes.behind, corrections, strict=True))
        return replace(modes, ahead=ahead, behind=behind)

    def correction(self, elevation_grid, rng: np.random.Generator):
        r"""Spectral corrections, per cascade, that condition one unconditional realisation.

        With the synthesis's :math:`\tilde h_c(\mathbf k, t) = h_0(\mathbf k)e^{-i\omega t}
        + \overline{h_0(-\mathbf k)}e^{i\omega t}`, the correction
        :math:`\sum_d w_d C_c(\mathbf x - \mathbf x_d, t - t_d)` (bilinear stencils in
        place of the points) of cascade c is of the same form with

        .. math::

            g_0(\mathbf k) = \tfrac12 a_c(\mathbf k)^2 \sum_g e^{i\omega t_g}
            \sum_{\text{nodes}} W_g e^{-i\mathbf k\cdot\mathbf x},

        W_g the weights of the data of time t_g spread on the cascade's nodes
        (L_cᵀw). The weights w are shared by the cascades: K sums their covariances.

        Parameters
        ----------
        elevation_grid : callable
            ``elevation_grid(cascade, t)``: a cascade's unconditional elevation on its
            grid at time t (s), an (N, N) array, m.
        rng : numpy.random.Generator
            Source of the D standard normal draws of the measurement noise ε.

        Returns
        -------
        list of (ahead, behind)
            Per cascade, g₀(k) and :math:`\overline{g_0(-\mathbf k)}` on the half-plane
            layout, m, complex128 of shape (N, N//2 + 1), to add to h₀(k) and
            :math:`\overline{h_0(-\mathbf k)}`.
        """
        at_data = np.zeros(self.elevation.size)
        for cascade, stencil in enumerate(self.stencils):
            for time, member in zip(self.times, self.members, strict=True):
                grid = elevation_grid(cascade, time)
                values = grid[stencil.rows[member], stencil.columns[member]]
                at_data[member] += np.einsum("dc,dc->d", values, stencil.weights[member])
        noise = self.noise * rng.standard_normal(self.elevation.size)
        residual = self.elevation - at_data - noise
        weights = self.eigenvectors @ ((self.eigenvectors.T @ residual) / self.eigenvalues)
        n = self.sea.grid_size
        corrections = []
        for stencil in self.stencils:
            ahead = np.zeros(stencil.power_half.shape, np.complex128)
            behind = np.zeros(stencil.power_half.shape, np.complex128)
            for time, member in zip(self.times, self.members, strict=True):
                spread = np.zeros((n, n))
                np.add.at(
                    spread,
                    (stencil.rows[member], stencil.columns[member]),
                    weights[member, None] * stencil.weights[member],
                )
                transform = scipy.fft.rfft2(spread)
                if time == 0.0:
                    ahead += transform
                    behind += transform
                else:
                    phase = np.exp(1j * stencil.omega_half * time)
                    ahead += phase * transform
                    behind += np.conj(phase) * transform
            ahead *= 0.5 * stencil.power_half
            behind *= 0.5 * stencil.power_mirror
            corrections.append((ahead, behind))
        return corrections


def check_points(points, *, period: float) -> np.ndarray:
    """Measured points checked without building anything: finite, on the patch, each once.

    Parameters
    ----------
    points : sequence of sequence of float
        Measurements (x, y, elevation) or (x, y, elevation, time), as `kriging` takes them.
    period : float
        Side of the sea's coarsest periodic patch (`workers.sea.cascades.Sea.patches`), m.

    Returns
    -------
    numpy.ndarray
        The points as rows (x, y, elevation, time), float64 of shape (D, 4).

    Raises
    ------
    ValueError
        For no point, a value not finite, a point outside the coarsest patch, or two
        points at the same place and time.
    """
    data = np.array([(*p[:3], p[3] if len(p) > 3 else 0.0) for p in points], dtype=np.float64)
    if data.ndim != 2 or data.shape[0] == 0:
        raise ValueError("conditioning needs at least one point [x, y, elevation(, time)]")
    if not np.all(np.isfinite(data)):
        raise ValueError("conditioning points must be finite numbers")
    for index, (x, y) in enumerate(data[:, :2]):
        if not (0.0 <= x < period and 0.0 <= y < period):
            raise ValueError(
                f"point {index} (x={x:g} m, y={y:g} m) lies off the sea's coarsest patch, "
                f"which covers [0, {period:g}) m in x and y"
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
def kriging(sea: Sea, *, points: tuple[tuple[float, ...], ...], noise: float) -> Kriging:
    r"""Build and check the kriging system of measured elevations.

    Parameters
    ----------
    sea : workers.sea.cascades.Sea
        The layout (spectrum and cascades) of the unconditional sea.
    points : tuple of tuple of float
        Measurements (x, y, elevation) or (x, y, elevation, time): x and y in the
        coarsest patch [0, L), m; elevation, m; time, s, on the clock of the frames
        (default 0, the first frame).
    noise : float
        Measurement noise standard deviation σ, m (≥ 0).

    Returns
    -------
    Kriging
        The system, with :math:`K = \sum_c L_c C_c L_c^\top + \sigma^2 I` decomposed.

    Raises
    ------
    ValueError
        For a point outside the coarsest patch, two points at the same place and time,
        or a singular or ill-conditioned K (smallest/largest eigenvalue below
        :data:`RCOND`), naming the points that the nearly-null combination involves.

    Notes
    -----
    K is assembled from the covariance grids of :func:`space_time_covariance`, per
    cascade one inverse FFT per distinct time lag between measurements
    (C(Δx, -τ) = C(-Δx, τ) halves them): a snapshot needs one, measurements at G
    irregular times up to G(G + 1)/2. The result is cached (16 systems).

    References
    ----------
    .. [1] Journel, A. G., & Huijbregts, C. J. (1978). Mining Geostatistics, §V.D
       (conditional simulations). Academic Press.
    .. [2] Chilès, J.-P., & Delfiner, P. (2012). Geostatistics: Modeling Spatial
       Uncertainty, 2nd ed., §7.3.1 (conditioning by kriging). Wiley.
    """
    data = check_points(points, period=sea.patches[-1])
    if not (np.isfinite(noise) and noise >= 0):
        raise ValueError(f"noise must be a non-negative number of metres, got {noise}")

    groups: dict[float, list[int]] = defaultdict(list)
    for index, t in enumerate(data[:, 3]):
        groups[float(t)].append(index)
    times = tuple(groups)
    members = tuple(np.asarray(groups[t], dtype=np.intp) for t in times)

    stencils = tuple(_stencil(sea, cascade, data) for cascade in range(len(sea.patches)))
    matrix = np.zeros((len(data), len(data)))
    for cascade, stencil in enumerate(stencils):
        power, omega = _grid(sea, cascade)
        covariances: dict[float, np.ndarray] = {}
        for g, first in enumerate(members):
            for h in range(g, len(members)):
                lag = times[g] - times[h]
                if lag not in covariances:
                    covariances[lag] = _covariance(power, omega, lag)
                block = _block(covariances[lag], sea.grid_size, stencil, first, members[h])
                matrix[np.ix_(first, members[h])] += block
                if h != g:
                    matrix[np.ix_(members[h], first)] += block.T
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
    for array in (eigenvalues, eigenvectors):
        array.flags.writeable = False
    return Kriging(
        sea=sea,
        times=times,
        members=members,
        stencils=stencils,
        elevation=data[:, 2].copy(),
        noise=float(noise),
        eigenvalues=eigenvalues,
        eigenvectors=eigenvectors,
    )


def _block(covariance, n, stencil, first, second):
    """(L C Lᵀ) of one cascade between the points `first` and `second`, from its C grid."""
    rows, columns, weights = stencil.rows, stencil.columns, stencil.weights
    out = np.empty((first.size, second.size))
    for start in range(0, first.size, _BLOCK):
        these = first[start : start + _BLOCK]
        dy = (rows[these, :, None, None] - rows[second][None, None]) % n
        dx = (columns[these, :, None, None] - columns[second][None, None]) % n
        out[start : start + _BLOCK] = np.einsum(
            "ac,acbe,be->ab", weights[these], covariance[dy, dx], weights[second]
        )
    return out
