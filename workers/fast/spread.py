"""Linear (non-periodic) spreading of light on in-water planes by Wells' point-spread function.

Light reaching a plane at depth z is spread by the small-angle point-spread function (PSF)
whose Fourier transform is the Wells MTF (`workers.optics.water.WaterOptics.mtf`). With the
paper's phase function that PSF is far wider than the image: in coastal water 99 % of the
scattered light of a point lies within about 22 m of it at 10 m depth, in turbid harbour
water within 40 m, against a footprint of a few metres. A periodic FFT convolution on a
plane a little wider than the image sends the light that leaves the plane back in on the
other side (wrap-around): the gate background came out up to 57 times too bright.

Here each plane has two levels, so the convolution is linear where it matters at a cost
close to that of the fine plane alone:

- the **fine** grid (`workers.setup.geometry.PlaneGrid`) covers the image and a guard band,
  at the laser's ray spacing;
- the **coarse** grid, `factor` times coarser, shares its axes and covers the fine grid and
  a margin holding `SPREAD_FRACTION` of the scattered light (`encircled_radius`); every
  coarse cell inside the fine grid is a block of factor × factor fine cells.

The MTF is split with a Gaussian low-pass W(f) = exp(−(f/f_c)²), f_c = 1/(4Δ) for the
coarse spacing Δ: the **far** part MTF_s·W (MTF_s the scattered part, without the
unscattered e^(−cz)) is smooth in space and is applied on the coarse grid, whose margin
makes it linear; the **near** part MTF − MTF_s·W (the unscattered light and the scattered
core minus its smoothed copy) integrates to the unscattered share and decays within a few
Δ, so the fine grid's guard holds it. A field is carried as a fine array plus a coarse
array for the light outside the fine grid (`Spread.__call__`).

The filters are built once per scene in numpy (`Spread.build`); a sample's fields may be
numpy arrays or PyTorch tensors (`workers.backends.backend`): `Spread.on` and `Levels.on` give the
same spread with its arrays on a backend, made once and kept. On numpy the FFTs are
`scipy.fft`'s (the renderer's bytes), on torch the namespace's.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass

import numpy as np
import scipy.fft
from scipy import integrate, special

from workers.backends.backend import Backend, get_backend
from workers.optics.water import WaterOptics
from workers.setup.geometry import PlaneGrid, fast_length, gaussian_transfer

__all__ = [
    "NEAR_SUPPORT",
    "SPREAD_FRACTION",
    "Levels",
    "Spread",
    "coarse_factor",
    "encircled_radius",
    "scattered_mtf",
]

SPREAD_FRACTION = 0.99
"""Share of a point's scattered light that the coarse grid's margin holds [1]."""

NEAR_SUPPORT = 4
"""Guard band of the fine grid, in coarse cells: the near kernel decays within it."""

MIN_FACTOR = 4
"""Fewest fine cells per coarse cell along each axis (1 makes the coarse level a linear,
zero-padded convolution at full resolution: the brute-force reference of the tests)."""

MAX_COARSE = 256
"""Most coarse cells per side before the coarse cells grow (bounds the coarse FFT)."""

_FACTORS = (4, 5, 6, 8, 9, 10, 12, 15, 16, 18, 20, 24, 25, 27, 30, 32, 36, 40, 45, 48, 50, 54)
"""Coarsening factors: 5-smooth, so fine grid lengths stay fast FFT lengths."""

_HANKEL_X = np.linspace(0.0, 200.0, 4001)
"""Quadrature nodes of the encircled-energy integral in x = 2πfR [1]."""


_LARGE_EXPONENT = 600.0
"""Exponent above which e^x is not taken alone (float64 overflows at 709)."""

_NUMPY = get_backend("numpy")


def _backend_of(values) -> Backend:
    """The backend whose arrays `values` is: numpy, or torch on the tensor's device."""
    if isinstance(values, np.ndarray):
        return _NUMPY
    return get_backend("torch", str(values.device))


def _held_by(backend: Backend, values) -> bool:
    """Whether `values` is an array of `backend`'s kind (numpy array or torch tensor)."""
    return isinstance(values, np.ndarray) == (backend.name == "numpy")


