r"""The layout of a multi-scale sea: FFT cascades of different patch sizes, one band each.

A sea is the sum of C cascades, each an N × N periodic grid; cascade c has the patch
:math:`L_c = N\Delta_c`, finest first (:math:`L_0 < L_1 < \dots`). Each holds a disjoint
band of wavenumber magnitudes of the same spectrum (no band counted twice):

.. math::

    \kappa_c \le |\mathbf k| < \kappa_{c-1},\qquad
    \kappa_{-1} = \frac{\pi}{\Delta_0},\qquad
    \kappa_c = \beta\,\frac{\pi}{\Delta_{c+1}}\ (c < C - 1),\qquad \kappa_{C-1} = 0,

with β = :data:`BAND_CUT`: a band ends a quarter of the way to the Nyquist wavenumber of
the coarser grid that holds the waves below it, where its bilinear interpolation keeps
90 % of a wave's variance. A grid point's power is the spectrum integrated over its cell
of the wavevector plane, restricted to the band, so that the cascades tile the plane
|k| < π/Δ₀ exactly; everything beyond (and what bilinear interpolation loses) is the
sub-grid slope of :func:`subgrid_slope_covariance`. The default patches come from
:func:`default_patches`; ``docs/model.md`` §1 states the rule.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from workers.sea.spectra import Spectrum

__all__ = [
    "BAND_CUT",
    "ENERGY_SHARE",
    "K_TOP",
    "MAX_CASCADES",
    "Sea",
    "check_patches",
    "default_patches",
    "describe",
    "resolved_share",
    "subgrid_slope_covariance",
]

BAND_CUT = 0.25
"""β: a coarser cascade holds the waves below β times its Nyquist wavenumber π/Δ."""

MAX_CASCADES = 4
"""Most cascades of a sea (a 256-point finest patch of 4.1 m grows to 16.8 km)."""

ENERGY_SHARE = 0.01
"""The default coarsest patch resolves all but this share of the elevation variance."""

K_TOP = 2.0 * math.pi / 1e-3
"""Top of the full band, rad/m (1 mm waves: viscosity damps shorter ones). It cuts the
divergent slope variance of k⁻³ tails (Pierson–Moskowitz, JONSWAP); Elfouhaily's and
Phillips' spectra have decayed long before it."""

# Cells of the wavevector plane whose power is integrated on SUBCELLS² points, not taken
# at the centre: those within RINGS cells of k = 0 (where Ψ changes by a large factor
# across a cell) and those that straddle a band's edge.
_SUBCELLS = 4
_RINGS = 16


def check_patches(*, grid_size: int, patches) -> None:
    """Refuse patches that do not make disjoint, non-empty bands on `grid_size` points.

    Raises
    ------
    ValueError
        Unless the patches (m, finest first) are finite, positive and each between 1
        (exclusive) and N/16 times the previous one: at most N/16, the band of the
        finer cascade starts at least two of its own grid steps Δk from k = 0.
    """
    limit = grid_size / 16.0
    for index, patch in enumerate(patches):
        if not (math.isfinite(patch) and patch > 0):
            raise ValueError(f"patch {index} must be a positive number of metres, got {patch}")
        if index and not patches[index - 1] < patch <= limit * patches[index - 1]:
            raise ValueError(
                f"patch {index} ({patch:g} m) must be larger than patch {index - 1} "
                f"({patches[index - 1]:g} m) and at most grid_size/16 = {limit:g} times it"
            )
    if len(patches) > MAX_CASCADES:
        raise ValueError(f"at most {MAX_CASCADES} cascades, got {len(patches)}")


