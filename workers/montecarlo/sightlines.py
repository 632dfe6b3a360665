"""The lines of sight in the water, bucketed by depth and place (numba).

The Monte Carlo renderer's local estimates (`workers.montecarlo.photons`) must find, for a point
in the
water, the pixels whose lines of sight through the rough surface hold it. The lines (through
the corners of S × S cells of each pixel, `workers.montecarlo.renderer`) are straight below the
surface; `build_lookup` lists, per horizontal slab and per square bucket of it, the cells
whose four lines' box over the slab meets the bucket, so that a point is tested against a
few cells only.

Conventions as `workers.montecarlo.photons`: the lines as a `workers.montecarlo.records.Rays`
of (PS + 1)² surface points x, y, z [m], downward unit directions, air paths [m] and
Fresnel transmittances.
"""

from __future__ import annotations

import numba
import numpy as np

from workers.montecarlo.records import LEAF, Buckets

__all__ = ["build_lookup", "corner_at"]


@numba.njit(**LEAF)
def corner_at(k, z, lines):
    """Corner line k at height z: (x, y, water length from the surface) [m]."""
    t = (z - lines.z[k]) / lines.dz[k]
    return lines.x[k] + t * lines.dx[k], lines.y[k] + t * lines.dy[k], t


@numba.njit(cache=True)
def _quad_box(lines, k00, side, za, zb):
    """Bounding box (x0, x1, y0, y1) of a pixel's four corner lines between two heights."""
    x0, x1, y0, y1 = np.inf, -np.inf, np.inf, -np.inf
    for k in (k00, k00 + 1, k00 + side, k00 + side + 1):
        for z in (za, zb):
            x, y, _ = corner_at(k, z, lines)
            x0, x1, y0, y1 = min(x0, x), max(x1, x), min(y0, y), max(y1, y)
    return x0, x1, y0, y1


@numba.njit(cache=True)
def _fill(lines, pixels, top, thick, buckets, counts, items, cursor, fill):
    """Count (`fill` False) or list (True) each slab's pixels in the buckets their boxes meet."""
    side = pixels + 1
    for s in range(buckets.x0.size):
        za, zb = top - s * thick, top - (s + 1) * thick
        gx0, gy0, size = buckets.x0[s], buckets.y0[s], buckets.size[s]
        nbx, first = buckets.across_x[s], buckets.first[s]
        for q in range(pixels * pixels):
            k00 = (q // pixels) * side + q % pixels
            x0, x1, y0, y1 = _quad_box(lines, k00, side, za, zb)
            for bj in range(int((y0 - gy0) / size), int((y1 - gy0) / size) + 1):
                for bi in range(int((x0 - gx0) / size), int((x1 - gx0) / size) + 1):
                    bucket = first + bj * nbx + bi
                    if fill:
                        items[cursor[bucket]] = q
                        cursor[bucket] += 1
                    else:
                        counts[bucket + 1] += 1


@numba.njit(cache=True)
def build_lookup(lines, pixels, top, thick, slabs):
    """Buckets of pixels per horizontal slab: which pixels' lines may hold a point.

    Parameters
    ----------
    lines : Rays
        The corner lines of sight, (pixels + 1)² (`workers.montecarlo.records.Rays`).
    pixels : int
        Pixels per side P.
    top : float
        Height of the first slab's top [m].
    thick : float
        Slab thickness [m].
    slabs : int
        Number of slabs.

    Returns
    -------
    buckets : Buckets
        Per slab: bucket grid origin x, y [m], bucket size [m] (the median pixel's box),
        buckets along x and y, and the index of its first bucket in `starts`
        (`workers.montecarlo.records.Buckets`).
    starts : ndarray
        Start of each bucket's pixels in `items` (one more entry at the end).
    items : ndarray
        Pixel indices (row · P + column), int32.
    """
    side = pixels + 1
    buckets = Buckets(
        np.zeros(slabs),
        np.zeros(slabs),
        np.zeros(slabs),
        np.zeros(slabs, dtype=np.int64),
        np.zeros(slabs, dtype=np.int64),
        np.zeros(slabs, dtype=np.int64),
    )
    widths = np.empty(pixels * pixels)
    total = 0
    for s in range(slabs):
        za, zb = top - s * thick, top - (s + 1) * thick
        gx0, gx1, gy0, gy1 = np.inf, -np.inf, np.inf, -np.inf
        for q in range(pixels * pixels):
            k00 = (q // pixels) * side + q % pixels
            x0, x1, y0, y1 = _quad_box(lines, k00, side, za, zb)
            gx0, gx1 = min(gx0, x0), max(gx1, x1)
            gy0, gy1 = min(gy0, y0), max(gy1, y1)
            widths[q] = max(x1 - x0, y1 - y0)
        # buckets a typical pixel's box wide, at most 4 a pixel along a side
        size = max(np.median(widths), max(gx1 - gx0, gy1 - gy0) / (4 * pixels))
        nbx = int((gx1 - gx0) / size) + 1
        nby = int((gy1 - gy0) / size) + 1
        buckets.x0[s], buckets.y0[s], buckets.size[s] = gx0, gy0, size
        buckets.across_x[s], buckets.across_y[s], buckets.first[s] = nbx, nby, total
        total += nbx * nby
    counts = np.zeros(total + 1, dtype=np.int64)
    items = np.empty(0, dtype=np.int32)
    _fill(lines, pixels, top, thick, buckets, counts, items, counts, False)
    for i in range(total):
        counts[i + 1] += counts[i]
    items = np.empty(counts[total], dtype=np.int32)
    cursor = counts[:-1].copy()
    _fill(lines, pixels, top, thick, buckets, counts, items, cursor, True)
    return buckets, counts, items
