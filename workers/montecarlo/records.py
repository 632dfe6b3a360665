"""The Monte Carlo kernels' records: named tuples numba takes, built by the renderer.

Each record holds what a packed float array held by position before: numba specialises
the kernels on the record's type (as `workers.backends.kernels.Cells`), so a field is read
by name at no cost. Arrays are float64 and C-contiguous (`as_rays`), as the kernels were
compiled for; integers are Python ints. World metres, z up (mean sea level z = 0).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = [
    "LEAF",
    "Buckets",
    "Gates",
    "Limits",
    "Lookup",
    "Medium",
    "Phase",
    "Point",
    "Rays",
    "Scenery",
    "Sea",
    "as_rays",
]


LEAF = {"cache": True, "_nrt": False}
"""numba options of the kernels' functions that allocate nothing and keep no array.

An array read out of a record is a new reference to numba's runtime (NRT): an atomic
increment and decrement each time, which the records made 3 times as many as the packed
arrays had (`_estimate`: 43 increments, was 13) and the transport 17 % slower over a flat
sea (coastal water, `benchmarks.transport`). Without the runtime in these functions the
arrays are borrowed, as arguments are: 392-405 000 photons/s, 354-373 000 before the
records (flat sea), 98-100 000 and 95-100 000 over a 5 m/s sea.
"""


class Rays(NamedTuple):
    """Straight rays in the water, one entry each (float64 arrays of one length).

    The pixels' lines of sight carry their Fresnel transmittance as `weight`; the photons
    at launch their raw power after it.
    """

    x: np.ndarray
    """Entry point on the surface, x [m]."""
    y: np.ndarray
    """Entry point, y [m]."""
    z: np.ndarray
    """Entry point, z (the surface's elevation there) [m]."""
    dx: np.ndarray
    """Unit direction in the water (down for the lines of sight), x [1]."""
    dy: np.ndarray
    """Unit direction, y [1]."""
    dz: np.ndarray
    """Unit direction, z [1]."""
    air: np.ndarray
    """Path in the air from the platform to the entry point [m]."""
    weight: np.ndarray
    """Lines: Fresnel transmittance [1]; photons: raw power after it."""


def as_rays(*, x, y, z, dx, dy, dz, air, weight) -> Rays:
    """A `Rays` of float64, C-contiguous copies of the given arrays (m, 1, raw power)."""
    values = (x, y, z, dx, dy, dz, air, weight)
    return Rays(*(np.ascontiguousarray(v, dtype=np.float64) for v in values))


class Medium(NamedTuple):
    """The water's optics and the blur of the slopes below the sea's grid."""

    refractive_index: float
    """n_w [1]."""
    attenuation: float
    """Beam attenuation c [1/m]."""
    absorption: float
    """Absorption a [1/m]."""
    scattering: float
    """Scattering b [1/m]."""
    blur_xx: float
    """The sub-grid slopes' covariance square root F, row-major [1] (0: none)."""
    blur_xy: float
    """F, first row, second column [1]."""
    blur_yx: float
    """F, second row, first column [1]."""
    blur_yy: float
    """F, second row, second column [1]."""
    blur_reach: float
    """1 − 1/n_w with sub-grid slopes, 0 without [1]."""


class Phase(NamedTuple):
    """The tabulated phase function (`workers.optics.phases.base.PhaseTable`), in logs."""

    log_theta0: float
    """ln of the table's first angle [ln rad]."""
    log_step: float
    """Step of ln θ between entries [1]."""
    log_values: np.ndarray
    """ln of the phase function at each angle [ln 1/sr]."""
    quantiles: np.ndarray
    """Scattering angles at equal steps of cumulative probability [rad]."""


class Limits(NamedTuple):
    """Where a photon's path stops counting, and the biasing shares."""

    longest: float
    """Longest round-trip optical path any gate holds [m]."""
    air_back: float
    """Least air path from the sea back to the receiver [m]."""
    lowest: float
    """Lowest surface elevation [m]."""
    highest: float
    """Highest surface elevation [m]."""
    most: int
    """Most scattering events along a path."""
    bias: float
    """Share of scatterings drawn about the way to the receiver [1]."""
    reflection_bias: float
    """Share of reflections off the target drawn about the way to the receiver [1]."""


class Sea(NamedTuple):
    """The sea's stored elevation grid: nodes at (x0 + i·spacing, y0 + j·spacing)."""

    elevation: np.ndarray
    """Elevation η, shape (size, size), index order (y, x) [m]."""
    x0: float
    """First node's x [m]."""
    y0: float
    """First node's y [m]."""
    spacing: float
    """Node spacing [m]."""
    size: int
    """Nodes along a side; 0: a flat sea."""


class Buckets(NamedTuple):
    """Per horizontal slab of the lines' lookup, its grid of square buckets."""

    x0: np.ndarray
    """Bucket grid origin x [m], one per slab (float64)."""
    y0: np.ndarray
    """Bucket grid origin y [m]."""
    size: np.ndarray
    """Bucket side [m]."""
    across_x: np.ndarray
    """Buckets along x (int64)."""
    across_y: np.ndarray
    """Buckets along y (int64)."""
    first: np.ndarray
    """Index of the slab's first bucket in `Lookup.starts` (int64)."""


class Lookup(NamedTuple):
    """Which cells' lines of sight may hold a point (`workers.montecarlo.sightlines`)."""

    top: float
    """Height of the first slab's top [m]."""
    thick: float
    """Slab thickness [m]."""
    slabs: int
    """Number of slabs."""
    subdivision: int
    """Cells per pixel side S."""
    buckets: Buckets
    """The slabs' bucket grids."""
    starts: np.ndarray
    """Start of each bucket's cells in `items` (one more entry at the end), int64."""
    items: np.ndarray
    """Cell indices (row · PS + column), int32."""


class Gates(NamedTuple):
    """Round-trip optical path at which each gate opens and closes [m] (float64)."""

    opens: np.ndarray
    closes: np.ndarray


class Point(NamedTuple):
    """A point in the world [m]."""

    x: float
    y: float
    z: float


class Scenery(NamedTuple):
    """What a frame's photons travel through and are seen by, the target apart."""

    medium: Medium
    phase: Phase
    limits: Limits
    camera: Point
    """The receiver's pinhole."""
    sea: Sea
    lines: Rays
    """The pixels' corner lines of sight, (PS + 1)², row-major."""
    lookup: Lookup
    gates: Gates