@dataclass(frozen=True)
class Sea:
    """The cascades of a multi-scale sea.

    Parameters
    ----------
    spectrum : workers.sea.spectra.Spectrum
        Directional wave spectrum.
    grid_size : int
        Number N of grid points along x and along y of every cascade.
    patches : tuple of float
        Patch L_c of each cascade, m, finest first (see :func:`check_patches`).
    """

    spectrum: Spectrum
    grid_size: int
    patches: tuple[float, ...]

    def __post_init__(self):
        n = self.grid_size
        if isinstance(n, bool) or int(n) != n or n < 2:
            raise ValueError(f"grid_size must be an integer >= 2, got {n!r}")
        object.__setattr__(self, "grid_size", int(n))
        object.__setattr__(self, "patches", tuple(float(p) for p in self.patches))
        if not self.patches:
            raise ValueError("a sea needs at least one cascade")
        check_patches(grid_size=self.grid_size, patches=self.patches)

    def spacing(self, cascade: int) -> float:
        """Grid spacing Δ_c = L_c/N of a cascade, m."""
        return self.patches[cascade] / self.grid_size

    def band(self, cascade: int) -> tuple[float, float]:
        """Wavenumbers (κ_c, κ_{c-1}) bounding a cascade's band, rad/m (low inclusive)."""
        high = math.pi / self.spacing(0) if cascade == 0 else self.band(cascade - 1)[0]
        if cascade == len(self.patches) - 1:
            return 0.0, high
        return BAND_CUT * math.pi / self.spacing(cascade + 1), high

    def wavenumbers(self, cascade: int) -> np.ndarray:
        """FFT-ordered wavenumbers 2π·fftfreq(N, Δ_c) of a cascade, rad/m."""
        return 2.0 * np.pi * np.fft.fftfreq(self.grid_size, d=self.spacing(cascade))

    def amplitudes(self, cascade: int) -> np.ndarray:
        r"""Root-mean-square amplitude of each Fourier mode of a cascade, m.

        .. math::

            a(\mathbf k)^2 = \int_{\text{cell}(\mathbf k)} \Psi(\mathbf q)\,
            \mathbf 1[\kappa_c \le |\mathbf q| < \kappa_{c-1}]\,d^2q,

        the cell the Δk × Δk square around **k**, Δk = 2π/L_c. Near k = 0 and on a
        band's edges the integral is a 4 × 4 midpoint rule, elsewhere Ψ(k) Δk² times
        the band indicator at the centre. The mean mode and the Nyquist row and column
        (no travelling wave, no derivative on the grid) carry nothing.

        Returns
        -------
        numpy.ndarray
            a, m, float64 of shape (N, N) in FFT order: element [i, j] belongs to
            k_y = wavenumbers[i], k_x = wavenumbers[j]. Cached per sea and cascade.
        """
        return _amplitudes(self, cascade)

    def drawn_modes(self, cascade: int) -> np.ndarray:
        r"""FFT-ordered indices, along y and along x, of the modes a draw gives normals to.

        A coarser cascade's band ends at β = :data:`BAND_CUT` of its Nyquist wavenumber,
        so its modes vanish beyond index ±βN/2 along each axis: it is drawn on the square
        of modes :math:`|i|, |j| \le m` that holds its band, about (βN + 1)² of its N²
        modes (:func:`workers.sea.surface.draw`). A cascade whose band reaches its grid's
        Nyquist wavenumber (the finest) is drawn whole.

        Returns
        -------
        numpy.ndarray
            The indices, int, ascending in FFT order: N of them (0 … N − 1) for a
            cascade drawn whole, else 0 … m then N − m … N − 1. Cached per sea and
            cascade, read-only.
        """
        return _drawn_modes(self, cascade)


@functools.lru_cache(maxsize=32)
def _drawn_modes(sea: Sea, cascade: int) -> np.ndarray:
    n = sea.grid_size
    signed = np.abs(np.fft.fftfreq(n, d=1.0 / n)).astype(int)
    rows, columns = np.nonzero(sea.amplitudes(cascade))
    reach = int(max(signed[rows].max(initial=0), signed[columns].max(initial=0)))
    index = np.arange(n) if reach >= n // 2 - 1 else np.flatnonzero(signed <= reach)
    index.flags.writeable = False
    return index


