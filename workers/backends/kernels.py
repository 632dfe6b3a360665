"""Compiled loops of the render: rays splatted onto two-level planes, pixels gathered.

`bilinear_sum` samples the sea's periodic cascades at the rays, `surface_hits` finds where
rays meet their sum, `cell_uniforms` hashes the rays' sub-grid cells to uniform numbers
(`workers.sea.surface`); `column_convolution` is the coarse spread's direct column sums
(`workers.fast.spread`).

Each ray or pixel is located on a plane's fine grid from its in-water line
(`workers.setup.interface.Projected`: ``base + z·slope`` along the plane's axes), in float32 with
the arithmetic of `workers.setup.geometry.PlaneGrid.locate_cells`, and splatted or gathered in
the same pass: no index or weight arrays are built. A `Cells` holds the affine map of a
plane; the loops are compiled once by numba (cached on disk) and are sequential, so the
same inputs give the same bytes.
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

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

_ONE = np.float32(1.0)
_ZERO = np.float32(0.0)
_NEXT = np.uint64(1)
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX_1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX_2 = np.uint64(0x94D049BB133111EB)
_FRAME = np.uint64(0x632BE59BD9B4E019)


class Cells(NamedTuple):
    """The float32 map from a ray's in-water line to fractional cells of a fine grid.

    ``col = (slope_u·z + base_u − origin_u) · scale_u`` and likewise for rows; with the
    two-level plane's coarse grid, ``coarse = fine / factor + shift``.
    """

    depth: np.float32
    origin_u: np.float32
    scale_u: np.float32
    origin_v: np.float32
    scale_v: np.float32
    factor: np.float32
    shift_v: np.float32
    shift_u: np.float32

    @classmethod
    def of_grid(cls, grid) -> Cells:
        """The map of a lone fine grid (`workers.setup.geometry.PlaneGrid`), for `sample`."""
        (o0, o1), (u0, u1), (v0, v1) = grid.origin, grid.axis_u, grid.axis_v
        zero, one = np.float32(0), np.float32(1)
        return cls(
            depth=np.float32(grid.depth),
            origin_u=np.float32(o0 * u0 + o1 * u1),
            scale_u=np.float32(1.0 / grid.spacing_u),
            origin_v=np.float32(o0 * v0 + o1 * v1),
            scale_v=np.float32(1.0 / grid.spacing_v),
            factor=one,
            shift_v=zero,
            shift_u=zero,
        )

    @classmethod
    def of(cls, levels) -> Cells:
        """The map of a two-level plane (`workers.fast.spread.Levels`)."""
        shift_v, shift_u = levels.to_coarse(np.float32(0), np.float32(0))
        return cls.of_grid(levels.fine)._replace(
            factor=np.float32(levels.factor),
            shift_v=np.float32(shift_v),
            shift_u=np.float32(shift_u),
        )


@numba.njit(cache=True)
def _at(base, slope, i, depth, origin, scale):
    """Fractional cell coordinate of line i on the plane [1], float32."""
    t = slope[i] * depth
    t = t + base[i]
    t = t - origin
    return t * scale


@numba.njit(cache=True)
def _split(row, col, rows, cols):
    """Cell (r, c) below-left of a point, and its fractions down and right.

    As `workers.setup.geometry.PlaneGrid.locate_cells`; r = -1 for a point off the grid.
    """
    if row >= 0 and col >= 0:
        r, c = int(row), int(col)  # the floor, for values >= 0
        if r < rows - 1 and c < cols - 1:
            return r, c, row - np.float32(r), col - np.float32(c)
    return -1, 0, _ZERO, _ZERO


@numba.njit(cache=True)
def _locate(lines, i, cells, rows, cols):
    """`_split` of line i's crossing of the plane."""
    base_u, slope_u, base_v, slope_v = lines
    row = _at(base_v, slope_v, i, cells.depth, cells.origin_v, cells.scale_v)
    col = _at(base_u, slope_u, i, cells.depth, cells.origin_u, cells.scale_u)
    return _split(row, col, rows, cols)


