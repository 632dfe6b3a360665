r"""FFT synthesis of a Gaussian, homogeneous, periodic sea surface and its slopes.

The surface is a sum of Fourier modes on an N × N periodic grid of spacing Δ, with
grid coordinates :math:`x_j = j\Delta` (j = 0 … N-1) and wavenumbers on the FFT grid,
:math:`\Delta k = 2\pi / (N\Delta)`. Arrays are indexed (t, y, x): axis -1 is x.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import scipy.fft

from workers.spectra import Spectrum, dispersion

if TYPE_CHECKING:
    from workers.conditioning import Kriging

# Points per block in Surface.sample. The temporaries of a block (256 KiB for an index
# array) are reused from the heap when glibc's mmap threshold is raised
# (service.tuning.tune_allocator, or glibc's own dynamic threshold after the first free);
# page faults on fresh mappings were measured to make a 262144-point call four times
# slower. Larger blocks pay less per-call overhead: 32768 was measured 1.5 times faster
# than 8192 for 65536 points with the tuned allocator.
_SAMPLE_BLOCK = 32768


def _wavenumbers(grid_size: int, spacing: float) -> np.ndarray:
    """FFT-ordered wavenumbers 2π·fftfreq(N, Δ), rad/m (float64)."""
    return 2.0 * np.pi * np.fft.fftfreq(grid_size, d=spacing)


def _check_grid(grid_size, spacing) -> None:
    if isinstance(grid_size, bool) or int(grid_size) != grid_size or grid_size < 2:
        raise ValueError(f"grid_size must be an integer >= 2, got {grid_size!r}")
    if not (math.isfinite(spacing) and spacing > 0):
        raise ValueError(f"spacing must be a positive number of metres, got {spacing!r}")


def surface_amplitudes(spectrum: Spectrum, *, grid_size: int, spacing: float) -> np.ndarray:
    r"""Root-mean-square amplitude of each Fourier mode of the grid, m.

    .. math::

        a(\mathbf k) = \sqrt{\Psi(k_x, k_y)\,\Delta k^2},\qquad
        \Delta k = \frac{2\pi}{N\Delta},\qquad
        \sum_{\mathbf k} a^2 = \sum_{\mathbf k} \Psi\,\Delta k^2,

    with Ψ = ``spectrum.directional``; the mean (k = 0) mode has no energy.

    Parameters
    ----------
    spectrum : workers.spectra.Spectrum
        Directional wave spectrum.
    grid_size : int
        Number N of grid points along x and along y.
    spacing : float
        Grid spacing Δ, m.

    Returns
    -------
    numpy.ndarray
        a, m, float64 of shape (N, N) in FFT order: element [i, j] belongs to
        k_y = 2π·fftfreq(N, Δ)[i], k_x = 2π·fftfreq(N, Δ)[j].

    Notes
    -----
    A pure function of its inputs (spectra are frozen dataclasses), so callers may
    cache it; :func:`synthesize` does. The Nyquist row and column (even N) take Ψ at
    k = -π/Δ, the value of ``fftfreq``.
    """
    _check_grid(grid_size, spacing)
    k = _wavenumbers(int(grid_size), spacing)
    dk = 2.0 * np.pi / (grid_size * spacing)
    return np.sqrt(spectrum.directional(k[None, :], k[:, None])) * dk


@dataclass(frozen=True)
class _Setup:
    """Per-(spectrum, grid) arrays for :func:`synthesize`, half-plane (rfft) layout."""

    amplitude: np.ndarray  # (N, N) float32, sqrt(Ψ Δk²) in FFT order
    mirror: np.ndarray  # (N·(N//2+1),) flat index into (N, N) of -k for each half-plane k
    omega: np.ndarray  # (N, N//2+1) float64, ω(|k|) from `dispersion`, rad/s
    derivative: np.ndarray  # (3, N, N//2+1) complex64: 1, i k_x, i k_y (0 at Nyquist)


@functools.lru_cache(maxsize=16)
def _setup(spectrum: Spectrum, grid_size: int, spacing: float) -> _Setup:
    n = grid_size
    half = n // 2 + 1
    k = _wavenumbers(n, spacing)
    kx, ky = k[None, :half], k[:, None]
    # The Nyquist mode (-1)^j has no derivative on the grid: i k η̂ there would break
    # Hermitian symmetry, so its derivative is set to zero.
    kx_derivative = np.where(np.arange(half) == n / 2, 0.0, kx)
    ky_derivative = np.where(np.arange(n)[:, None] == n / 2, 0.0, ky)
    derivative = np.empty((3, n, half), np.complex64)
    derivative[0] = 1.0
    derivative[1] = 1j * kx_derivative
    derivative[2] = 1j * ky_derivative
    rows = (-np.arange(n)) % n
    columns = (-np.arange(half)) % n
    mirror = (rows[:, None] * n + columns[None, :]).ravel()
    amplitude = surface_amplitudes(spectrum, grid_size=n, spacing=spacing).astype(np.float32)
    for array in (amplitude, mirror, derivative):
        array.flags.writeable = False
    return _Setup(amplitude, mirror, dispersion(np.hypot(kx, ky)), derivative)


@dataclass(frozen=True, eq=False)
class Surface:
    """A synthesised sea surface: elevation and slopes on a periodic grid, per frame.

    Parameters
    ----------
    elevation : numpy.ndarray
        Elevation η above mean sea level, m, float32 of shape (T, N, N), index order
        (frame, y, x); element [t, i, j] is at x = jΔ, y = iΔ.
    slope_x, slope_y : numpy.ndarray
        ∂η/∂x and ∂η/∂y (dimensionless), float32 of shape (T, N, N).
    spacing : float
        Grid spacing Δ, m.
    grid_size : int
        Number N of grid points along x and along y.

    Notes
    -----
    The three arrays are stored float32, C-ordered and read-only. The surface is
    periodic with period NΔ in x and in y.
    """

    elevation: np.ndarray
    slope_x: np.ndarray
    slope_y: np.ndarray
    spacing: float
    grid_size: int

    def __post_init__(self):
        _check_grid(self.grid_size, self.spacing)
        n = int(self.grid_size)
        frames = None
        for name in ("elevation", "slope_x", "slope_y"):
            array = np.ascontiguousarray(getattr(self, name), dtype=np.float32)
            if array.ndim != 3 or array.shape[1:] != (n, n) or array.shape[0] < 1:
                raise ValueError(f"{name} must have shape (frames, {n}, {n}), got {array.shape}")
            if frames is not None and array.shape[0] != frames:
                raise ValueError(f"{name} has {array.shape[0]} frames, elevation has {frames}")
            frames = array.shape[0]
            array.flags.writeable = False
            object.__setattr__(self, name, array)
        object.__setattr__(self, "_wrapped", {})

    def _wrapped_fields(self, frame):
        """Elevation and slopes of `frame`, each padded to (N + 1, N + 1) and flattened.

        Row N and column N repeat row 0 and column 0, so the four corners of a cell need
        no wrapping. Made on first use and kept (4(N + 1)² bytes per field and frame).
        """
        frame = int(frame)
        if frame not in self._wrapped:
            n = int(self.grid_size)
            padded = np.empty((3, n + 1, n + 1), np.float32)
            for field, grid in zip(
                padded, (self.elevation, self.slope_x, self.slope_y), strict=True
            ):
                field[:n, :n] = grid[frame]
                field[n, :n] = grid[frame, 0]
                field[:, n] = field[:, 0]
            self._wrapped[frame] = tuple(field.ravel() for field in padded)
        return self._wrapped[frame]

    def sample(self, x, y, frame=0):
        r"""Bilinear, periodically wrapped elevation and slopes at world points.

        .. math::

            f(x, y) = (1-t_y)\left[(1-t_x) f_{i,j} + t_x f_{i,j+1}\right]
            + t_y\left[(1-t_x) f_{i+1,j} + t_x f_{i+1,j+1}\right],

        with :math:`j + t_x = x/\Delta`, :math:`i + t_y = y/\Delta`,
        :math:`0 \le t < 1`, and indices taken modulo N.

        Parameters
        ----------
        x, y : array_like
            World coordinates, m (broadcast together).
        frame : int, optional
            Frame index into the first axis of the fields.

        Returns
        -------
        elevation, slope_x, slope_y : numpy.ndarray
            η (m), ∂η/∂x and ∂η/∂y, float32 of the broadcast shape of ``x`` and ``y``.

        Notes
        -----
        Coordinates are converted to float32 first, so a point is located to about
        6×10⁻⁸ |x| (0.06 mm at 1 km). The slopes are interpolated spectral slopes, not
        the derivative of the interpolated elevation. A power-of-two N wraps indices
        with a bit mask, any other N with a (slower) remainder; a copy of each frame
        with its first row and column repeated after the last (made on first use and
        kept) gives the other three corners without wrapping. Points are processed in
        blocks of 32768 to keep the temporaries small.
        """
        return self._sample(self._wrapped_fields(frame), x, y)

    def elevation_at(self, x, y, frame=0):
        """Bilinear, periodically wrapped elevation alone at world points, m (see `sample`)."""
        return self._sample(self._wrapped_fields(frame)[:1], x, y)[0]

    def slopes_at(self, x, y, frame=0):
        """Bilinear, periodically wrapped slopes ∂η/∂x, ∂η/∂y alone at world points [1].

        See `sample`; the values are those it returns.
        """
        return self._sample(self._wrapped_fields(frame)[1:], x, y)

    def _sample(self, grids, x, y):
        x, y = np.broadcast_arrays(x, y)
        shape = x.shape
        x = x.ravel()
        y = y.ravel()
        out = np.empty((len(grids), x.size), np.float32)
        for start in range(0, x.size, _SAMPLE_BLOCK):
            block = slice(start, start + _SAMPLE_BLOCK)
            self._interpolate(grids, x[block], y[block], out[:, block])
        return tuple(values.reshape(shape) for values in out)

    def _interpolate(self, grids, x, y, out):
        """Bilinear interpolation of the wrapped, flattened ``grids`` at (x, y) into ``out``."""
        n = self.grid_size
        inverse = np.float32(1.0 / self.spacing)
        tx = np.multiply(x, inverse, dtype=np.float32)
        ty = np.multiply(y, inverse, dtype=np.float32)
        column = np.floor(tx)
        row = np.floor(ty)
        tx -= column
        ty -= row
        column = column.astype(np.intp)
        row = row.astype(np.intp)
        for index in (column, row):
            if n & (n - 1) == 0:
                np.bitwise_and(index, n - 1, out=index)
            else:
                np.remainder(index, n, out=index)
        row *= n + 1
        row += column
        corners = (row, row + 1, row + (n + 1), row + (n + 2))
        for values, result in zip(grids, out, strict=True):
            low, low_right, high, high_right = (values.take(corner) for corner in corners)
            low_right -= low
            low_right *= tx
            low_right += low
            high_right -= high
            high_right *= tx
            high_right += high
            high_right -= low_right
            high_right *= ty
            np.add(high_right, low_right, out=result)


def synthesize(
    spectrum: Spectrum,
    *,
    grid_size: int,
    spacing: float,
    rng: np.random.Generator,
    times: Sequence[float] = (0.0,),
    max_elevation: float | None = None,
    conditioning: Kriging | None = None,
) -> Surface:
    r"""One random realisation of the sea surface, at one or more times.

    Each wave mode travels towards its wavevector with the gravity–capillary
    frequency ω(k) of :func:`workers.spectra.dispersion` (after Tessendorf 2001, with
    the sign of time chosen so that energy at **k** travels towards **k**):

    .. math::

        \tilde h(\mathbf k, t) = h_0(\mathbf k)\,e^{-i\omega t}
        + \overline{h_0(-\mathbf k)}\,e^{i\omega t},\qquad
        h_0(\mathbf k) = \tfrac12\,a(\mathbf k)\,(\xi_1 + i\xi_2),

    .. math::

        \eta(\mathbf x, t) = \sum_{\mathbf k} \tilde h(\mathbf k, t)
        e^{i\mathbf k\cdot\mathbf x},\qquad
        \partial_x\eta = \sum_{\mathbf k} i k_x \tilde h\,
        e^{i\mathbf k\cdot\mathbf x},\qquad
        \partial_y\eta = \sum_{\mathbf k} i k_y \tilde h\,
        e^{i\mathbf k\cdot\mathbf x},

    with ξ independent standard normals and a from :func:`surface_amplitudes`. Since
    :math:`\tilde h(-\mathbf k) = \overline{\tilde h(\mathbf k)}` the field is real, and
    :math:`\operatorname{E}\,\overline{\eta^2} = \sum_{\mathbf k} \Psi\,\Delta k^2`
    at every t (the resolved band of the spectrum).

    Parameters
    ----------
    spectrum : workers.spectra.Spectrum
        Directional wave spectrum.
    grid_size : int
        Number N of grid points along x and along y.
    spacing : float
        Grid spacing Δ, m.
    rng : numpy.random.Generator
        Source of the 2N² normal draws, all made once: every time shows the same
        realisation.
    times : sequence of float, optional
        Times t of the frames, s.
    max_elevation : float or None, optional
        If given, m (> 0): the realisation (elevation and slopes, all frames) is
        rescaled so that max |η| over all frames equals it (the "maximum wave
        elevation" of Carmona et al. 2000). Off by default.
    conditioning : workers.conditioning.Kriging or None, optional
        Measured elevations the realisation must honour, from
        :func:`workers.conditioning.kriging` for this spectrum and grid. The
        unconditional draw is corrected by kriging its residual at the data, the
        measurement noise drawn from ``rng`` after the 2N² normals, so that without it
        the draws (and bytes) are unchanged. Exclusive with ``max_elevation``, which
        would rescale the data away.

    Returns
    -------
    Surface
        Elevation and slopes, float32 of shape (len(times), N, N).

    Notes
    -----
    Slopes are spectral derivatives; the derivative of the Nyquist mode along its own
    axis (even N) is set to zero. On the Nyquist row and column k and -k are the same
    grid point, so those modes (a fraction ~2/N of the grid) are standing rather than
    travelling waves; their variance is still Ψ Δk². Rescaling by ``max_elevation``
    changes the variance of the realisation away from Σ Ψ Δk²: the surface then no
    longer follows the spectrum's amplitude, only its shape. The per-(spectrum, grid)
    arrays are cached (16 entries); a frame costs three inverse real FFTs of N × N, and
    conditioning one inverse and one forward real FFT per distinct measurement time.

    References
    ----------
    .. [1] Tessendorf, J. (2001). Simulating ocean water. SIGGRAPH 2001 course notes
       "Simulating Nature: Realistic and Interactive Techniques", course 47.
    .. [2] Carmona, R., Cérou, F., & Blasco, B. (2000). Lidar imaging through the ocean
       surface, §3 and §5. Report, Dept. of Operations Research & Financial
       Engineering, Princeton University, June 30, 2000.
    """
    _check_grid(grid_size, spacing)
    n = int(grid_size)
    times = np.asarray(times, dtype=np.float64)
    if times.ndim != 1 or times.size == 0 or not np.all(np.isfinite(times)):
        raise ValueError(f"times must be a non-empty sequence of finite seconds, got {times}")
    if max_elevation is not None and not (math.isfinite(max_elevation) and max_elevation > 0):
        raise ValueError(f"max_elevation must be a positive number of metres, got {max_elevation}")
    if conditioning is not None:
        if max_elevation is not None:
            raise ValueError("conditioning and max_elevation exclude each other")
        if (conditioning.spectrum, conditioning.grid_size, conditioning.spacing) != (
            spectrum,
            n,
            float(spacing),
        ):
            raise ValueError("conditioning was built for another spectrum or grid")
    setup = _setup(spectrum, n, float(spacing))

    h0 = np.empty((n, n), np.complex64)
    rng.standard_normal(out=h0.view(np.float32), dtype=np.float32)
    h0 *= 0.5 * setup.amplitude
    forward = np.ascontiguousarray(h0[:, : n // 2 + 1])
    backward = np.conj(h0.ravel().take(setup.mirror)).reshape(forward.shape)

    rotation = np.empty(forward.shape, np.complex64)
    spectrum_t = np.empty(forward.shape, np.complex64)
    product = np.empty(forward.shape, np.complex64)

    def at_time(time):
        """h̃(k, t) on the half-plane, into `spectrum_t` (uses `rotation`, `product`)."""
        cycles = setup.omega * (time / (2.0 * np.pi))
        cycles -= np.floor(cycles)
        phase = (2.0 * np.pi * cycles).astype(np.float32)
        np.cos(phase, out=rotation.real)
        np.sin(phase, out=rotation.imag)
        np.multiply(backward, rotation, out=spectrum_t)
        np.conjugate(rotation, out=rotation)
        np.multiply(forward, rotation, out=product)
        return np.add(spectrum_t, product, out=spectrum_t)

    if conditioning is not None:
        ahead, behind = conditioning.correction(
            lambda time: scipy.fft.irfft2(at_time(time), s=(n, n), norm="forward"), rng
        )
        forward += ahead
        backward += behind

    fields = np.empty((3, times.size, n, n), np.float32)
    for frame, time in enumerate(times):
        at_time(time)
        # One transform per field: scipy's batched irfft2 is several times slower.
        for component, derivative in enumerate(setup.derivative):
            np.multiply(derivative, spectrum_t, out=product)
            fields[component, frame] = scipy.fft.irfft2(product, s=(n, n), norm="forward")
    if max_elevation is not None:
        peak = float(np.abs(fields[0]).max())
        if peak == 0:
            raise ValueError("max_elevation cannot rescale a flat surface (zero spectrum)")
        fields *= np.float32(max_elevation / peak)
    return Surface(
        elevation=fields[0],
        slope_x=fields[1],
        slope_y=fields[2],
        spacing=float(spacing),
        grid_size=n,
    )