def _copy_on(owner, backend: Backend, make):
    """`owner`'s copy on `backend`: `make()` the first time, then the one kept."""
    if backend == owner.backend:
        return owner
    copy = owner._copies.get(backend)
    return copy if copy is not None else owner._copies.setdefault(backend, make())


def scattered_mtf(water: WaterOptics, frequency, *, distance, passes=1):
    r"""Scattered part of the Wells MTF: the MTF less its unscattered share e^(−cz).

    Parameters
    ----------
    water : WaterOptics
        The water column.
    frequency : float or array_like
        Spatial frequency magnitude f on the plane [cycles/m].
    distance : float
        Water path z from the source plane [m].
    passes : int, optional
        1 for one way; 2 for the round trip down and up the same path (MTF²).

    Returns
    -------
    float or ndarray
        :math:`e^{-pcz}\left(e^{p\,b_f z D(fz)} - 1\right)` [1] for p passes, float64; at
        f = 0 and p = 1 it is :math:`e^{-Kz} - e^{-cz}`, the scattered share of the light.
    """
    psi = np.abs(np.asarray(frequency, dtype=np.float64)) * distance
    exponent = passes * water.forward_scattering * distance * water.mtf_exponent(psi)
    unscattered = -passes * water.attenuation * distance
    # e^(−pcz) (e^(pbz D) − 1), without cancellation where pbz D is small, nor overflow
    # where it is large (e^(−pcz) underflows to 0, e^(pbz D) to inf: take e^(pbz D − pcz))
    large = exponent > _LARGE_EXPONENT
    small = np.exp(unscattered) * np.expm1(np.minimum(exponent, _LARGE_EXPONENT))
    return np.where(large, np.exp(exponent + unscattered) - np.exp(unscattered), small)[()]


@functools.lru_cache(maxsize=256)
def encircled_radius(water: WaterOptics, *, distance: float, fraction: float) -> float:
    r"""Radius holding `fraction` of the scattered light of a point source on a plane.

    Parameters
    ----------
    water : WaterOptics
        The water column.
    distance : float
        Water path z from the source plane [m].
    fraction : float
        Share of the scattered light, in (0, 1) [1].

    Returns
    -------
    float
        The radius R [m]; 0 when nothing is scattered.

    Notes
    -----
    The scattered kernel's encircled energy is a Hankel transform of its MTF:

    .. math::

        E(R) = 2\pi R\int_0^\infty M_s(f)\,J_1(2\pi f R)\,df
             = 1 - \int_0^\infty h(x)\,J_1(x)\,dx,\qquad
        h(x) = 1 - \frac{M_s(x/2\pi R)}{M_s(0)},

    (using :math:`\int_0^\infty J_1 = 1`). The integral is taken by the trapezoid rule on
    x ∈ [0, 200] (step 0.05) plus the tail :math:`h(X)J_0(X)`, exact where h has
    levelled off; R is searched on a log grid (16 points per decade, interpolated in
    ln R) from 1 mm to 10 km.
    """
    if distance <= 0 or scattered_mtf(water, 0.0, distance=distance) <= 0:
        return 0.0
    total = scattered_mtf(water, 0.0, distance=distance)
    radii = np.geomspace(1e-3, 1e4, 7 * 16 + 1)
    x = _HANKEL_X
    scattered = scattered_mtf(water, x[None, :] / (2 * np.pi * radii[:, None]), distance=distance)
    h = 1.0 - scattered / total
    inside = 1.0 - integrate.trapezoid(h * special.j1(x), x, axis=1) - h[:, -1] * special.j0(x[-1])
    reached = np.flatnonzero(inside >= fraction)
    if not reached.size:
        return float(radii[-1])
    i = max(int(reached[0]), 1)
    share = np.clip((fraction - inside[i - 1]) / (inside[i] - inside[i - 1]), 0.0, 1.0)
    return float(np.exp(np.log(radii[i - 1]) + share * np.log(radii[i] / radii[i - 1])))


