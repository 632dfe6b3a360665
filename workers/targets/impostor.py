"""The target as a 2.5-D impostor on a horizontal plane (paper §4.5).

A target is replaced by maps on the plane through its centre, indexed by where a line along
the mean in-water ray direction crosses that plane (each shape builds its own,
`workers.targets.base.TargetShape.impostor`):

- ``occupancy`` (0–1): the fraction of the cell whose line meets the target (its silhouette);
- ``weight``: the effective Lambertian reflectance the cell carries;
- ``surface_depth``: the depth at which that line first meets the target [m].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Impostor", "disc_cover", "gated_share", "offsets", "sphere_area_weights"]

_GAUSS_NODES, _GAUSS_WEIGHTS = np.polynomial.legendre.leggauss(8)


def sphere_area_weights(*, u, w, cell_u, cell_w, radius):
    r"""Area of the hemisphere above each rectangular cell (the paper's `ponder`).

    Parameters
    ----------
    u, w : ndarray
        Cell centres relative to the sphere centre, in a plane across the viewing direction
        [m].
    cell_u, cell_w : float
        Cell sizes along u and w [m].
    radius : float
        Sphere radius r [m].

    Returns
    -------
    ndarray
        Area of the hemisphere surface that projects onto each cell [m²]. Over a grid that
        covers the disk the sum is :math:`2\pi r^2`, up to the quadrature error in u at the
        two rim columns.

    Notes
    -----
    The paper approximates the area over cell :math:`[i, i+1]\times[j, j+1]` by
    :math:`R'R''\,|\Delta\arcsin(\cdot/R'')|\,|\Delta\arcsin(\cdot/R')|`, a product of two
    one-dimensional arcsine increments. We integrate exactly what it approximates,

    .. math:: A = \int_{u_1}^{u_2} r\left[\arcsin\frac{w}{\sqrt{r^2-u^2}}\right]_{w_1}^{w_2}du,

    with the arcsine argument clipped to [-1, 1] (the part of the cell outside the disk
    adds nothing) and an 8-point Gauss–Legendre rule in u. The integrand is bounded, so
    rim cells are accurate, where the raw density :math:`r/\sqrt{r^2-\rho^2}` is singular.

    References
    ----------
    Carmona, Cérou & Blasco (2000), §4.5, figures 10–12.
    """
    nodes = u[..., np.newaxis] + 0.5 * cell_u * _GAUSS_NODES
    half_chord = np.sqrt(np.clip(radius**2 - nodes**2, 0.0, None))
    safe = np.where(half_chord > 0, half_chord, 1.0)
    lower = np.clip((w[..., np.newaxis] - 0.5 * cell_w) / safe, -1.0, 1.0)
    upper = np.clip((w[..., np.newaxis] + 0.5 * cell_w) / safe, -1.0, 1.0)
    column = np.where(half_chord > 0, radius * (np.arcsin(upper) - np.arcsin(lower)), 0.0)
    return 0.5 * cell_u * column @ _GAUSS_WEIGHTS


def disc_cover(*, u, w, cell_u, cell_w, radius, within=None):
    r"""Share of each rectangular cell inside a disc, and the mean of cos i over the cell.

    Parameters
    ----------
    u, w : ndarray
        Cell centres relative to the disc's centre [m].
    cell_u, cell_w : float
        Cell sizes along u and w [m].
    radius : float
        Disc radius r [m].
    within : ndarray, optional
        Per cell, a radius R ≤ r [m]: both integrals are then taken over the part of
        the cell within R of the centre only (the cosine still the sphere's of radius r).

    Returns
    -------
    cover : ndarray
        :math:`rac{1}{|C|}\iint_C \mathbf{1}[u^2 + w^2 < r^2]\,du\,dw` [1].
    cosine : ndarray
        :math:`rac{1}{|C|}\iint_C \sqrt{1 - (u^2+w^2)/r^2}_+\,du\,dw` [1]: the cell's
        mean of the cosine between a sphere's normal and the viewing line, over the
        sphere's silhouette (the Lambertian return of the cell's share of the sphere).

    Notes
    -----
    Both are integrated exactly in w (the chord :math:`[-a, a]`, :math:`a = \sqrt{r^2 -
    u^2}`, clipped to the cell;
    :math:`\int\sqrt{a^2-w^2}dw = 	frac12(w\sqrt{a^2-w^2} + a^2rcsin(w/a))`) and by an
    8-point Gauss–Legendre rule in u, so a cell the size of the disc or larger gets the
    disc's area and return wherever the disc lies in it: a sub-pixel target neither
    vanishes nor turns dark.
    """
    u, w = np.broadcast_arrays(np.asarray(u, dtype=np.float64), np.asarray(w, dtype=np.float64))
    limit = np.broadcast_to(radius if within is None else np.asarray(within), u.shape)
    cover, cosine = np.zeros(u.shape), np.zeros(u.shape)
    near = (np.abs(u) < radius + cell_u) & (np.abs(w) < radius + cell_w)
    uc, wc, rc = u[near], w[near], np.clip(limit[near], 0.0, radius)
    start = np.maximum(uc - 0.5 * cell_u, -rc)
    stop = np.minimum(uc + 0.5 * cell_u, rc)
    span = np.clip(stop - start, 0.0, None)
    nodes = 0.5 * (start + stop)[:, np.newaxis] + 0.5 * span[:, np.newaxis] * _GAUSS_NODES
    half = np.sqrt(np.clip(radius**2 - nodes**2, 0.0, None))
    reach = np.sqrt(np.clip(rc[:, np.newaxis] ** 2 - nodes**2, 0.0, None))
    lower = np.clip(wc[:, np.newaxis] - 0.5 * cell_w, -reach, reach)
    upper = np.clip(wc[:, np.newaxis] + 0.5 * cell_w, -reach, reach)
    safe = np.where(half > 0, half, 1.0)

    def primitive(x):
        root = np.sqrt(np.clip(half**2 - x**2, 0.0, None))
        return 0.5 * (x * root + half**2 * np.arcsin(np.clip(x / safe, -1.0, 1.0)))

    size = cell_u * cell_w
    cover[near] = 0.5 * span * ((upper - lower) @ _GAUSS_WEIGHTS) / size
    lit = (primitive(upper) - primitive(lower)) / radius
    cosine[near] = 0.5 * span * (lit @ _GAUSS_WEIGHTS) / size
    return np.clip(cover, 0.0, 1.0), cosine


@dataclass(frozen=True)
class Impostor:
    """Target maps on the plane through the target's centre.

    Attributes
    ----------
    occupancy : ndarray
        Fraction of each cell inside the silhouette [1].
    weight : ndarray
        Effective Lambertian reflectance per cell [1]; radiance = weight·E/π with E the
        horizontal irradiance on the plane.
    surface_depth : ndarray
        Depth where the viewing line through the cell first meets the target [m]
        (meaningful where occupancy > 0).
    top, bottom : float
        Depth extent of the target [m].
    """

    occupancy: np.ndarray
    weight: np.ndarray
    surface_depth: np.ndarray
    top: float
    bottom: float


def offsets(grid, centre):
    """Each cell's offset from the target's centre, across and along its lines [m].

    Along the lines of sight is positive away from the platform.
    """
    x, y = grid.cell_centres()
    du = (x - centre[0]) * grid.axis_u[0] + (y - centre[1]) * grid.axis_u[1]
    along = -((x - centre[0]) * grid.axis_v[0] + (y - centre[1]) * grid.axis_v[1])
    return du, along


def gated_share(*, grid, centre, radius, refracted_nadir, top, bottom, on, delays, shares):
    r"""Share of each cell's Lambertian return from a sphere whose surface a gate holds.

    Parameters
    ----------
    grid : PlaneGrid
        Plane through the sphere's centre.
    centre : tuple of float
        World (x, y) of the sphere's centre [m].
    radius : float
        Sphere radius r [m].
    refracted_nadir : float
        Angle from the vertical of the lines of sight in the water [rad].
    top, bottom : ndarray
        Per cell, the depths its line of sight gates [m].
    on : ndarray of bool
        The cells to compute (the others are 0): those the sphere covers.
    delays, shares : sequence of float
        The return arrives in parts, share s_k as if from δ_k deeper
        (`workers.fast.delays.return_delays`; (0,), (1,) for the return on time) [m], [1].

    Returns
    -------
    ndarray
        Per cell, in [0, 1]: the cell's return from the part of the sphere whose surface
        depth plus δ_k lies in [top, bottom], summed over the parts with their shares,
        over the cell's whole return (0 off the sphere).

    Notes
    -----
    A line at distance ρ from the centre meets the sphere after the chord half-length
    :math:`q = \sqrt{r^2-\rho^2}`, at depth :math:`z_s = z_c - (a\sin\vartheta + q)
    \cos\vartheta` (a the cell's offset along the lines, ϑ the refracted nadir): the gate
    holds an annulus :math:`\rho \in [\sqrt{r^2-q_{hi}^2}, \sqrt{r^2-q_{lo}^2}]`, whose
    return (the cosine of incidence integrated over the cell, `disc_cover`) is taken
    exactly, not the cell centre's all or nothing: a gate edge through the sphere cuts
    its cells where the edge runs.
    """
    du, along = (values[on] for values in offsets(grid, centre))
    cos_t, sin_t = np.cos(refracted_nadir), np.sin(refracted_nadir)
    base = grid.depth - along * sin_t * cos_t
    cells = {
        "u": du,
        "w": along * cos_t,
        "cell_u": grid.spacing_u,
        "cell_w": grid.spacing_v * cos_t,
        "radius": radius,
    }

    _, whole = disc_cover(**cells)
    # a cell's nearest and farthest points from the centre: a disc of radius R holds all
    # of a cell with its farthest point inside, none with its nearest point outside
    reach_u, reach_w = (
        np.abs(cells[axis]) + 0.5 * cells[f"cell_{axis}"] * np.array([[-1.0], [1.0]])
        for axis in ("u", "w")
    )
    nearest = np.hypot(*(np.maximum(reach[0], 0.0) for reach in (reach_u, reach_w)))
    farthest = np.hypot(reach_u[1], reach_w[1])

    def held_within(depth):
        """Each cell's return from the disc of the sphere's points shallower than `depth`.

        `depth` is (depths, cells): every depth's cut cells in one `disc_cover`.
        """
        chord = np.clip((base - depth) / cos_t, 0.0, radius)
        limit = np.sqrt(radius**2 - chord**2)
        out = np.where(farthest <= limit, whole, 0.0)
        cut = (nearest < limit) & (farthest > limit)
        if cut.any():
            part = {
                key: np.broadcast_to(value, cut.shape)[cut] if np.ndim(value) else value
                for key, value in cells.items()
            }
            out[cut] = disc_cover(**part, within=limit[cut])[1]
        return out

    top, bottom = (np.asarray(v, dtype=np.float64)[on] for v in (top, bottom))
    delays = np.asarray(delays, dtype=np.float64)[:, np.newaxis]
    below, above = np.split(held_within(np.concatenate([bottom - delays, top - delays])), 2)
    held = np.zeros(whole.shape)
    for share, low, high in zip(shares, below, above, strict=True):
        held += share * (low - high)
    out = np.zeros(grid.shape)
    out[on] = np.clip(np.divide(held, whole, out=np.zeros(whole.shape), where=whole > 0), 0, 1)
    return out