@numba.njit(cache=True)
def _unsigned(r, c):
    """A cell's (r, c), both >= 0, as unsigned ints.

    numba indexes with them without its negative-index wraparound: 11 % of a splat's
    instructions (callgrind, a 256² sample), 40 % of a gather's with its assembly's.
    """
    return np.uint64(r), np.uint64(c)


@numba.njit(cache=True)
def _deposit(field, row, col, value):
    """Add `value` bilinearly at (row, col) of `field`; False (nothing added) outside."""
    r, c, down, right = _split(row, col, field.shape[0], field.shape[1])
    if r < 0:
        return False
    left = _ONE - right
    w2 = left * down
    w3 = right * down
    r, c = _unsigned(r, c)
    field[r, c] += (left - w2) * value
    field[r, c + _NEXT] += (right - w3) * value
    field[r + _NEXT, c] += w2 * value
    field[r + _NEXT, c + _NEXT] += w3 * value
    return True


@numba.njit(cache=True)
def _coarse(row, col, cells):
    """Fractional coarse (row, col) of a fractional fine one, float32."""
    return row / cells.factor + cells.shift_v, col / cells.factor + cells.shift_u


@numba.njit(cache=True, nogil=True)
def splat_levels(lines, power, cells, densities, fine, source, block):
    """Splat rays onto a two-level plane: the fine field and the coarse spread source.

    Parameters
    ----------
    lines : tuple of ndarray
        ``(base_u, slope_u, base_v, slope_v)`` of the rays, float32.
    power : ndarray
        Power of each ray, float32.
    cells : Cells
        The plane's map.
    densities : tuple of float32
        1 / cell area of the fine and coarse grids [1/m²].
    fine : ndarray
        In zeros, out the fine field: power per area, float32.
    source : ndarray
        In zeros, out the coarse source of the far spread: block means of `fine` inside the
        fine region, the light of the rays that miss it outside, float32.
    block : tuple of int
        Coarse (row, col) of the fine grid's first block.

    Returns
    -------
    tuple of int
        The fine rows and the coarse rows outside which `fine` and `source` are zero
        (first, last + 1 of each).

    Notes
    -----
    Rays that miss the fine grid land on the coarse one; rays that miss both are dropped.
    The block means are taken over the fine rows and columns that rays reached (the
    other blocks hold nothing, and adding their zero changes no value).
    """
    base_u, slope_u, base_v, slope_v = lines
    fine_density, coarse_density = densities
    rows, cols = fine.shape
    top, bottom, left, right = rows, 0, cols, 0
    coarse_top, coarse_bottom = source.shape[0], 0
    for i in range(power.size):
        row = _at(base_v, slope_v, i, cells.depth, cells.origin_v, cells.scale_v)
        col = _at(base_u, slope_u, i, cells.depth, cells.origin_u, cells.scale_u)
        if _deposit(fine, row, col, power[i] * fine_density):
            r, c = int(row), int(col)
            top = min(top, r)
            bottom = max(bottom, r + 2)
            left = min(left, c)
            right = max(right, c + 2)
            continue
        row, col = _coarse(row, col, cells)
        if _deposit(source, row, col, power[i] * coarse_density):
            coarse_top = min(coarse_top, int(row))
            coarse_bottom = max(coarse_bottom, int(row) + 2)
    factor = int(cells.factor)
    share = 1.0 / (factor * factor)
    for br in range(top // factor, (bottom + factor - 1) // factor):
        coarse_top = min(coarse_top, block[0] + br)
        coarse_bottom = max(coarse_bottom, block[0] + br + 1)
        for bc in range(left // factor, (right + factor - 1) // factor):
            total = 0.0
            for r in range(br * factor, (br + 1) * factor):
                for c in range(bc * factor, (bc + 1) * factor):
                    total += fine[r, c]
            source[block[0] + br, block[1] + bc] += np.float32(total * share)
    fine_rows = min(top, bottom), bottom
    coarse_rows = min(coarse_top, coarse_bottom), coarse_bottom
    return (*fine_rows, *coarse_rows)


@numba.njit(cache=True, nogil=True)
def reach(lines, cells, shape, coarse_shape):
    """The fine cells the lines' bilinear corners touch, and the coarse rows the others read.

    Parameters
    ----------
    lines : tuple of ndarray
        ``(base_u, slope_u, base_v, slope_v)`` of the pixels' lines of sight, float32.
    cells : Cells
        The plane's map.
    shape, coarse_shape : tuple of int
        The fine and the coarse grids' shapes.

    Returns
    -------
    tuple of int
        The window: the first row, the last row + 1, the first column and the last
        column + 1 of the fine cells the lines' bilinear corners touch (all 0 if no line
        meets the fine grid); then the first row and the last row + 1 of the coarse cells
        whose corners the lines that miss the fine grid touch on the coarse one
        (`gather_levels` reads them there; 0, 0 if every line meets the fine grid or
        misses both). One pass over the lines.
    """
    rows, cols = shape
    base_u, slope_u, base_v, slope_v = lines
    top, bottom, left, right = rows, 0, cols, 0
    first, last = coarse_shape[0], 0
    for i in range(lines[0].size):
        row = _at(base_v, slope_v, i, cells.depth, cells.origin_v, cells.scale_v)
        col = _at(base_u, slope_u, i, cells.depth, cells.origin_u, cells.scale_u)
        r, c, _, _ = _split(row, col, rows, cols)
        if r >= 0:
            top = min(top, r)
            bottom = max(bottom, r + 2)
            left = min(left, c)
            right = max(right, c + 2)
            continue
        row, col = _coarse(row, col, cells)
        r = _split(row, col, coarse_shape[0], coarse_shape[1])[0]
        if r >= 0:
            first = min(first, r)
            last = max(last, r + 2)
    if top >= bottom:
        top, bottom, left, right = 0, 0, 0, 0
    if first >= last:
        first, last = 0, 0
    return top, bottom, left, right, first, last


@numba.njit(cache=True)
def _interpolate(field, r, c, down, right):
    """Bilinear value of `field` at cell (r, c) with fractions down and right, float32."""
    left = _ONE - right
    w2 = left * down
    w3 = right * down
    r, c = _unsigned(r, c)
    total = field[r, c] * (left - w2)
    total += field[r, c + _NEXT] * (right - w3)
    total += field[r + _NEXT, c] * w2
    total += field[r + _NEXT, c + _NEXT] * w3
    return total


@numba.njit(cache=True, nogil=True)
def gather_levels(lines, cells, shape, parts, lift, lit, weights, out):
    """Add the spread field, bilinearly interpolated at each line's crossing, to each output.

    Parameters
    ----------
    lines : tuple of ndarray
        ``(base_u, slope_u, base_v, slope_v)`` of the pixels' lines of sight, float32.
    cells : Cells
        The plane's map.
    shape : tuple of int
        The fine grid's shape.
    parts : tuple
        ``(near, window, far, tail)``: the near spread on the fine rows
        ``window[0]:window[1]``, the fine cells the lines reach (`reach`), the far spread
        on the coarse grid (on the rows the lines off the fine grid read too, `reach`),
        and the beam tail's near and far spreads (size 0: none); float32.
    lift : tuple
        ``((lower row, weight), (lower col, weight))`` of each fine cell on the coarse grid
        (`workers.fast.spread.Levels.lift`).
    lit : ndarray
        Share of each fine cell's light that the last output keeps (the gate's water the
        target leaves lit), float32 (size 0: all); the other outputs read all the light.
    weights : tuple of ndarray
        Per output, the factor on each pixel, float32.
    out : tuple of ndarray
        In and out: per output, each pixel's sum, float32; pixels off both grids add
        nothing.

    Notes
    -----
    The field is first assembled on the window, ``near + upsampled far`` (and that times
    `lit`), in float32 as `workers.fast.spread.Spread` does on the whole grid; the far
    part is interpolated along the columns once per fine row. Each line is located and
    read once for all outputs: every output gets the bytes a gather of its own would
    give (an image and its target-free twin in one pass).

    A line that misses the fine grid (a steep sea bends it past the guard band) reads
    the coarse level alone: the far spread plus the tail's far part, bilinearly at its
    coarse crossing (located as `splat_levels` locates a ray there), all its light kept
    (the target's shadow lies inside the fine grid). The near part is left out there:
    the near kernel decays within the guard band (`workers.fast.spread.NEAR_SUPPORT`), so
    beyond the fine grid the light of the fine level is all in the far part. What it
    misses is the near part of the light of rays that themselves landed off the fine
    grid (their unscattered share and scattered core), a part of the light a few
    guard-widths from the image that the coarse cells would blur anyway.
    """
    near, window, far, (tail_near, tail_far) = parts
    top, bottom, left, right = window
    (rl, rw), (cl, cw) = lift
    last = len(out) - 1
    field = np.empty((bottom - top, right - left), dtype=np.float32)
    kept = np.empty(field.shape if lit.size else (0, 0), dtype=np.float32)
    if top < bottom:
        first = cl[left]
        along = np.empty(cl[right - 1] + 2 - first, dtype=np.float32)
        # unsigned indices throughout, as `_unsigned`'s
        top_u, left_u, first_u = np.uint64(top), np.uint64(left), np.uint64(first)
        for r in range(top_u, np.uint64(bottom)):
            a, lower, upper = np.uint64(rl[r]), _ONE - rw[r], rw[r]
            for b in range(np.uint64(along.size)):
                f = first_u + b
                value = far[a, f] * lower + far[a + _NEXT, f] * upper
                if tail_far.size:
                    value += tail_far[a, f] * lower + tail_far[a + _NEXT, f] * upper
                along[b] = value
            for c in range(left_u, np.uint64(right)):
                b = np.uint64(cl[c] - first)
                value = near[r - top_u, c]
                if tail_near.size:
                    value += tail_near[r, c]
                value += along[b] * (_ONE - cw[c]) + along[b + _NEXT] * cw[c]
                field[r - top_u, c - left_u] = value
                if lit.size:
                    kept[r - top_u, c - left_u] = value * lit[r, c]
    rows, cols = shape
    base_u, slope_u, base_v, slope_v = lines
    for i in range(lines[0].size):
        row = _at(base_v, slope_v, i, cells.depth, cells.origin_v, cells.scale_v)
        col = _at(base_u, slope_u, i, cells.depth, cells.origin_u, cells.scale_u)
        r, c, down, right_share = _split(row, col, rows, cols)
        if r >= 0:
            total = _interpolate(field, r - top, c - left, down, right_share)
            for k in range(last):
                out[k][i] += total * weights[k][i]
            if lit.size:
                total = _interpolate(kept, r - top, c - left, down, right_share)
            out[last][i] += total * weights[last][i]
            continue
        row, col = _coarse(row, col, cells)
        r, c, down, right_share = _split(row, col, far.shape[0], far.shape[1])
        if r < 0:
            continue
        total = _interpolate(far, r, c, down, right_share)
        if tail_far.size:
            total += _interpolate(tail_far, r, c, down, right_share)
        for k in range(last + 1):
            out[k][i] += total * weights[k][i]


@numba.njit(cache=True, nogil=True)
def sample(lines, cells, fields, box, out):
    """Bilinear values of fine-grid fields where lines cross the plane (0 off the grid).

    Parameters
    ----------
    lines : tuple of ndarray
        ``(base_u, slope_u, base_v, slope_v)``, float32.
    cells : Cells
        The plane's map.
    fields : tuple of ndarray
        Fields on the fine grid, float32.
    box : tuple of int
        First row, last row + 1, first column, last column + 1 of the cells outside which
        every field is 0 (lines there are not looked up).
    out : ndarray, shape (len(fields), lines)
        Out: the values, float32 (summed as `workers.setup.geometry.PlaneGrid.gather` does).
    """
    rows, cols = fields[0].shape
    top, bottom, left, right = box
    for i in range(lines[0].size):
        r, c, down, right_share = _locate(lines, i, cells, rows, cols)
        if r < 0 or r + 1 < top or r >= bottom or c + 1 < left or c >= right:
            for k in range(len(fields)):
                out[k, i] = 0.0
            continue
        for k, field in enumerate(fields):
            out[k, i] = _interpolate(field, r, c, down, right_share)


@numba.njit(cache=True, nogil=True)
def bilinear_sum(grids, sizes, inverses, x, y, out):
    """Sum over periodic grids of their bilinear values at points, field by field.

    Parameters
    ----------
    grids : tuple of ndarray
        Per grid, its fields, shape (fields, (N + 1)²), float32: each an N × N periodic
        field with its first row and column repeated after the last, flattened.
    sizes : tuple of int
        N of each grid.
    inverses : tuple of float32
        1 / spacing of each grid [1/m].
    x, y : ndarray
        World coordinates of the points [m] (taken to float32 first).
    out : ndarray, shape (fields, points)
        Out: the sums, float32.

    Notes
    -----
    The arithmetic is that of `workers.sea.surface.Cascade.sample`, in float32 and in the
    same order, and the grids are added in turn as `workers.sea.surface.Surface` adds its
    cascades: the same bytes as the numpy formulation. One pass over the points per
    grid and field (a one-dimensional loop) is faster than one over the grids per point.
    """
    for g in range(len(grids)):
        for k in range(out.shape[0]):
            _bilinear(grids[g][k], sizes[g], inverses[g], x, y, out[k], g == 0)


@numba.njit(cache=True, nogil=True)
def _bilinear(field, n, inverse, x, y, out, first):
    """`bilinear_sum` of one field of one grid: into `out` if `first`, else added to it."""
    mask = n & (n - 1) == 0
    for i in range(x.size):
        tx = np.float32(x[i]) * inverse
        ty = np.float32(y[i]) * inverse
        column, row = np.floor(tx), np.floor(ty)
        tx -= column
        ty -= row
        c, r = int(column), int(row)
        if mask:
            c &= n - 1
            r &= n - 1
        else:
            c %= n
            r %= n
        low = r * (n + 1) + c
        high = low + n + 1
        lower = (field[low + 1] - field[low]) * tx + field[low]
        upper = (field[high + 1] - field[high]) * tx + field[high]
        value = (upper - lower) * ty + lower
        if first:
            out[i] = value
        else:
            out[i] += value


@numba.njit(cache=True, nogil=True)
def surface_hits(grids, sizes, inverses, rays, tolerance, iterations, travel, eta):
    """Rays' hits on the sum of periodic elevation grids, by fixed-point iteration from z = 0.

    Parameters
    ----------
    grids, sizes, inverses : tuple
        The elevation grids, as for `bilinear_sum` (one field each).
    rays : tuple of ndarray
        ``(ox, oy, oz, dx, dy, dz)``: the rays' origins [m] and directions [1], one value
        a ray (a shared origin broadcast, stride 0), all of one float dtype.
    tolerance : float32
        Largest height change [m] over all rays at which the iteration stops.
    iterations : int
        Most steps.
    travel : ndarray
        Out: each ray's parameter at its hit, ``(η − oz) / dz`` of the η before the last
        step, the rays' dtype.
    eta : ndarray
        Out: the elevation under ``o + travel·d`` [m], float32.

    Notes
    -----
    Start: ``travel = −oz/dz`` (z = 0), η the elevation under that point. A step sets
    ``travel = (η − oz)/dz`` and η to the elevation under ``o + travel·d``, for every ray;
    the steps stop after the first whose largest height change over all rays is below
    `tolerance`, or after `iterations`. The grids are summed with `bilinear_sum`'s loops
    and the rays' own arithmetic is in their dtype, as numpy does it: the same bytes as
    the steps written with numpy arrays, and as a fixed count of `iterations` steps that
    stops updating every ray once they have all converged (the torch twin). A step is
    a few passes over the rays, with no arrays made but three for the whole search.
    """
    ox, oy, oz, dx, dy, dz = rays
    x, y, heights = np.empty_like(travel), np.empty_like(travel), np.empty_like(eta)
    for i in range(dz.size):
        travel[i] = -oz[i] / dz[i]
        x[i] = ox[i] + travel[i] * dx[i]
        y[i] = oy[i] + travel[i] * dy[i]
    for g in range(len(grids)):
        _bilinear(grids[g][0], sizes[g], inverses[g], x, y, eta, g == 0)
    for _ in range(iterations):
        for i in range(dz.size):
            travel[i] = (eta[i] - oz[i]) / dz[i]
            x[i] = ox[i] + travel[i] * dx[i]
            y[i] = oy[i] + travel[i] * dy[i]
        for g in range(len(grids)):
            _bilinear(grids[g][0], sizes[g], inverses[g], x, y, heights, g == 0)
        largest = _ZERO  # NaN once any change is NaN, as numpy's max
        for i in range(dz.size):
            change = abs(heights[i] - eta[i])
            if change > largest or change != change:
                largest = change
            eta[i] = heights[i]
        if largest < tolerance:
            break


@numba.njit(cache=True)
def _mix(z):
    """SplitMix64's finaliser (Steele, Lea & Flood 2014) on a uint64."""
    z ^= z >> np.uint64(30)
    z *= _MIX_1
    z ^= z >> np.uint64(27)
    z *= _MIX_2
    z ^= z >> np.uint64(31)
    return z


@numba.njit(cache=True, nogil=True)
def cell_uniforms(x, y, inverse, key, frame, first, second):
    """Two uniform numbers in (0, 1) per point, a hash of its cell, the frame and a key.

    Parameters
    ----------
    x, y : ndarray
        World coordinates of the points [m].
    inverse : float32
        1 / cell size [1/m]; the cell of a point is (floor(y·inverse), floor(x·inverse)),
        in float32.
    key : uint64
        The seed's key.
    frame : uint64
        Frame index.
    first, second : ndarray
        Out: the numbers, float32, (k + 0.5)·2⁻²⁴ for 24-bit k.

    Notes
    -----
    The hash is SplitMix64's finaliser: w = mix(col·φ ⊕ mix(row + mix(key ⊕ frame·c))),
    with 64-bit wrapping arithmetic (φ the golden-ratio constant, c another odd constant);
    the first number takes w's top 24 bits, the second its low 24.
    """
    seed = _mix(key ^ (frame * _FRAME))
    scale = np.float32(2.0**-24)
    half = np.float32(0.5)
    for i in range(x.size):
        column = np.int64(np.floor(np.float32(x[i]) * inverse))
        row = np.int64(np.floor(np.float32(y[i]) * inverse))
        word = np.uint64(column) * _GOLDEN
        word ^= _mix(np.uint64(row) + seed)
        word = _mix(word)
        first[i] = (np.float32(word >> np.uint64(40)) + half) * scale
        second[i] = (np.float32(word & np.uint64(0xFFFFFF)) + half) * scale


@numba.njit(cache=True, nogil=True)
def column_convolution(kernel, rows, first, start, out):
    """Circular convolution along axis 0 of a few rows with a kernel, per column.

    ``out[o, k] += Σ_j kernel[(start + o − first − j) mod N, k] · rows[j, k]``, N the
    kernel's length along axis 0: the rows are rows ``first…`` of an N-row field that is
    zero elsewhere, `out` holds its rows ``start…`` of the convolution. The sum over j
    is taken in increasing order, in complex64.
    """
    n = kernel.shape[0]
    for o in range(out.shape[0]):
        for j in range(rows.shape[0]):
            lag = (start + o - first - j) % n
            for k in range(rows.shape[1]):
                out[o, k] += kernel[lag, k] * rows[j, k]
