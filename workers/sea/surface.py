r"""FFT synthesis of a Gaussian, homogeneous multi-scale sea surface and its slopes.

A sea (:class:`workers.sea.cascades.Sea`) is a sum of cascades, each a sum of Fourier modes on
an N × N periodic grid of spacing Δ_c, with grid coordinates :math:`x_j = j\Delta_c`
(j = 0 … N-1) and wavenumbers on the FFT grid, :math:`\Delta k = 2\pi / (N\Delta_c)`;
each cascade holds its own band of the spectrum. Synthesis is in two steps, so that
conditioning (:mod:`workers.sea.conditioning`) composes on top of it: :func:`draw` draws the
complex amplitudes (:class:`Modes`), :meth:`Modes.surface` evolves them to the frames'
times (:class:`Surface`). Arrays are indexed (t, y, x): axis -1 is x.

The modes are drawn (and conditioned) on the host with numpy, so every backend shows the
same sea; :meth:`Modes.surface` moves them to a `workers.backends.backend.Backend` and runs the
evolution and the FFTs there (scipy's on numpy, torch's on PyTorch), and a
:class:`Surface` answers at points with the backend's kernels
(`workers.backends.kernels` / `workers.backends.kernels_torch`). Across backends the fields agree
to
float32 rounding, not bit for bit.
"""

from __future__ import annotations

import functools
import importlib
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import scipy.fft
from array_api_compat import is_torch_array

from workers.backends.backend import Backend, get_backend
from workers.sea.cascades import Sea, subgrid_slope_covariance
from workers.sea.spectra import dispersion

__all__ = [
    "NUMPY",
    "Cascade",
    "Modes",
    "SubgridSlopes",
    "Surface",
    "centred_axis",
    "draw",
    "synthesize",
]

NUMPY = get_backend()
"""The numpy backend (numba kernels, scipy's FFTs): the default, today's bytes."""


def _check_grid(grid_size, spacing) -> None:
    if isinstance(grid_size, bool) or int(grid_size) != grid_size or grid_size < 2:
        raise ValueError(f"grid_size must be an integer >= 2, got {grid_size!r}")
    if not (math.isfinite(spacing) and spacing > 0):
        raise ValueError(f"spacing must be a positive number of metres, got {spacing!r}")


def _field(backend: Backend, values):
    """`values` as a C-ordered float32 array of `backend` (read-only on numpy)."""
    if backend.name == "numpy":
        array = np.ascontiguousarray(values, dtype=np.float32)
        array.flags.writeable = False
        return array
    if not is_torch_array(values):
        values = backend.asarray(values, np.float32)
    return values.to(device=backend.device, dtype=backend.xp.float32).contiguous()


def _points(backend: Backend, x, y):
    """Points (x, y) broadcast together, as 1-D arrays of `backend`, and their shape.

    On numpy they are passed on as given (the kernel rounds them to float32); on torch
    host values are moved to the device and rounded to float32 first, the same values.
    """
    if backend.name == "numpy":
        x, y = np.broadcast_arrays(x, y)
        return x.ravel(), y.ravel(), x.shape
    xp = backend.xp
    x, y = (v if is_torch_array(v) else backend.asarray(v) for v in (x, y))
    x, y = xp.broadcast_arrays(xp.astype(x, xp.float32), xp.astype(y, xp.float32))
    return xp.reshape(x, (-1,)), xp.reshape(y, (-1,)), tuple(x.shape)


