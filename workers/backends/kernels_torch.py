"""The render's kernels on PyTorch tensors: `workers.backends.kernels`' eight, vectorised.

The same names, arguments, out-parameters and returned ints as the numba loops of
`workers.backends.kernels`, on torch tensors of the same dtypes on any device (CPU or CUDA): a
``Cells`` is the same NamedTuple of float32 scalars. Every ray, pixel or point is handled
at once (no Python loop over them), in float32 with the numba code's operations in the
same order (``t = slope·depth; t += base; t −= origin; t·scale``), so the two agree to
float32 rounding; `bilinear_sum`, `reach`, `sample` and `cell_uniforms` have no sums
whose order could differ.

No float atomics: the scatter-adds of `splat_levels` (the rays' bilinear deposits and
the fine field's block sums) are taken in fixed point (`_FixedPoint`), exact int64 sums,
so the result does not depend on the rays' order nor on the device's scheduling: the
same inputs give the same bytes. The only host synchronisations are the ints the
kernels return (and `gather_levels`' window, which the caller passes as ints):
`surface_hits` takes a fixed count of steps where numba stops at convergence.
"""

from __future__ import annotations

import functools
import math

import torch

from workers.backends.kernels import Cells

__all__ = [
    "Cells",
    "bilinear_sum",
    "cell_uniforms",
    "column_convolution",
    "gather_levels",
    "reach",
    "sample",
    "splat_levels",
    "surface_hits",
]

_MASK = (1 << 64) - 1
_GOLDEN = 0x9E3779B97F4A7C15
_MIX_1 = 0xBF58476D1CE4E5B9
_MIX_2 = 0x94D049BB133111EB
_FRAME = 0x632BE59BD9B4E019

_HEADROOM_BITS = 62
"""The fixed point's sums stay below 2⁶² in magnitude (int64 holds 2⁶³)."""


_SCALARS = 4096
"""Most 0-d tensors `_scalar` keeps (a few kilobytes each on a GPU, at most)."""


def _scalar(value, like: torch.Tensor) -> torch.Tensor:
    """A float32 scalar as a 0-d float32 tensor on `like`'s device (float32 arithmetic).

    The tensor is made once per value and device (`_device_scalar`), so that a call
    copies no Python scalar to the device: the planes' maps (`Cells`), densities and
    the sea's grid steps are the same in every sample of a scene. A device tensor, not a
    Python number: CUDA divides by a host scalar as a product with its reciprocal, not
    as numba does.
    """
    value = float(value)
    return _device_scalar(value, math.copysign(1.0, value), like.device)


@functools.lru_cache(maxsize=_SCALARS)
def _device_scalar(value: float, sign: float, device: torch.device) -> torch.Tensor:
    """`_scalar`'s tensor of `value` on `device` (`sign` tells −0.0 from 0.0 in the key)."""
    return torch.tensor(value, dtype=torch.float32, device=device)


def _at(base, slope, depth, origin, scale):
    """Fractional cell coordinate of every line on the plane [1], float32 (numba's order)."""
    t = slope * depth
    t = t + base
    t = t - origin
    return t * scale


def _coordinates(lines, cells):
    """Fractional (row, col) of every line's crossing of the plane described by `cells`."""
    base_u, slope_u, base_v, slope_v = lines
    depth, origin_u, scale_u, origin_v, scale_v = (
        _scalar(v, base_u)
        for v in (cells.depth, cells.origin_u, cells.scale_u, cells.origin_v, cells.scale_v)
    )
    row = _at(base_v, slope_v, depth, origin_v, scale_v)
    col = _at(base_u, slope_u, depth, origin_u, scale_u)
    return row, col


def _coarse(row, col, cells):
    """Fractional coarse (row, col) of fractional fine ones, float32 (numba's order)."""
    factor = _scalar(cells.factor, row)
    return row / factor + _scalar(cells.shift_v, row), col / factor + _scalar(cells.shift_u, col)


def _split(row, col, rows, cols):
    """Cells (r, c) below-left of points, their fractions down and right, and a hit mask.

    As `workers.backends.kernels._split`: a point is on the grid if row, col >= 0, r < rows − 1 and
    c < cols − 1 (r = floor(row)); off it r = c = 0 and both fractions 0 (mask False).
    """
    r = torch.floor(row.clamp(min=0.0, max=float(rows)))
    c = torch.floor(col.clamp(min=0.0, max=float(cols)))
    hit = (row >= 0) & (col >= 0) & (r < rows - 1) & (c < cols - 1)
    zero = torch.zeros((), dtype=row.dtype, device=row.device)
    down = torch.where(hit, row - r, zero)
    right = torch.where(hit, col - c, zero)
    r = torch.where(hit, r.to(torch.int64), 0)
    c = torch.where(hit, c.to(torch.int64), 0)
    return r, c, down, right, hit