def coarse_factor(*, spacing: float, extent: float) -> int:
    """Fine cells per coarse cell so that `extent` spans at most `MAX_COARSE` coarse cells.

    Parameters
    ----------
    spacing : float
        Fine cell size [m].
    extent : float
        Width the coarse grid must cover [m].

    Returns
    -------
    int
        A 5-smooth factor, at least `MIN_FACTOR`.
    """
    need = max(MIN_FACTOR, int(np.ceil(extent / (MAX_COARSE * spacing))))
    return next((f for f in (1, *_FACTORS) if f >= need), need)


@dataclass(frozen=True)
class Levels:
    """A fine plane grid and the coarse grid around it.

    Attributes
    ----------
    fine : PlaneGrid
        The fine grid; its shape is a multiple of `factor`.
    coarse : PlaneGrid
        Same axes and depth, cells `factor` times larger, covering the fine grid.
    factor : int
        Fine cells per coarse cell along each axis.
    offset : tuple of int
        Coarse (row, col) of the block holding fine cell (0, 0).
    backend : Backend
        Where `lift`, `downsample` and `upsample` put their arrays (default numpy).
    """

    fine: PlaneGrid
    coarse: PlaneGrid
    factor: int
    offset: tuple[int, int]
    backend: Backend = _NUMPY
    _copies: dict = dataclasses.field(default_factory=dict, init=False, repr=False, compare=False)

    def on(self, backend: Backend) -> Levels:
        """The same levels on `backend` (made once, then kept): its `lift` there."""
        return _copy_on(self, backend, lambda: dataclasses.replace(self, backend=backend))

    @classmethod
    def around(cls, fine: PlaneGrid, *, factor: int, margin: float) -> Levels:
        """The coarse grid covering `fine` and `margin` metres beyond it on every side.

        Parameters
        ----------
        fine : PlaneGrid
            The fine grid (shape a multiple of `factor`).
        factor : int
            Fine cells per coarse cell.
        margin : float
            Width beyond the fine grid [m].

        Returns
        -------
        Levels
        """
        rows, cols = fine.shape
        if rows % factor or cols % factor:
            raise ValueError(f"fine grid shape {fine.shape} is not a multiple of {factor}")
        su, sv = fine.spacing_u * factor, fine.spacing_v * factor
        pad_u = int(np.ceil(margin / su)) + 1
        pad_v = int(np.ceil(margin / sv)) + 1
        coarse_cols = fast_length(cols // factor + 2 * pad_u)
        coarse_rows = fast_length(rows // factor + 2 * pad_v)
        c0 = (coarse_cols - cols // factor) // 2
        r0 = (coarse_rows - rows // factor) // 2
        half = 0.5 * (factor - 1)
        u, v = np.asarray(fine.axis_u), np.asarray(fine.axis_v)
        origin = (
            np.asarray(fine.origin)
            + (half * fine.spacing_u - c0 * su) * u
            + (half * fine.spacing_v - r0 * sv) * v
        )
        coarse = PlaneGrid(
            depth=fine.depth,
            origin=(float(origin[0]), float(origin[1])),
            axis_u=fine.axis_u,
            axis_v=fine.axis_v,
            spacing_u=su,
            spacing_v=sv,
            shape=(coarse_rows, coarse_cols),
        )
        return cls(fine=fine, coarse=coarse, factor=factor, offset=(r0, c0))

    @property
    def block(self) -> tuple[slice, slice]:
        """Coarse index of the region the fine grid covers."""
        (r0, c0), (rows, cols) = self.offset, self.fine.shape
        return slice(r0, r0 + rows // self.factor), slice(c0, c0 + cols // self.factor)

    def downsample(self, fine, rows: slice = slice(None)):
        """A fine field as a coarse one: block means inside the fine region, 0 outside.

        `fine` (numpy array or torch tensor, float32) is zero outside its fine `rows`
        (default all): only the blocks holding them are averaged (the others are 0). The
        coarse field is an array of `fine`'s backend.
        """
        if not _held_by(self.backend, fine):
            return self.on(_backend_of(fine)).downsample(fine, rows)
        xp, s = self.backend.xp, self.factor
        first, last, _ = rows.indices(fine.shape[0])
        blocks = slice(first // s, -(-last // s)) if last > first else slice(0, 0)
        shape = (blocks.stop - blocks.start, s, fine.shape[1] // s, s)
        out = xp.zeros(self.coarse.shape, dtype=xp.float32, device=self.backend.device)
        inside = xp.reshape(fine[blocks.start * s : blocks.stop * s], shape)
        out[self.block][blocks] = xp.mean(inside, axis=(1, 3))
        return out

    def to_coarse(self, row, col):
        """Fractional coarse (row, col) of fractional fine (row, col) [1]."""
        s, (r0, c0) = np.float32(self.factor), self.offset
        shift = np.float32(0.5 / self.factor - 0.5)
        return row / s + np.float32(r0 + shift), col / s + np.float32(c0 + shift)

    @functools.cached_property
    def lift(self):
        """Per axis: lower coarse index and weight of the upper one for each fine cell.

        Arrays of the levels' `backend` (intp or int64 indices, float32 weights).
        """
        return tuple(
            (self.backend.asarray(lower), self.backend.asarray(weight))
            for lower, weight in self._host_lift
        )

    @functools.cached_property
    def _host_lift(self):
        """`lift` in numpy, on the host (what `coarse_rows` reads)."""
        rows, cols = self.fine.shape
        zero = np.float32(0)
        positions = (
            self.to_coarse(np.arange(rows, dtype=np.float32), zero)[0],
            self.to_coarse(zero, np.arange(cols, dtype=np.float32))[1],
        )
        axes = []
        for position in positions:
            lower = np.floor(position).astype(np.intp)
            axes.append((lower, (position - lower).astype(np.float32)))
        return tuple(axes)

    def coarse_rows(self, rows: slice) -> slice:
        """The coarse rows that the bilinear upsampling of the fine `rows` reads."""
        if rows.start == rows.stop:
            return slice(0, 0)
        lower = self._host_lift[0][0]
        return slice(int(lower[rows.start]), int(lower[rows.stop - 1]) + 2)

    def upsample(self, coarse, rows: slice = slice(None)):
        """A coarse field at the fine cell centres (bilinear interpolation), float32.

        Only the fine `rows` are returned (default all), as an array of `coarse`'s
        backend (numpy array or torch tensor).
        """
        if not _held_by(self.backend, coarse):
            return self.on(_backend_of(coarse)).upsample(coarse, rows)
        (rl, rw), (cl, cw) = self.lift
        rl, rw = rl[rows], rw[rows]
        along = coarse[rl] * (1 - rw)[:, None] + coarse[rl + 1] * rw[:, None]
        fine = along[:, cl] * (1 - cw) + along[:, cl + 1] * cw
        return self.backend.xp.astype(fine, self.backend.xp.float32)


_ALL = (slice(None), slice(None))


def _overwrite(backend: Backend) -> dict:
    """`scipy.fft`'s leave to overwrite its input (numpy only: torch's FFTs lack it)."""
    return {"overwrite_x": True} if backend.name == "numpy" else {}


def _forward(field, rows, backend: Backend):
    """rfft2 of a real field that is zero outside `rows` (a slice of its rows)."""
    fft = backend.fft
    if rows == slice(None):
        return fft.rfft2(field)
    first, last, _ = rows.indices(field.shape[0])
    shape = (field.shape[0], field.shape[1] // 2 + 1)
    half = backend.xp.empty(shape, dtype=backend.xp.complex64, device=backend.device)
    half[:first] = 0.0
    if last > first:  # torch's FFTs refuse an empty batch of rows
        half[first:last] = fft.rfft(field[first:last], axis=1)
    half[last:] = 0.0
    return fft.fft(half, axis=0, **_overwrite(backend))


def _direct(columns, field, rows_in, rows_out, backend: Backend):
    """`field` filtered by the kernel `columns`, on `rows_out`, by direct column sums.

    `field` is zero outside its rows `rows_in`; see `Spread.filtered`. The sums are
    `backend.kernels.column_convolution`'s.
    """
    xp, shape = backend.xp, field.shape
    first, start = rows_in.indices(shape[0])[0], rows_out.indices(shape[0])[0]
    rows = len(range(*rows_out.indices(shape[0])))
    if not rows or not len(range(*rows_in.indices(shape[0]))):
        return _no_rows(rows, shape[1], backend)
    half = backend.fft.rfft(field[rows_in], axis=1)
    mixed = xp.zeros((rows, half.shape[1]), dtype=xp.complex64, device=backend.device)
    backend.kernels.column_convolution(columns, half, first, start, mixed)
    return backend.fft.irfft(mixed, n=shape[1], axis=1)


def _inverse(spectrum, shape, rows, backend: Backend):
    """irfft2 of `spectrum` to `shape`, on the rows `rows` (a slice) only."""
    if rows == slice(None):
        return backend.fft.irfft2(spectrum, s=shape)
    columns = backend.fft.ifft(spectrum, axis=0, **_overwrite(backend))
    if not len(range(*rows.indices(shape[0]))):
        return _no_rows(0, shape[1], backend)
    return backend.fft.irfft(columns[rows], n=shape[1], axis=1)


def _no_rows(rows: int, cols: int, backend: Backend):
    """Zeros of `rows` × `cols`, float32: a field filtered from no rows, or to none.

    torch's FFTs refuse an empty batch of rows, where numpy's return an empty array.
    """
    xp = backend.xp
    return xp.zeros((rows, cols), dtype=xp.float32, device=backend.device)


@dataclass(frozen=True)
class Spread:
    """One-way spreading of light over a water path onto a two-level plane.

    Attributes
    ----------
    levels : Levels
        The plane.
    near : ndarray
        Near filter on the fine grid's rfft2 frequencies [1].
    far : ndarray
        Far filter on the coarse grid's rfft2 frequencies [1].
    whole : ndarray
        The whole MTF on the coarse grid's frequencies, for the light outside the fine
        grid [1].
    columns : ndarray
        The far filter's kernel along the coarse columns, per row frequency: the inverse
        FFT of `far` along axis 0, complex64.
    backend : Backend
        Where the filters (and `levels`' arrays) are, and what the spreads run on
        (default numpy, as `build` makes them; `on` moves them).
    """

    levels: Levels
    near: np.ndarray
    far: np.ndarray
    whole: np.ndarray
    columns: np.ndarray
    backend: Backend = _NUMPY
    _copies: dict = dataclasses.field(default_factory=dict, init=False, repr=False, compare=False)

    def on(self, backend: Backend) -> Spread:
        """The same spread with its filters and levels on `backend`.

        Made once per backend and kept (the filters are copied to the device once per
        scene, not per sample); `self` when it is already there.

        Parameters
        ----------
        backend : Backend
            From `workers.backends.backend.get_backend`.

        Returns
        -------
        Spread
        """

        def make():
            filters = {
                name: backend.asarray(self.backend.to_numpy(getattr(self, name)))
                for name in ("near", "far", "whole", "columns")
            }
            levels = self.levels.on(backend)
            return dataclasses.replace(self, levels=levels, backend=backend, **filters)

        return _copy_on(self, backend, make)

    @classmethod
    def build(
        cls,
        *,
        water: WaterOptics,
        levels: Levels,
        distance: float,
        truncation: float | None,
        passes: int = 1,
        gain: float = 1.0,
        blur: tuple[float, float] = (0.0, 0.0),
        sway: np.ndarray | None = None,
    ) -> Spread:
        r"""The filters of the water path `distance` for the plane `levels`.

        Parameters
        ----------
        water : WaterOptics
            The water column.
        levels : Levels
            The plane (fine and coarse grids).
        distance : float
            Water path from the surface to the plane [m].
        truncation : float or None
            If set, the share of the scattered light at which the point-spread function
            is cut off (the paper truncates it at 0.95): light scattered further is
            dropped. None keeps the whole function.
        passes : int, optional
            1: one way (MTF); 2: down and up the same path in one product (MTF²).
        gain : float, optional
            A factor on the whole filter, e.g. a uniform reflectance between the passes.
        blur : tuple of float, optional
            Standard deviations (along the grid's u and v axes) of a Gaussian added to
            the fine level's kernel [m] (default none): what brings the splat and gather
            of the rays to the scale the light is read at (`workers.fast.planes.read_blur`).
            The coarse level, far wider, is left as it is.
        sway : ndarray, optional
            The covariance along (u, v) of a further Gaussian on the fine level [m²]
            (`workers.setup.compiled.Setup.subgrid_sway`: where the sub-grid slopes move
            the lines of sight); None: none.

        Returns
        -------
        Spread

        Notes
        -----
        With :math:`W(f) = e^{-(f/f_c)^2}`, :math:`f_c = 1/(4\Delta)`, Δ the larger coarse
        spacing: near = MTF − M_s W on the fine grid, far = M_s W on the coarse grid. The
        far filter is divided by the transfer function of the fine-to-coarse block mean
        and of the bilinear return, about [sinc(f_u Δ_u) sinc(f_v Δ_v) / sinc(f_u δ_u)
        sinc(f_v δ_v)]³ (δ the fine spacing; 1 when the levels coincide), so the two
        levels add up to the MTF within the coarse band. With `truncation`, the far kernel
        is cut in space at `encircled_radius` of that share (the near kernel lies well
        inside it).
        """
        fine, coarse = levels.fine, levels.coarse
        delta = max(coarse.spacing_u, coarse.spacing_v)
        cutoff = 1.0 / (4.0 * delta)
        f_fine = fine.frequency()
        low = np.exp(-((f_fine / cutoff) ** 2))
        mtf = water.mtf(f_fine, distance=distance).astype(np.float64) ** passes
        if any(blur) or sway is not None:
            fv = np.fft.fftfreq(fine.shape[0], d=fine.spacing_v)[:, None]
            fu = np.fft.rfftfreq(fine.shape[1], d=fine.spacing_u)[None, :]
            mtf = mtf * np.exp(-2.0 * np.pi**2 * ((blur[0] * fu) ** 2 + (blur[1] * fv) ** 2))
            if sway is not None:
                mtf = mtf * gaussian_transfer(fu, fv, sway)
        near = mtf - scattered_mtf(water, f_fine, distance=distance, passes=passes) * low
        rows, cols = coarse.shape
        fv = np.fft.fftfreq(rows, d=coarse.spacing_v)[:, None]
        fu = np.fft.rfftfreq(cols, d=coarse.spacing_u)[None, :]
        f_coarse = np.hypot(fv, fu)
        transfer = (
            np.sinc(fu * coarse.spacing_u)
            / np.sinc(fu * fine.spacing_u)
            * np.sinc(fv * coarse.spacing_v)
            / np.sinc(fv * fine.spacing_v)
        ) ** 3
        scattered = scattered_mtf(water, f_coarse, distance=distance, passes=passes)
        far = scattered * np.exp(-((f_coarse / cutoff) ** 2)) / transfer
        unscattered = np.exp(-passes * water.attenuation * distance)
        if truncation is not None:
            radius = encircled_radius(water, distance=distance, fraction=truncation)
            kernel = scipy.fft.irfft2(far, s=coarse.shape)
            r = np.fft.fftfreq(rows, d=1.0 / rows)[:, None] * coarse.spacing_v
            c = np.fft.fftfreq(cols, d=1.0 / cols)[None, :] * coarse.spacing_u
            beyond = np.hypot(r, c) > radius
            kernel[beyond] = 0.0
            far = scipy.fft.rfft2(kernel).real
            kernel = scipy.fft.irfft2(scattered, s=coarse.shape)
            kernel[beyond] = 0.0
            scattered = scipy.fft.rfft2(kernel).real
        far = (gain * far).astype(np.float32)
        return cls(
            levels=levels,
            near=(gain * near).astype(np.float32),
            far=far,
            whole=(gain * (unscattered + scattered)).astype(np.float32),
            columns=np.fft.ifft(far.astype(np.float64), axis=0).astype(np.complex64),
        )

    def __call__(self, fine, coarse=None, *, far_out=True):
        """Spread a field: a fine array and, optionally, the light outside the fine grid.

        The fields are numpy arrays or torch tensors (float32); the spread runs on their
        backend (`on`), and returns arrays of it.

        Parameters
        ----------
        fine : ndarray or torch.Tensor
            Field on the fine grid (e.g. irradiance [W/m²] or power per area).
        coarse : ndarray or torch.Tensor, optional
            Field on the coarse grid outside the fine region (0 inside it).
        far_out : bool, optional
            Also return the spread field outside the fine region (default True).

        Returns
        -------
        fine : ndarray
            The spread field on the fine grid, float32.
        coarse : ndarray or None
            The spread field on the coarse grid outside the fine region (0 inside it),
            with the whole MTF; None when `far_out` is false.
        """
        if not _held_by(self.backend, fine):
            return self.on(_backend_of(fine))(fine, coarse, far_out=far_out)
        levels = self.levels
        source = levels.downsample(fine)
        if coarse is not None:
            source += coarse
        out, far, outside = self.filtered(fine, source, far_out=far_out)
        out += levels.upsample(far)
        return out, outside

    def filtered(self, fine, source, *, rows_in=_ALL, rows_out=_ALL, far_out=False):
        """The two parts of a spread, before the far one is brought to the fine grid.

        The fields are numpy arrays or torch tensors; the spread runs on their backend
        (`on`: scipy's FFTs and the numba column sums for numpy, torch's FFTs and
        `workers.backends.kernels_torch.column_convolution` for torch) and returns its arrays.

        Parameters
        ----------
        fine : ndarray or torch.Tensor
            Field on the fine grid, float32.
        source : ndarray or torch.Tensor
            The far part's source on the coarse grid: `fine`'s block means
            (`Levels.downsample`) plus the light outside the fine grid, float32.
        rows_in : tuple of slice, optional
            The rows of `fine` and of `source` outside which they are zero.
        rows_out : tuple of slice, optional
            The rows of the near (fine) and far (coarse) parts to return.
        far_out : bool, optional
            Also return the spread field outside the fine region (all rows).

        Returns
        -------
        near : ndarray
            The near spread of `fine` on its `rows_out`, float32.
        far : ndarray
            The far spread of `source` on the coarse grid (0 outside its `rows_out`),
            float32: the whole spread is ``near + levels.upsample(far)``.
        outside : ndarray or None
            As in `__call__`.

        Notes
        -----
        A 2-D real FFT is a pass along rows and one along columns, so rows known to be
        zero skip the first pass and rows not needed skip the last: the same transform,
        cheaper. On the coarse grid the light often fills a few rows and a few rows are
        read: when (rows in) × (rows out) is below N log₂ N (N the coarse rows), the two
        column passes are replaced by the circular convolution they make, summed directly
        along each column of the row spectra with the far kernel `columns`. Both are the
        same linear map; they differ by float32 rounding (relative 1e-7 of the field).
        """
        backend = self.backend
        if not _held_by(backend, fine):
            return self.on(_backend_of(fine)).filtered(
                fine, source, rows_in=rows_in, rows_out=rows_out, far_out=far_out
            )
        spectrum = _forward(fine, rows_in[0], backend)
        spectrum *= self.near
        near = _inverse(spectrum, fine.shape, rows_out[0], backend)
        shape = source.shape
        inside = len(range(*rows_in[1].indices(shape[0])))
        read = len(range(*rows_out[1].indices(shape[0])))
        if (
            not far_out
            and rows_out[1] != slice(None)
            and inside * read < shape[0] * np.log2(shape[0])
        ):
            far = _direct(self.columns, source, rows_in[1], rows_out[1], backend)
        else:
            spectrum = _forward(source, rows_in[1], backend)
            far = _inverse(spectrum * self.far, shape, rows_out[1], backend)
        if rows_out[1] != slice(None):
            xp = backend.xp
            rows = far
            far = xp.zeros(shape, dtype=xp.float32, device=backend.device)
            far[rows_out[1]] = rows
        if not far_out:
            return near, far, None
        outside = backend.fft.irfft2(spectrum * self.whole, s=shape)
        outside[self.levels.block] = 0.0
        return near, far, outside