@dataclass(frozen=True, eq=False)
class Cascade:
    """One cascade of a synthesised sea: elevation and slopes on a periodic grid, per frame.

    Parameters
    ----------
    elevation : array
        Elevation η above mean sea level, m, float32 of shape (T, N, N), index order
        (frame, y, x); element [t, i, j] is at x = jΔ, y = iΔ.
    slope_x, slope_y : array
        ∂η/∂x and ∂η/∂y (dimensionless), float32 of shape (T, N, N).
    spacing : float
        Grid spacing Δ, m.
    grid_size : int
        Number N of grid points along x and along y.
    backend : workers.backends.backend.Backend, optional
        Where the arrays live and what samples them (default numpy).

    Notes
    -----
    The three arrays are stored float32 and C-ordered on the backend (read-only on
    numpy). The surface is periodic with period NΔ in x and in y.
    """

    elevation: np.ndarray
    slope_x: np.ndarray
    slope_y: np.ndarray
    spacing: float
    grid_size: int
    backend: Backend = field(default=NUMPY, repr=False)

    def __post_init__(self):
        _check_grid(self.grid_size, self.spacing)
        n = int(self.grid_size)
        frames = None
        for name in ("elevation", "slope_x", "slope_y"):
            array = _field(self.backend, getattr(self, name))
            shape = tuple(array.shape)
            if len(shape) != 3 or shape[1:] != (n, n) or shape[0] < 1:
                raise ValueError(f"{name} must have shape (frames, {n}, {n}), got {shape}")
            if frames is not None and shape[0] != frames:
                raise ValueError(f"{name} has {shape[0]} frames, elevation has {frames}")
            frames = shape[0]
            object.__setattr__(self, name, array)
        object.__setattr__(self, "_wrapped", {})

    def _wrapped_fields(self, frame):
        """Elevation and slopes of `frame`, each padded to (N + 1, N + 1): (3, (N + 1)²).

        Row N and column N repeat row 0 and column 0, so the four corners of a cell need
        no wrapping. Made on first use and kept (4(N + 1)² bytes per field and frame).
        """
        frame = int(frame)
        if frame not in self._wrapped:
            xp = self.backend.xp
            fields = xp.stack([self.elevation[frame], self.slope_x[frame], self.slope_y[frame]])
            fields = xp.concat([fields, fields[:, :1, :]], axis=1)
            fields = xp.concat([fields, fields[:, :, :1]], axis=2)
            self._wrapped[frame] = xp.reshape(fields, (3, -1))
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
        x, y : array
            World coordinates, m (broadcast together), arrays of the backend (on
            torch, host arrays are moved to its device).
        frame : int, optional
            Frame index into the first axis of the fields.

        Returns
        -------
        elevation, slope_x, slope_y : array
            η (m), ∂η/∂x and ∂η/∂y, float32 arrays of the backend, of the broadcast
            shape of ``x`` and ``y``.

        Notes
        -----
        Coordinates are converted to float32 first, so a point is located to about
        6×10⁻⁸ |x| (0.06 mm at 1 km). The slopes are interpolated spectral slopes, not
        the derivative of the interpolated elevation. A power-of-two N wraps indices
        with a bit mask, any other N with a (slower) remainder; a copy of each frame
        with its first row and column repeated after the last (made on first use and
        kept) gives the other three corners without wrapping. The loop is the
        backend's kernel (`workers.backends.kernels.bilinear_sum` or its torch twin).
        """
        return _sample((self,), (self._wrapped_fields(frame),), x, y)

    def elevation_at(self, x, y, frame=0):
        """Bilinear, periodically wrapped elevation alone at world points, m (see `sample`)."""
        return _sample((self,), (self._wrapped_fields(frame)[:1],), x, y)[0]

    def slopes_at(self, x, y, frame=0):
        """Bilinear, periodically wrapped slopes ∂η/∂x, ∂η/∂y alone at world points [1].

        See `sample`; the values are those it returns.
        """
        return _sample((self,), (self._wrapped_fields(frame)[1:],), x, y)


def _sample(cascades, grids, x, y):
    """The sum over `cascades` of their bilinear `grids` (`Cascade._wrapped_fields` rows)."""
    backend = cascades[0].backend
    xp = backend.xp
    x, y, shape = _points(backend, x, y)
    count = grids[0].shape[0]
    out = xp.empty((count, x.shape[0]), dtype=xp.float32, device=backend.device)
    sizes = tuple(int(c.grid_size) for c in cascades)
    inverses = tuple(np.float32(1.0 / c.spacing) for c in cascades)
    backend.kernels.bilinear_sum(grids, sizes, inverses, x, y, out)
    return tuple(xp.reshape(out[k], shape) for k in range(count))


@dataclass(frozen=True, eq=False)
class SubgridSlopes:
    r"""The slopes finer than the finest grid: a Gaussian blur of the facets' normals.

    Every cell of the finest grid (Δ₀ × Δ₀, frame by frame) gets its own slope
    :math:`\mathbf s = F\mathbf z`, F Fᵀ = Σ
    (:func:`workers.sea.cascades.subgrid_slope_covariance`)
    and z two standard normals; a point's slopes are the resolved ones plus the s of its
    cell, so refraction scatters the rays with the unresolved slope variance. z is a
    hash of (cell, frame, key) (SplitMix64, then Box–Muller), so it is the same whatever
    the order, number or grouping of the points asked for, never periodic, and fixed by
    the seed through `key`. Cells are independent: the unresolved waves are shorter
    than 2Δ₀, and a cell is Δ₀ wide. Frames are independent: waves that short (periods
    below 0.1 s at Δ₀ = 1.6 cm) decorrelate between frames.

    Parameters
    ----------
    factor : numpy.ndarray
        F, a square root of Σ (F Fᵀ = Σ, dimensionless), (2, 2).
    cell : float
        Δ₀, m.
    key : int
        64-bit key drawn from the surface's random stream.
    backend : workers.backends.backend.Backend, optional
        Where the points live and what hashes them (default numpy).
    """

    factor: np.ndarray
    cell: float
    key: int
    backend: Backend = field(default=NUMPY, repr=False)

    def at(self, x, y, frame):
        """The sub-grid slopes (∂η/∂x, ∂η/∂y) at points: float32 arrays of the backend.

        Of the broadcast shape of `x` and `y` (m); `frame` is the frame's index.
        """
        backend, xp = self.backend, self.backend.xp
        inverse = np.float32(1.0 / self.cell)
        x, y, shape = _points(backend, x, y)
        first = xp.empty(x.shape, dtype=xp.float32, device=backend.device)
        second = xp.empty(x.shape, dtype=xp.float32, device=backend.device)
        key, frame = int(self.key), int(frame) & 0xFFFFFFFFFFFFFFFF
        if backend.name == "numpy":  # numba's hash needs unsigned 64-bit words
            key, frame = np.uint64(key), np.uint64(frame)
        backend.kernels.cell_uniforms(x, y, inverse, key, frame, first, second)
        radius = xp.sqrt(-2.0 * xp.log(first))
        angle = (2.0 * np.pi) * second
        normal_x, normal_y = radius * xp.cos(angle), radius * xp.sin(angle)
        (f00, f01), (f10, f11) = np.asarray(self.factor, np.float32).tolist()
        slope_x = f00 * normal_x + f01 * normal_y
        slope_y = f10 * normal_x + f11 * normal_y
        return xp.reshape(slope_x, shape), xp.reshape(slope_y, shape)


def centred_axis(*, grid_size: int, spacing: float) -> np.ndarray:
    r"""The N + 1 nodes :math:`x_j = (j - N/2)\Delta`, j = 0 … N, centred on the origin.

    Parameters
    ----------
    grid_size : int
        N.
    spacing : float
        Δ, m.

    Returns
    -------
    numpy.ndarray
        The positions, m, float64.

    Notes
    -----
    The boresight meets mean sea level at the origin in the first frame
    (`workers.setup.geometry`), so with the finest cascade's Δ₀ and the default spacing (the
    footprint's span over N) the grid spans the footprint: [−NΔ₀/2, NΔ₀/2] at nadir.
    """
    _check_grid(grid_size, spacing)
    return (np.arange(grid_size + 1) - grid_size / 2) * spacing


@dataclass(frozen=True, eq=False)
class Surface:
    """A synthesised multi-scale sea: its cascades summed, plus the sub-grid slopes.

    Parameters
    ----------
    cascades : tuple of Cascade
        The cascades, finest first, with the same frames.
    subgrid : SubgridSlopes or None, optional
        The slopes finer than the finest grid (None: left out).

    Notes
    -----
    A point's elevation is the sum of the cascades' bilinear values; its slopes the
    sum of theirs plus the sub-grid slopes of its cell. The sum is periodic only with
    a common multiple of the patches. The fields live on the cascades' backend
    (`backend`): points are asked and answered there, while the gridded elevations
    (`elevation`, `centred_elevation`: what a store keeps) come back as numpy.
    """

    cascades: tuple[Cascade, ...]
    subgrid: SubgridSlopes | None = None

    def __post_init__(self):
        frames = {cascade.elevation.shape[0] for cascade in self.cascades}
        if len(frames) != 1:
            raise ValueError(f"the cascades must share their frames, got {sorted(frames)}")

    @property
    def backend(self) -> Backend:
        """The backend the fields live on (the cascades')."""
        return self.cascades[0].backend

    @property
    def spacing(self) -> float:
        """Spacing Δ₀ of the finest grid, m."""
        return self.cascades[0].spacing

    @property
    def grid_size(self) -> int:
        """Number N of points per side of the finest grid."""
        return self.cascades[0].grid_size

    @functools.cached_property
    def elevation(self) -> np.ndarray:
        """The summed elevation on the finest grid's nodes [0, NΔ₀)², m, (T, N, N) float32.

        On the host (numpy, read-only) whatever the backend.
        """
        finest, backend = self.cascades[0], self.backend
        nodes = np.arange(finest.grid_size) * finest.spacing
        x, y = backend.asarray(nodes[None, :]), backend.asarray(nodes[:, None])
        out = backend.xp.asarray(finest.elevation, copy=True)
        for frame in range(out.shape[0]):
            for cascade in self.cascades[1:]:
                out[frame] += cascade.elevation_at(x, y, frame)
        out = backend.to_numpy(out)
        out.flags.writeable = False
        return out

    @property
    def axis(self) -> np.ndarray:
        """Positions of `centred_elevation`'s nodes along x and along y, m (`centred_axis`)."""
        return centred_axis(grid_size=self.grid_size, spacing=self.spacing)

    @functools.cached_property
    def centred_elevation(self) -> np.ndarray:
        """The summed elevation (`elevation_at`) on the grid centred on the origin, m.

        Nodes at (`axis`, `axis`), over the footprint (`centred_axis`): float32 of
        shape (T, N + 1, N + 1), index order (frame, y, x), on the host (numpy,
        read-only) whatever the backend.
        """
        backend = self.backend
        x, y = backend.asarray(self.axis[None, :]), backend.asarray(self.axis[:, None])
        frames = self.cascades[0].elevation.shape[0]
        out = backend.xp.stack([self.elevation_at(x, y, frame) for frame in range(frames)])
        out = backend.to_numpy(out)
        out.flags.writeable = False
        return out

    def sample(self, x, y, frame=0):
        """Elevation and slopes at world points (see `Cascade.sample`), float32.

        Returns
        -------
        elevation, slope_x, slope_y : array
            η (m), ∂η/∂x and ∂η/∂y (sub-grid slopes included), arrays of the backend.
        """
        eta = self.elevation_at(x, y, frame)
        return (eta, *self.slopes_at(x, y, frame))

    def elevation_at(self, x, y, frame=0):
        """Elevation at world points, m: the sum of the cascades' bilinear values."""
        grids = tuple(c._wrapped_fields(frame)[:1] for c in self.cascades)
        return _sample(self.cascades, grids, x, y)[0]

    def hits(self, rays, frame, *, iterations, tolerance):
        """Where rays meet the surface: fixed-point iteration on the elevation from z = 0.

        Parameters
        ----------
        rays : tuple
            ``(ox, oy, oz, dx, dy, dz)`` [m], [1] of one float dtype: 1-D arrays of the
            backend, an origin every ray shares as numbers.
        frame : int
            Frame index.
        iterations : int
            Most steps.
        tolerance : float
            Largest height change [m] over all rays below which the iteration stops.

        Returns
        -------
        travel, eta : array
            Each ray's parameter at its hit (the rays' dtype) and the elevation there
            [m] (float32): ``eta`` is `elevation_at` ``o + travel·d``.

        Notes
        -----
        One call of the backend's kernel (`workers.backends.kernels.surface_hits`) for
        the whole search; on torch a fixed count of steps and nothing read on the host.
        The values of the steps written with `elevation_at`
        (`workers.setup.interface.surface_hit`).
        """
        backend, xp = self.backend, self.backend.xp
        dz = rays[5]
        if backend.name == "numpy":  # numba: arrays of one dtype, a float32 tolerance
            dtype = np.result_type(*rays)
            rays = tuple(np.broadcast_to(np.asarray(v, dtype), dz.shape) for v in rays)
            tolerance = np.float32(tolerance)
        travel = xp.empty(dz.shape, dtype=rays[5].dtype, device=backend.device)
        eta = xp.empty(dz.shape, dtype=xp.float32, device=backend.device)
        grids = tuple(c._wrapped_fields(frame)[:1] for c in self.cascades)
        sizes = tuple(int(c.grid_size) for c in self.cascades)
        inverses = tuple(np.float32(1.0 / c.spacing) for c in self.cascades)
        backend.kernels.surface_hits(
            grids, sizes, inverses, rays, tolerance, iterations, travel, eta
        )
        return travel, eta

    def slopes_at(self, x, y, frame=0):
        """Slopes ∂η/∂x, ∂η/∂y at world points [1]: the cascades' plus the sub-grid ones."""
        grids = tuple(c._wrapped_fields(frame)[1:] for c in self.cascades)
        slope_x, slope_y = _sample(self.cascades, grids, x, y)
        if self.subgrid is not None:
            more_x, more_y = self.subgrid.at(x, y, frame)
            slope_x += more_x
            slope_y += more_y
        return slope_x, slope_y


@dataclass(frozen=True)
class _Setup:
    """Per-(sea, cascade) arrays for the synthesis, half-plane (rfft) layout."""

    amplitude: np.ndarray  # (N, N) float32, a(k) of the cascade in FFT order
    mirror: np.ndarray  # (N·(N//2+1),) flat index into (N, N) of -k for each half-plane k
    omega: np.ndarray  # (N, N//2+1) float64, ω(|k|) from `dispersion`, rad/s
    derivative: np.ndarray  # (2, N, N//2+1) complex64: i k_x, i k_y


@functools.lru_cache(maxsize=32)
def _evolution(sea: Sea, cascade: int, backend: Backend):
    """ω (float64) and i k (complex64) of `_setup` on `backend`'s device (cached)."""
    setup = _setup(sea, cascade)
    return backend.asarray(setup.omega), backend.asarray(setup.derivative)


def _evolve(backend: Backend, omega, ahead, behind, time: float):
    r"""The modes at `time` (s), arrays of `backend` (`Modes.spectrum_at`'s formula).

    The phase ωt is reduced to a cycle in float64, then rounded to float32; the
    rotation and the products are complex64 on every backend.
    """
    xp = backend.xp
    cycles = omega * (time / (2.0 * np.pi))
    cycles = cycles - xp.floor(cycles)
    phase = xp.astype(2.0 * np.pi * cycles, xp.float32)
    if backend.name == "numpy":
        rotation = np.empty(phase.shape, np.complex64)
        np.cos(phase, out=rotation.real)
        np.sin(phase, out=rotation.imag)
    else:
        rotation = importlib.import_module("torch").complex(xp.cos(phase), xp.sin(phase))
    return behind * rotation + xp.conj(rotation) * ahead


@functools.lru_cache(maxsize=32)
def _setup(sea: Sea, cascade: int) -> _Setup:
    n = sea.grid_size
    half = n // 2 + 1
    k = sea.wavenumbers(cascade)
    kx, ky = k[None, :half], k[:, None]
    derivative = np.empty((2, n, half), np.complex64)
    derivative[0] = 1j * kx
    derivative[1] = 1j * ky
    rows = (-np.arange(n)) % n
    columns = (-np.arange(half)) % n
    mirror = (rows[:, None] * n + columns[None, :]).ravel()
    amplitude = sea.amplitudes(cascade).astype(np.float32)
    for array in (amplitude, mirror, derivative):
        array.flags.writeable = False
    return _Setup(amplitude, mirror, dispersion(np.hypot(kx, ky)), derivative)


@dataclass(frozen=True, eq=False)
class Modes:
    r"""The complex amplitudes of one drawn sea, per cascade, on the half-plane.

    Attributes
    ----------
    sea : workers.sea.cascades.Sea
        The layout.
    ahead, behind : tuple of numpy.ndarray
        Per cascade, :math:`h_0(\mathbf k)` and :math:`\overline{h_0(-\mathbf k)}`, m,
        complex (N, N//2 + 1).
    subgrid_key : int
        Key of the sub-grid slopes (:class:`SubgridSlopes`).
    """

    sea: Sea
    ahead: tuple[np.ndarray, ...]
    behind: tuple[np.ndarray, ...]
    subgrid_key: int

    def spectrum_at(self, cascade: int, time: float) -> np.ndarray:
        r"""A cascade's modes at time t (s) on the half-plane, complex64, m.

        :math:`\tilde h(\mathbf k, t) = h_0 e^{-i\omega t}
        + \overline{h_0(-\mathbf k)} e^{i\omega t}`.
        """
        omega = _setup(self.sea, cascade).omega
        return _evolve(NUMPY, omega, self.ahead[cascade], self.behind[cascade], float(time))

    def elevation_grid(self, cascade: int, time: float) -> np.ndarray:
        """A cascade's elevation on its grid at time t (s), m, (N, N) float32."""
        n = self.sea.grid_size
        return scipy.fft.irfft2(self.spectrum_at(cascade, time), s=(n, n), norm="forward")

    def surface(
        self, times: Sequence[float] = (0.0,), *, max_elevation=None, backend: Backend = NUMPY
    ) -> Surface:
        r"""The sea at the frames' times: every cascade evolved, its slopes derived.

        .. math::

            \eta_c(\mathbf x, t) = \sum_{\mathbf k} \tilde h_c(\mathbf k, t)
            e^{i\mathbf k\cdot\mathbf x},\qquad
            \partial_x\eta_c = \sum_{\mathbf k} i k_x \tilde h_c\,
            e^{i\mathbf k\cdot\mathbf x},\qquad
            \partial_y\eta_c = \sum_{\mathbf k} i k_y \tilde h_c\,
            e^{i\mathbf k\cdot\mathbf x}.

        Parameters
        ----------
        times : sequence of float, optional
            Times t of the frames, s.
        max_elevation : float or None, optional
            If given, m (> 0): the realisation (cascades and sub-grid slopes, all
            frames) is rescaled so that max |η| over `Surface.centred_elevation` (the
            grid centred on the origin, over the footprint) and all frames equals it (the
            "maximum wave elevation" of Carmona et al. 2000). It then no longer
            follows the spectrum's amplitude, only its shape.
        backend : workers.backends.backend.Backend, optional
            Where the modes are evolved and transformed (`Backend.fft`) and the fields
            kept (default numpy: scipy's FFTs, one field at a time).

        Returns
        -------
        Surface
            Cascades of float32 fields of shape (len(times), N, N) on `backend`.
        """
        times = np.asarray(times, dtype=np.float64)
        if times.ndim != 1 or times.size == 0 or not np.all(np.isfinite(times)):
            raise ValueError(f"times must be a non-empty sequence of finite seconds, got {times}")
        if max_elevation is not None and not (math.isfinite(max_elevation) and max_elevation > 0):
            raise ValueError(
                f"max_elevation must be a positive number of metres, got {max_elevation}"
            )
        sea, n, xp = self.sea, self.sea.grid_size, backend.xp
        shape = (len(sea.patches), 3, times.size, n, n)
        fields = xp.empty(shape, dtype=xp.float32, device=backend.device)
        for cascade in range(len(sea.patches)):
            omega, derivative = _evolution(sea, cascade, backend)
            ahead, behind = (backend.asarray(m[cascade]) for m in (self.ahead, self.behind))
            for frame, time in enumerate(times.tolist()):
                spectrum = _evolve(backend, omega, ahead, behind, time)
                # One transform per field: scipy's batched irfft2 is several times slower.
                for component in range(3):
                    product = spectrum if component == 0 else derivative[component - 1] * spectrum
                    fields[cascade, component, frame] = backend.fft.irfftn(
                        product, s=(n, n), axes=(-2, -1), norm="forward"
                    )
        values, vectors = np.linalg.eigh(subgrid_slope_covariance(sea))
        factor = vectors * np.sqrt(np.maximum(values, 0.0))  # F Fᵀ = Σ
        surface = self._assemble(fields, factor, backend)
        if max_elevation is not None:
            peak = float(np.abs(surface.centred_elevation).max())
            if peak == 0:
                raise ValueError("max_elevation cannot rescale a flat surface (zero spectrum)")
            scale = max_elevation / peak
            fields *= float(np.float32(scale))
            surface = self._assemble(fields, factor * scale, backend)
        return surface

    def _assemble(self, fields, factor, backend: Backend) -> Surface:
        cascades = tuple(
            Cascade(
                elevation=fields[cascade, 0],
                slope_x=fields[cascade, 1],
                slope_y=fields[cascade, 2],
                spacing=self.sea.spacing(cascade),
                grid_size=self.sea.grid_size,
                backend=backend,
            )
            for cascade in range(fields.shape[0])
        )
        subgrid = SubgridSlopes(
            factor=factor, cell=self.sea.spacing(0), key=self.subgrid_key, backend=backend
        )
        return Surface(cascades=cascades, subgrid=subgrid)


def draw(sea: Sea, rng) -> Modes:
    r"""Draw the complex amplitudes of one realisation of the sea.

    Per cascade (after Tessendorf 2001, with the sign of time chosen so that energy at
    **k** travels towards **k**):

    .. math::

        h_0(\mathbf k) = \tfrac12\,a(\mathbf k)\,(\xi_1 + i\xi_2),

    ξ independent standard normals and a from :meth:`workers.sea.cascades.Sea.amplitudes`.
    Since :math:`\tilde h(-\mathbf k) = \overline{\tilde h(\mathbf k)}` the field is
    real, and :math:`\operatorname{E}\eta^2 = \sum_c \sum_{\mathbf k} a_c^2` at every
    node of every cascade and every t, the spectrum's band integral over |k| < π/Δ₀.

    Parameters
    ----------
    sea : workers.sea.cascades.Sea
        The layout.
    rng : numpy.random.Generator or sequence of them
        One generator per cascade (finest first), or one for all, drawn in that order:
        2M² normals per cascade (the M × M modes of its band's square,
        `workers.sea.cascades.Sea.drawn_modes`: M = N for the finest), then (from the first)
        one 64-bit sub-grid key.

    Returns
    -------
    Modes
    """
    count = len(sea.patches)
    rngs = (rng,) * count if isinstance(rng, np.random.Generator) else tuple(rng)
    if len(rngs) != count:
        raise ValueError(f"need one generator per cascade ({count}), got {len(rngs)}")
    n = sea.grid_size
    ahead, behind = [], []
    for cascade, generator in enumerate(rngs):
        setup = _setup(sea, cascade)
        index = sea.drawn_modes(cascade)
        drawn = np.empty((index.size, index.size), np.complex64)
        generator.standard_normal(out=drawn.view(np.float32), dtype=np.float32)
        if index.size == n:
            h0 = drawn
        else:  # the modes beyond the band's square are zero
            h0 = np.zeros((n, n), np.complex64)
            h0[np.ix_(index, index)] = drawn
        h0 *= 0.5 * setup.amplitude
        ahead.append(np.ascontiguousarray(h0[:, : n // 2 + 1]))
        behind.append(np.conj(h0.ravel().take(setup.mirror)).reshape(ahead[-1].shape))
    key = int(rngs[0].integers(0, 2**63, dtype=np.int64))
    return Modes(sea=sea, ahead=tuple(ahead), behind=tuple(behind), subgrid_key=key)


def synthesize(
    sea: Sea, *, rng, times: Sequence[float] = (0.0,), max_elevation: float | None = None
) -> Surface:
    """One random realisation of the sea at one or more times.

    :func:`draw` then :meth:`Modes.surface`, with their parameters.

    Notes
    -----
    Every frame shows the same realisation. A frame costs three inverse real FFTs of
    N × N per cascade; the per-(sea, cascade) arrays are cached (32 entries).

    References
    ----------
    .. [1] Tessendorf, J. (2001). Simulating ocean water. SIGGRAPH 2001 course notes
       "Simulating Nature: Realistic and Interactive Techniques", course 47.
    .. [2] Carmona, R., Cérou, F., & Blasco, B. (2000). Lidar imaging through the ocean
       surface, §3 and §5. Report, Dept. of Operations Research & Financial
       Engineering, Princeton University, June 30, 2000.
    """
    return draw(sea, rng).surface(times, max_elevation=max_elevation)