def _corner_weights(down, right):
    """The bilinear weights of the four corners (r, c), (r, c+1), (r+1, c), (r+1, c+1)."""
    left = 1.0 - right
    w2 = left * down
    w3 = right * down
    return left - w2, right - w3, w2, w3


def _bilinear(field, r, c, weights):
    """Σ corner value × weight at cells (r, c) of a 2-D field, in numba's order."""
    w0, w1, w2, w3 = weights
    total = field[r, c] * w0
    total = total + field[r, c + 1] * w1
    total = total + field[r + 1, c] * w2
    return total + field[r + 1, c + 1] * w3


def _extent(index, hit, size):
    """(min index, max index + 2) over the hits, (size, 0) if none: int64 0-d tensors."""
    low = torch.where(hit, index, size).amin() if index.numel() else index.new_tensor(size)
    high = torch.where(hit, index + 2, 0).amax() if index.numel() else index.new_tensor(0)
    return low, high


class _FixedPoint:
    r"""Exact, order-free sums of float32 terms: int64 multiples of a power of two.

    Parameters
    ----------
    terms : torch.Tensor
        Every term that will be added (any shape, finite), float32.

    Notes
    -----
    The scale is :math:`s = 2^{\lfloor 62 - \log_2(n\,M)\rfloor}` for n terms of largest
    magnitude M, so that no partial sum exceeds 2⁶² in magnitude (int64 holds 2⁶³). Each
    term is rounded to the nearest multiple of 1/s: an absolute error at most
    :math:`1/(2s) \le n M 2^{-62}`, i.e. ``n · 2⁻⁶²`` of the largest term (2⁻⁴⁰ for four
    million terms, far below float32's 2⁻²⁴); the sums themselves are exact, so they do
    not depend on the order of the terms. The scale is computed on the device (no host
    synchronisation).
    """

    def __init__(self, terms: torch.Tensor):
        largest = terms.abs().amax().to(torch.float64) if terms.numel() else None
        if largest is None:
            self.scale = torch.ones((), dtype=torch.float64, device=terms.device)
            return
        largest = largest.clamp(min=torch.finfo(torch.float64).tiny)
        bits = _HEADROOM_BITS - torch.log2(largest * max(terms.numel(), 1))
        self.scale = torch.exp2(torch.floor(bits).clamp(max=1000.0))

    def quantise(self, values: torch.Tensor) -> torch.Tensor:
        """Float values as int64 multiples of 1/scale."""
        return torch.round(values.to(torch.float64) * self.scale).to(torch.int64)

    def value(self, sums: torch.Tensor) -> torch.Tensor:
        """Int64 sums back as float64 values."""
        return sums.to(torch.float64) / self.scale


def _deposit(shape, r, c, weights, values, hit, fixed):
    """The bilinear deposits of `values` at (r, c) of a zero field of `shape`, as int64."""
    rows, cols = shape
    sums = torch.zeros(rows * cols, dtype=torch.int64, device=values.device)
    flat = r * cols + c
    for offset, weight in zip((0, 1, cols, cols + 1), weights, strict=True):
        term = torch.where(hit, fixed.quantise(weight * values), 0)
        sums.index_add_(0, flat + offset, term)
    return sums.reshape(rows, cols)


