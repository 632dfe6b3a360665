"""Compiled loops of the render: rays splatted onto two-level planes, pixels gathered.

Each ray or pixel is located on a plane's fine grid from its in-water line
(`workers.interface.Projected`: ``base + z·slope`` along the plane's axes), in float32 with
the arithmetic of `workers.geometry.PlaneGrid.locate_cells`, and splatted or gathered in
the same pass: no index or weight arrays are built. A `Cells` holds the affine map of a
plane; the loops are compiled once by numba (cached on disk) and are sequential, so the
same inputs give the same bytes.
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

__all__ = ["Cells", "gather_levels", "span", "splat_levels"]

_ONE = np.float32(1.0)


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
    def of(cls, levels) -> Cells:
        """The map of a two-level plane (`workers.spread.Levels`)."""
        grid = levels.fine
        (o0, o1), (u0, u1), (v0, v1) = grid.origin, grid.axis_u, grid.axis_v
        shift_v, shift_u = levels.to_coarse(np.float32(0), np.float32(0))
        return cls(
            depth=np.float32(grid.depth),
            origin_u=np.float32(o0 * u0 + o1 * u1),
            scale_u=np.float32(1.0 / grid.spacing_u),
            origin_v=np.float32(o0 * v0 + o1 * v1),
            scale_v=np.float32(1.0 / grid.spacing_v),
            factor=np.float32(levels.factor),
            shift_v=np.float32(shift_v),
            shift_u=np.float32(shift_u),
        )


@numba.njit(cache=True)
def _at(base, slope, i, depth, origin, scale):
    """Fractional cell coordinate of line i on the plane (float32, as `Projected.cross`)."""
    t = slope[i] * depth
    t = t + base[i]
    t = t - origin
    return t * scale


@numba.njit(cache=True)
def _deposit(field, row, col, value):
    """Add `value` bilinearly at (row, col) of `field`; False (nothing added) outside."""
    rows, cols = field.shape
    r0 = np.floor(row)
    c0 = np.floor(col)
    if not (r0 >= 0 and r0 < rows - 1 and c0 >= 0 and c0 < cols - 1):
        return False
    r, c = int(r0), int(c0)
    down = row - r0
    right = col - c0
    left = _ONE - right
    w2 = left * down
    w3 = right * down
    field[r, c] += (left - w2) * value
    field[r, c + 1] += (right - w3) * value
    field[r + 1, c] += w2 * value
    field[r + 1, c + 1] += w3 * value
    return True


@numba.njit(cache=True, nogil=True)
def splat_levels(lines, power, cells, densities, tails, fine, source, block):
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
    tails : tuple of ndarray
        Light already on the fine and coarse grids (the beam's tail), float32.
    fine : ndarray
        Out: the fine field (tail plus rays), float32.
    source : ndarray
        Out: the coarse source of the far spread: block means of `fine` inside the fine
        region, the tail's and the rays' light outside it, float32.
    block : tuple of int
        Coarse (row, col) of the fine grid's first block.

    Notes
    -----
    Rays that miss the fine grid land on the coarse one; rays that miss both are dropped.
    Sums are taken in float64, as ``np.bincount`` does in `PlaneGrid.splat`.
    """
    base_u, slope_u, base_v, slope_v = lines
    fine_density, coarse_density = densities
    acc = np.zeros(fine.shape)
    outside = np.zeros(source.shape)
    for i in range(power.size):
        row = _at(base_v, slope_v, i, cells.depth, cells.origin_v, cells.scale_v)
        col = _at(base_u, slope_u, i, cells.depth, cells.origin_u, cells.scale_u)
        if not _deposit(acc, row, col, power[i] * fine_density):
            _deposit(
                outside,
                row / cells.factor + cells.shift_v,
                col / cells.factor + cells.shift_u,
                power[i] * coarse_density,
            )
    rows, cols = fine.shape
    for r in range(rows):
        for c in range(cols):
            fine[r, c] = np.float32(acc[r, c]) + tails[0][r, c]
    coarse_rows, coarse_cols = source.shape
    for r in range(coarse_rows):
        for c in range(coarse_cols):
            source[r, c] = np.float32(outside[r, c]) + tails[1][r, c]
    factor = int(cells.factor)
    share = 1.0 / (factor * factor)
    for br in range(rows // factor):
        for bc in range(cols // factor):
            total = 0.0
            for r in range(br * factor, (br + 1) * factor):
                for c in range(bc * factor, (bc + 1) * factor):
                    total += fine[r, c]
            source[block[0] + br, block[1] + bc] += np.float32(total * share)


@numba.njit(cache=True, nogil=True)
def span(lines, cells, shape):
    """The fine cells the lines' bilinear corners touch.

    Returns the first row, the last row + 1, the first column and the last column + 1
    (all 0 if no line meets the grid).
    """
    base_u, slope_u, base_v, slope_v = lines
    rows, cols = shape
    top, bottom, left, right = rows, 0, cols, 0
    for i in range(base_u.size):
        row = _at(base_v, slope_v, i, cells.depth, cells.origin_v, cells.scale_v)
        col = _at(base_u, slope_u, i, cells.depth, cells.origin_u, cells.scale_u)
        r0 = np.floor(row)
        c0 = np.floor(col)
        if r0 >= 0 and r0 < rows - 1 and c0 >= 0 and c0 < cols - 1:
            top = min(top, int(r0))
            bottom = max(bottom, int(r0) + 2)
            left = min(left, int(c0))
            right = max(right, int(c0) + 2)
    if top >= bottom:
        return 0, 0, 0, 0
    return top, bottom, left, right


@numba.njit(cache=True, nogil=True)
def gather_levels(lines, cells, shape, near, window, far, lift, occlusion, weight, out):
    """Add the spread field, bilinearly interpolated at each line's crossing, to `out`.

    Parameters
    ----------
    lines : tuple of ndarray
        ``(base_u, slope_u, base_v, slope_v)`` of the pixels' lines of sight, float32.
    cells : Cells
        The plane's map.
    shape : tuple of int
        The fine grid's shape.
    near : ndarray
        The near spread on the fine rows ``window[0]:window[1]``, float32.
    window : tuple of int
        The fine cells the lines reach (`span`).
    far : ndarray
        The far spread on the coarse grid, float32.
    lift : tuple
        ``((lower row, weight), (lower col, weight))`` of each fine cell on the coarse grid
        (`workers.spread.Levels.lift`).
    occlusion : ndarray
        Factor on each fine cell, float32 (size 0: none).
    weight : ndarray
        Factor on each pixel, float32.
    out : ndarray
        In and out: each pixel's sum, float32; pixels off the fine grid add nothing.

    Notes
    -----
    The field is first assembled on the window, ``near + upsampled far`` (times the
    occlusion), in float32 as `workers.spread.Spread` does on the whole grid.
    """
    top, bottom, left, right = window
    (rl, rw), (cl, cw) = lift
    field = np.empty((bottom - top, right - left), dtype=np.float32)
    for r in range(top, bottom):
        a, lower, upper = rl[r], _ONE - rw[r], rw[r]
        for c in range(left, right):
            b = cl[c]
            first = far[a, b] * lower + far[a + 1, b] * upper
            second = far[a, b + 1] * lower + far[a + 1, b + 1] * upper
            value = near[r - top, c] + (first * (_ONE - cw[c]) + second * cw[c])
            if occlusion.size:
                value *= occlusion[r, c]
            field[r - top, c - left] = value
    base_u, slope_u, base_v, slope_v = lines
    rows, cols = shape
    for i in range(base_u.size):
        row = _at(base_v, slope_v, i, cells.depth, cells.origin_v, cells.scale_v)
        col = _at(base_u, slope_u, i, cells.depth, cells.origin_u, cells.scale_u)
        r0 = np.floor(row)
        c0 = np.floor(col)
        if not (r0 >= 0 and r0 < rows - 1 and c0 >= 0 and c0 < cols - 1):
            continue
        r, c = int(r0) - top, int(c0) - left
        down = row - r0
        right_share = col - c0
        left_share = _ONE - right_share
        w2 = left_share * down
        w3 = right_share * down
        total = field[r, c] * (left_share - w2)
        total += field[r, c + 1] * (right_share - w3)
        total += field[r + 1, c] * w2
        total += field[r + 1, c + 1] * w3
        out[i] += total * weight[i]