@functools.lru_cache(maxsize=32)
def _amplitudes(sea: Sea, cascade: int) -> np.ndarray:
    n = sea.grid_size
    k = sea.wavenumbers(cascade)
    dk = 2.0 * np.pi / sea.patches[cascade]
    low, high = sea.band(cascade)
    kx, ky = k[None, :], k[:, None]
    magnitude = np.hypot(kx, ky)
    inside = (magnitude >= low) & (magnitude < high)
    power = np.where(inside, sea.spectrum.directional(kx, ky) * dk**2, 0.0)
    reach = 0.75 * dk  # half a cell's diagonal, with margin
    refine = (magnitude < _RINGS * dk) | (np.abs(magnitude - low) < reach)
    refine |= np.abs(magnitude - high) < reach
    rows, columns = np.nonzero(refine)
    offsets = ((np.arange(_SUBCELLS) + 0.5) / _SUBCELLS - 0.5) * dk
    qx = k[columns, None, None] + offsets[None, None, :]
    qy = k[rows, None, None] + offsets[None, :, None]
    q = np.hypot(qx, qy)
    values = np.where((q >= low) & (q < high), sea.spectrum.directional(qx, qy), 0.0)
    power[rows, columns] = values.mean(axis=(1, 2)) * dk**2
    power[0, 0] = 0.0
    if n % 2 == 0:
        power[n // 2, :] = 0.0
        power[:, n // 2] = 0.0
    amplitude = np.sqrt(power)
    amplitude.flags.writeable = False
    return amplitude


@functools.lru_cache(maxsize=64)
def _energy_wavenumber(spectrum: Spectrum) -> float:
    """The wavenumber below which the spectrum holds ENERGY_SHARE of Var η, rad/m.

    The cumulative variance ∫ k S(k) d(ln k) by the trapezoid rule on 4001 points of
    ln k from 10⁻⁵ to K_TOP rad/m (steps of 0.005), interpolated linearly in ln k.
    """
    u = np.linspace(math.log(1e-5), math.log(K_TOP), 4001)
    density = np.exp(u) * spectrum.omnidirectional(np.exp(u))
    cumulative = np.concatenate([[0.0], np.cumsum(0.5 * (density[1:] + density[:-1]))])
    return float(np.exp(np.interp(ENERGY_SHARE * cumulative[-1], cumulative, u)))


def default_patches(spectrum: Spectrum, *, grid_size: int, spacing: float, span: float):
    r"""The default cascades: patches from the footprint and the spectrum, m.

    The finest patch is N Δ. Each further patch is r = ⌊N/16⌋ times the previous one
    (none if r < 2), added until the coarsest patch covers both the footprint's span
    and 2π/k_E, where the waves with k < k_E hold :data:`ENERGY_SHARE` of the elevation
    variance (the coarsest grid step Δk is then below k_E), or until there are
    :data:`MAX_CASCADES`.

    Parameters
    ----------
    spectrum : workers.sea.spectra.Spectrum
        Directional wave spectrum.
    grid_size : int
        Number N of grid points of every cascade.
    spacing : float
        Spacing Δ of the finest grid, m.
    span : float
        Longest chord of the receiver's footprint along x or y, m.

    Returns
    -------
    tuple of float
        The patches, finest first, m.
    """
    patches = [grid_size * spacing]
    ratio = grid_size // 16
    if ratio < 2:
        return tuple(patches)
    need = max(span, 2.0 * math.pi / _energy_wavenumber(spectrum))
    while patches[-1] < need and len(patches) < MAX_CASCADES:
        patches.append(patches[-1] * ratio)
    return tuple(patches)


def _interpolation_loss(sea: Sea, cascade: int) -> np.ndarray:
    r"""(N, N) share of a mode's variance that bilinear interpolation keeps, on average.

    A wave e^{ikx} interpolated linearly between nodes Δ apart at a uniformly random
    place has mean-square :math:`(2 + \cos k\Delta)/3`; bilinearly, the product of the
    factors along x and y.
    """
    phase = sea.wavenumbers(cascade) * sea.spacing(cascade)
    factor = (2.0 + np.cos(phase)) / 3.0
    return factor[:, None] * factor[None, :]


@functools.lru_cache(maxsize=64)
def _full_slope_tensor(spectrum: Spectrum) -> np.ndarray:
    r"""∬_{|k|<K_TOP} k kᵀ Ψ d²k, the full band's slope covariance (2 × 2)."""
    u = np.linspace(math.log(1e-5), math.log(K_TOP), 4001)
    phi = np.linspace(-np.pi, np.pi, 72, endpoint=False)
    k = np.exp(u)[:, None]
    psi = phi[None, :] + spectrum.wind_direction
    density = spectrum.omnidirectional(k) * spectrum.spreading(k, phi[None, :]) * k**3
    weights = np.full(u.size, u[1] - u[0])
    weights[[0, -1]] *= 0.5
    angular = 2.0 * np.pi / phi.size
    moments = [np.cos(psi) ** 2, np.cos(psi) * np.sin(psi), np.sin(psi) ** 2]
    xx, xy, yy = ((weights @ (density * m)).sum() * angular for m in moments)
    tensor = np.array([[xx, xy], [xy, yy]])
    if xx + yy <= 0:  # a spectrum narrower than this grid: no tail to speak of
        return tensor
    # the trace from the spectrum's own quadrature, the shape from this one
    return tensor * spectrum.slope_variance(k_max=K_TOP) / (xx + yy)


@functools.lru_cache(maxsize=32)
def subgrid_slope_covariance(sea: Sea) -> np.ndarray:
    r"""Covariance of the slopes the cascades do not show at a random point (2 × 2).

    .. math::

        \Sigma = \iint_{|\mathbf k| < K_{top}} \mathbf k\mathbf k^\top \Psi\,d^2k
        - \sum_c \sum_{\mathbf k} \mathbf k\mathbf k^\top a_c(\mathbf k)^2
        \,f(k_x\Delta_c) f(k_y\Delta_c),\qquad f(\theta) = \frac{2 + \cos\theta}{3}:

    the slope of the waves beyond the finest grid's Nyquist wavenumber (the spectrum's
    tail up to :data:`K_TOP`) plus what bilinear interpolation of the resolved slopes
    loses on average. Eigenvalues below zero (the quadratures' rounding) are set to 0.

    Returns
    -------
    numpy.ndarray
        Σ (dimensionless), float64 of shape (2, 2), indexed (x, y); read-only, cached
        per sea.
    """
    tensor = _full_slope_tensor(sea.spectrum).copy()
    for cascade in range(len(sea.patches)):
        k = sea.wavenumbers(cascade)
        power = sea.amplitudes(cascade) ** 2 * _interpolation_loss(sea, cascade)
        kx, ky = k[None, :], k[:, None]
        tensor -= [
            [np.sum(power * kx * kx), np.sum(power * kx * ky)],
            [np.sum(power * kx * ky), np.sum(power * ky * ky)],
        ]
    values, vectors = np.linalg.eigh(0.5 * (tensor + tensor.T))
    covariance = (vectors * np.maximum(values, 0.0)) @ vectors.T
    covariance.flags.writeable = False
    return covariance


def resolved_share(sea: Sea) -> tuple[float, float]:
    """Shares of the elevation variance and of the full-band slope variance resolved.

    Returns
    -------
    elevation, slope : float
        Σ_c Σ_k a_c² over Var η, and Σ_c Σ_k |k|² a_c² over the slope variance up to
        :data:`K_TOP` (both on the grid nodes, before interpolation), dimensionless.
    """
    elevation = slope = 0.0
    for cascade in range(len(sea.patches)):
        k = sea.wavenumbers(cascade)
        power = sea.amplitudes(cascade) ** 2
        elevation += float(power.sum())
        slope += float(np.sum(power * (k[None, :] ** 2 + k[:, None] ** 2)))
    spectrum = sea.spectrum
    return elevation / spectrum.variance(), slope / spectrum.slope_variance(k_max=K_TOP)


def describe(sea: Sea) -> str:
    """One sentence: the cascades and the shares of the spectrum they resolve."""
    elevation, slope = resolved_share(sea)
    patches = ", ".join(f"{patch:.4g}" for patch in sea.patches)
    return (
        f"{len(sea.patches)} cascade(s) of {sea.grid_size}^2 points, patches {patches} m; they "
        f"resolve {100 * elevation:.1f} % of the spectrum's elevation variance and "
        f"{100 * slope:.1f} % of its slope variance (the rest of the slope enters as sub-grid "
        "blur)"
    )