def splat_levels(lines, power, cells, densities, fine, source, block):
    """Splat rays onto a two-level plane: `workers.backends.kernels.splat_levels` on tensors.

    Parameters
    ----------
    lines : tuple of torch.Tensor
        ``(base_u, slope_u, base_v, slope_v)`` of the rays, float32.
    power : torch.Tensor
        Power of each ray, float32 (any non-finite value makes both fields NaN).
    cells : Cells
        The plane's map.
    densities : tuple of float32
        1 / cell area of the fine and coarse grids [1/m²].
    fine : torch.Tensor
        In zeros, out the fine field: power per area, float32.
    source : torch.Tensor
        In zeros, out the coarse source of the far spread, float32.
    block : tuple of int
        Coarse (row, col) of the fine grid's first block.

    Returns
    -------
    tuple of int
        The fine rows and the coarse rows outside which `fine` and `source` are zero
        (first, last + 1 of each).

    Notes
    -----
    Each deposit is summed in fixed point (`_FixedPoint`, one scale per level from its
    largest term): the fields differ from the numba loop's sequential float32 sums by
    float32 rounding and a resolution of (terms) · 2⁻⁶² of the largest deposit, and do
    not depend on the order of the rays. The block means are the exact sums of the
    fine field's deposits in each block (numba sums the float32 fine values in float64).
    """
    rows, cols = fine.shape
    factor = int(cells.factor)
    row, col = _coordinates(lines, cells)
    r, c, down, right, hit = _split(row, col, rows, cols)
    value = power * _scalar(densities[0], power)
    weights = _corner_weights(down, right)
    fixed = _FixedPoint(torch.where(hit, value, 0.0))
    fine_sums = _deposit((rows, cols), r, c, weights, value, hit, fixed)
    top, bottom = _extent(r, hit, rows)
    left, right_end = _extent(c, hit, cols)
    rc, cc, down, right, coarse_hit = _split(*_coarse(row, col, cells), *source.shape)
    coarse_hit &= ~hit
    value = power * _scalar(densities[1], power)
    coarse = _FixedPoint(torch.where(coarse_hit, value, 0.0))
    weights = _corner_weights(down, right)
    coarse_sums = _deposit(source.shape, rc, cc, weights, value, coarse_hit, coarse)
    coarse_top, coarse_bottom = _extent(rc, coarse_hit, source.shape[0])
    top, bottom, left, right_end, coarse_top, coarse_bottom = torch.stack(
        (top, bottom, left, right_end, coarse_top, coarse_bottom)
    ).tolist()
    # fixed point holds finite values only: a non-finite power makes both fields NaN (a
    # sample the service refuses), where numba carries it to its cells
    poison = torch.where(torch.isfinite(power).all(), 0.0, torch.nan).to(torch.float32)
    fine += fixed.value(fine_sums).to(torch.float32) + poison
    source += coarse.value(coarse_sums).to(torch.float32) + poison
    first_row, last_row = top // factor, -(-bottom // factor)
    first_col, last_col = left // factor, -(-right_end // factor)
    if first_row < last_row and first_col < last_col:
        coarse_top = min(coarse_top, block[0] + first_row)
        coarse_bottom = max(coarse_bottom, block[0] + last_row)
        blocks = _block_sums(fine_sums, factor, (first_row, last_row, first_col, last_col))
        mean = (fixed.value(blocks) * (1.0 / (factor * factor))).to(torch.float32)
        target = source[
            block[0] + first_row : block[0] + last_row, block[1] + first_col : block[1] + last_col
        ]
        target += mean
    return min(top, bottom), bottom, min(coarse_top, coarse_bottom), coarse_bottom


def _block_sums(sums, factor, box):
    """The int64 sums of `factor` × `factor` blocks of `sums` in the block range `box`."""
    first_row, last_row, first_col, last_col = box
    rows, cols = (last_row - first_row) * factor, (last_col - first_col) * factor
    part = sums[first_row * factor :, first_col * factor :][:rows, :cols]
    if part.shape != (rows, cols):  # blocks running past the fine grid's edge hold zeros
        part = torch.nn.functional.pad(part, (0, cols - part.shape[1], 0, rows - part.shape[0]))
    blocks = part.reshape(last_row - first_row, factor, last_col - first_col, factor)
    return blocks.sum(dim=(1, 3))


def reach(lines, cells, shape, coarse_shape):
    """The window the lines read and the coarse rows the others do (`kernels.reach`).

    Returns the fine window's first row, last row + 1, first column and last column + 1
    (all 0 if no line meets the fine grid), then the first row and the last row + 1 of
    the coarse cells the lines off the fine grid read (0, 0 if none): python ints, read
    from the device at once.
    """
    rows, cols = shape
    row, col = _coordinates(lines, cells)
    r, c, _, _, hit = _split(row, col, rows, cols)
    rc, _, _, _, coarse_hit = _split(*_coarse(row, col, cells), *coarse_shape)
    extents = (
        *_extent(r, hit, rows),
        *_extent(c, hit, cols),
        *_extent(rc, coarse_hit & ~hit, coarse_shape[0]),
    )
    top, bottom, left, right, first, last = torch.stack(extents).tolist()
    if top >= bottom:
        top, bottom, left, right = 0, 0, 0, 0
    if first >= last:
        first, last = 0, 0
    return top, bottom, left, right, first, last


def gather_levels(lines, cells, shape, parts, lift, lit, weights, out):
    """Add the spread field at each line's crossing to each output (`kernels.gather_levels`).

    Parameters
    ----------
    lines : tuple of torch.Tensor
        ``(base_u, slope_u, base_v, slope_v)`` of the pixels' lines of sight, float32.
    cells : Cells
        The plane's map.
    shape : tuple of int
        The fine grid's shape.
    parts : tuple
        ``(near, window, far, tail)``: the near spread on the fine rows
        ``window[0]:window[1]``, the window (python ints, `reach`), the far spread on the
        coarse grid (on the rows `reach` gives too), the beam tail's near and far spreads
        (size 0: none); float32.
    lift : tuple
        ``((lower row, weight), (lower col, weight))`` of each fine cell on the coarse
        grid, int64 and float32 tensors.
    lit : torch.Tensor
        Share of each fine cell's light that the last output keeps (the gate's water the
        target leaves lit), float32 (size 0: all); the other outputs read all the light.
    weights : tuple of torch.Tensor
        Per output, the factor on each pixel, float32.
    out : tuple of torch.Tensor
        In and out: per output, each pixel's sum, float32; pixels off both grids add
        nothing.

    Notes
    -----
    The window's field is ``near (+ tail near) + (far (+ tail far) upsampled)`` (times
    `lit` for the last output), in numba's float32 order (the far part along the columns
    first); a line off the fine grid reads the far spread (+ the tail's far part) at its
    coarse crossing, all its light kept, as numba does. Each line is located once for
    all outputs. No sum over lines, so the values agree with numba's to float32 rounding.
    """
    near, window, far, (tail_near, tail_far) = parts
    top, bottom, left, right = window
    row, col = _coordinates(lines, cells)
    r, c, down, right_share, hit = _split(row, col, *shape)
    if top < bottom:
        (rl, rw), (cl, cw) = (
            tuple(torch.as_tensor(part, device=near.device) for part in axis) for axis in lift
        )
        a, upper = rl[top:bottom, None], rw[top:bottom, None]
        lower = 1.0 - upper
        b, across = cl[None, left:right], cw[None, left:right]

        def along(column):
            value = far[a, column] * lower + far[a + 1, column] * upper
            if tail_far.numel():
                value = value + (tail_far[a, column] * lower + tail_far[a + 1, column] * upper)
            return value

        field = near[:, left:right]
        if tail_near.numel():
            field = field + tail_near[top:bottom, left:right]
        field = field + (along(b) * (1.0 - across) + along(b + 1) * across)
        r = torch.where(hit, r - top, 0)
        c = torch.where(hit, c - left, 0)
        corners = _corner_weights(down, right_share)
        total = _bilinear(field, r, c, corners)
        for k, (weight, sums) in enumerate(zip(weights, out, strict=True)):
            if k == len(out) - 1 and lit.numel():
                total = _bilinear(field * lit[top:bottom, left:right], r, c, corners)
            sums.copy_(torch.where(hit, sums + total * weight, sums))
    rc, cc, down, right_share, coarse_hit = _split(*_coarse(row, col, cells), *far.shape)
    coarse_hit &= ~hit
    corners = _corner_weights(down, right_share)
    total = _bilinear(far, rc, cc, corners)
    if tail_far.numel():
        total = total + _bilinear(tail_far, rc, cc, corners)
    for weight, sums in zip(weights, out, strict=True):
        sums.copy_(torch.where(coarse_hit, sums + total * weight, sums))


def sample(lines, cells, fields, box, out):
    """Bilinear values of fine-grid fields at the lines (`workers.backends.kernels.sample`).

    Parameters
    ----------
    lines : tuple of torch.Tensor
        ``(base_u, slope_u, base_v, slope_v)``, float32.
    cells : Cells
        The plane's map.
    fields : tuple of torch.Tensor
        Fields on the fine grid, float32.
    box : tuple of int
        First row, last row + 1, first column, last column + 1 of the cells outside which
        every field is 0 (lines there give 0).
    out : torch.Tensor, shape (len(fields), lines)
        Out: the values, float32.
    """
    rows, cols = fields[0].shape
    top, bottom, left, right = box
    r, c, down, right_share, hit = _split(*_coordinates(lines, cells), rows, cols)
    hit &= (r + 1 >= top) & (r < bottom) & (c + 1 >= left) & (c < right)
    weights = _corner_weights(down, right_share)
    for k, field in enumerate(fields):
        out[k] = torch.where(hit, _bilinear(field, r, c, weights), 0.0)


def bilinear_sum(grids, sizes, inverses, x, y, out):
    """Sum over periodic grids of their bilinear values at points (`workers.backends.kernels`).

    Parameters
    ----------
    grids : tuple of torch.Tensor
        Per grid, its fields, shape (fields, (N + 1)²), float32: each an N × N periodic
        field with its first row and column repeated after the last, flattened.
    sizes : tuple of int
        N of each grid.
    inverses : tuple of float32
        1 / spacing of each grid [1/m].
    x, y : torch.Tensor
        World coordinates of the points [m] (taken to float32 first).
    out : torch.Tensor, shape (fields, points)
        Out: the sums, float32.

    Notes
    -----
    numba's float32 arithmetic in the same order, the grids added in turn; cells wrap
    with a remainder of the sign of N (numba's bit mask for a power of two, the same
    values for negative coordinates).
    """
    x, y = x.to(torch.float32), y.to(torch.float32)
    for g, (fields, n) in enumerate(zip(grids, sizes, strict=True)):
        tx, ty = x * _scalar(inverses[g], x), y * _scalar(inverses[g], y)
        column, row = torch.floor(tx), torch.floor(ty)
        tx, ty = tx - column, ty - row
        c = torch.remainder(column.to(torch.int64), n)
        r = torch.remainder(row.to(torch.int64), n)
        low = r * (n + 1) + c
        high = low + n + 1
        for k in range(out.shape[0]):
            field = fields[k]
            lower = (field[low + 1] - field[low]) * tx + field[low]
            upper = (field[high + 1] - field[high]) * tx + field[high]
            value = (upper - lower) * ty + lower
            out[k] = value if g == 0 else out[k] + value


def surface_hits(grids, sizes, inverses, rays, tolerance, iterations, travel, eta):
    """Rays' hits on the sum of periodic elevation grids (`workers.backends.kernels`).

    Parameters
    ----------
    grids, sizes, inverses : tuple
        The elevation grids, as for `bilinear_sum` (one field each).
    rays : tuple
        ``(ox, oy, oz, dx, dy, dz)`` [m], [1]: tensors of the rays' shape, or numbers
        (0-d tensors) for an origin every ray shares.
    tolerance : float
        Largest height change [m] over all rays below which the steps stop changing
        anything.
    iterations : int
        The number of steps.
    travel, eta : torch.Tensor
        Out: each ray's parameter at its hit (the rays' dtype) and the elevation there
        [m] (float32).

    Notes
    -----
    Always `iterations` steps, and no read on the host: a flag on the device, cleared by
    the first step whose largest change is below `tolerance`, keeps every ray where it is
    from then on. The numba loop stops there instead: the same values (to float32
    rounding). Each step samples every grid in one set of operations (`_Elevation`).
    """
    ox, oy, oz, dx, dy, dz = rays
    elevation = _Elevation(grids, sizes, inverses, eta.device)
    if not isinstance(oz, torch.Tensor):  # number / tensor is a reciprocal times the number
        oz = dz.new_full((), oz)
    step = -oz / dz
    height = elevation(ox + step * dx, oy + step * dy)
    going = torch.ones((), dtype=torch.bool, device=eta.device)
    for _ in range(iterations):
        moved = (height - oz) / dz
        new = elevation(ox + moved * dx, oy + moved * dy)
        converged = torch.max(torch.abs(new - height)) < tolerance
        step = torch.where(going, moved, step)
        height = torch.where(going, new, height)
        going = going & ~converged
    travel.copy_(step)
    eta.copy_(height)


class _Elevation:
    """The sum of periodic grids' bilinear values at points, every grid in one set of ops.

    `bilinear_sum`'s arithmetic for one field a grid: the grids' fields laid end to end,
    each point's value on every grid at once (grid × point), then the grids added in turn.
    """

    def __init__(self, grids, sizes, inverses, device):
        self.fields = torch.cat([grid[0] for grid in grids])
        self.size, self.start, self.inverse = _grid_layout(
            tuple(int(n) for n in sizes), tuple(float(i) for i in inverses), device
        )

    def __call__(self, x, y):
        tx = x.to(torch.float32) * self.inverse
        ty = y.to(torch.float32) * self.inverse
        column, row = torch.floor(tx), torch.floor(ty)
        tx, ty = tx - column, ty - row
        c = torch.remainder(column.to(torch.int64), self.size)
        r = torch.remainder(row.to(torch.int64), self.size)
        low = r * (self.size + 1) + c + self.start
        high = low + self.size + 1
        field = self.fields
        lower = (field[low + 1] - field[low]) * tx + field[low]
        upper = (field[high + 1] - field[high]) * tx + field[high]
        value = (upper - lower) * ty + lower
        total = value[0]
        for g in range(1, value.shape[0]):
            total = total + value[g]
        return total


@functools.lru_cache(maxsize=_SCALARS)
def _grid_layout(sizes: tuple, inverses: tuple, device: torch.device) -> tuple:
    """`_Elevation`'s grid sizes, first elements and inverse steps, made once per device.

    Each (grid, 1) on `device`: the grid's side N (int64), the index of its first element
    in the grids laid end to end ((N + 1)² each), its 1 / spacing (float32). Cached, like
    `_scalar`'s, so that a call copies nothing from the host.
    """
    size = torch.tensor(sizes, device=device)[:, None]
    ends = torch.tensor([(n + 1) ** 2 for n in sizes], device=device).cumsum(0)
    start = (ends - (size[:, 0] + 1) ** 2)[:, None]
    inverse = torch.tensor(inverses, dtype=torch.float32, device=device)[:, None]
    return size, start, inverse


def _signed(word: int) -> int:
    """A uint64 as the int64 of the same bits (two's complement)."""
    word &= _MASK
    return word - (1 << 64) if word >> 63 else word


def _shift(z: torch.Tensor, bits: int) -> torch.Tensor:
    """Logical right shift of int64 tensors holding uint64 bits."""
    return (z >> bits) & ((1 << (64 - bits)) - 1)


def _mix(z: torch.Tensor) -> torch.Tensor:
    """SplitMix64's finaliser on int64 tensors holding uint64 bits (wrapping multiplies)."""
    z = z ^ _shift(z, 30)
    z = z * _signed(_MIX_1)
    z = z ^ _shift(z, 27)
    z = z * _signed(_MIX_2)
    return z ^ _shift(z, 31)


def _mix_int(z: int) -> int:
    """SplitMix64's finaliser on a python int (the per-call seed, on the host)."""
    z ^= z >> 30
    z = (z * _MIX_1) & _MASK
    z ^= z >> 27
    z = (z * _MIX_2) & _MASK
    return z ^ (z >> 31)


def cell_uniforms(x, y, inverse, key, frame, first, second):
    """Two uniform numbers in (0, 1) per point, a hash of its cell, the frame and a key.

    `workers.backends.kernels.cell_uniforms` bit for bit: uint64 arithmetic emulated on int64
    tensors (wrapping multiplies and additions, logical shifts).

    Parameters
    ----------
    x, y : torch.Tensor
        World coordinates of the points [m].
    inverse : float32
        1 / cell size [1/m].
    key : int or numpy.uint64
        The seed's key.
    frame : int or numpy.uint64
        Frame index.
    first, second : torch.Tensor
        Out: the numbers, float32, (k + 0.5)·2⁻²⁴ for 24-bit k.
    """
    seed = _mix_int(int(key) ^ ((int(frame) * _FRAME) & _MASK))
    column = torch.floor(x.to(torch.float32) * _scalar(inverse, first)).to(torch.int64)
    row = torch.floor(y.to(torch.float32) * _scalar(inverse, first)).to(torch.int64)
    word = column * _signed(_GOLDEN)
    word = word ^ _mix(row + _signed(seed))
    word = _mix(word)
    first.copy_((_shift(word, 40).to(torch.float32) + 0.5) * 2.0**-24)
    second.copy_(((word & 0xFFFFFF).to(torch.float32) + 0.5) * 2.0**-24)


def column_convolution(kernel, rows, first, start, out):
    """Circular convolution along axis 0 of a few rows with a kernel, per column.

    ``out[o, k] += Σ_j kernel[(start + o − first − j) mod N, k] · rows[j, k]``
    (`workers.backends.kernels.column_convolution`), complex64, the sum over j in increasing
    order; every output row and column at once, one step per input row.
    """
    n = kernel.shape[0]
    lags = start - first + torch.arange(out.shape[0], device=out.device)
    for j in range(rows.shape[0]):
        out += kernel[torch.remainder(lags - j, n)] * rows[j]
