"""The target's shadow in a gate: the water it hides from the pixels and from the laser.

`gate_shadow` builds, once per scene, frame and gate (with `workers.fast.planes.frame_geometry`),
two deficit maps: what the pixels' lines of sight lose where they cross the target's depth
(`unseen`, on the target's plane, sampled at each pixel's line through the actual sea) and
what the laser's light loses on the gate's plane (`unlit`, sampled where the pixel's line
crosses it). The model is in ``docs/model.md`` §6; it is held to photon transport by
``tests/test_transport_reference.py``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from workers.setup.gates import hidden_fraction
from workers.setup.geometry import PlaneGrid

__all__ = ["gate_shadow"]

_LOG_STEP = 1e-3
"""Half-step in ln ψ of the central difference giving Σ(ψ) = D + dD/dln ψ."""


def gate_shadow(setup, sensor, *, gate_grid, target_grid, sight, paths):
    r"""The deficits of a gate's water behind the target: unseen, and unlit (None if none).

    Parameters
    ----------
    setup : workers.setup.compiled.Setup
        The scene's setup.
    sensor : workers.setup.sensor.Sensor
        The frame's sensor.
    gate_grid, target_grid : PlaneGrid
        The fine grids of the gate's plane and of the plane through the target's centre.
    sight : PlaneGrid
        The pixels' own grid at the target's depth (`workers.setup.sensor.Sensor.sight_grid`).
    paths : tuple of float
        The gate's opening and closing path lengths (`workers.setup.sensor.Sensor.paths`) [m].

    Returns
    -------
    unseen : ndarray or None
        On `sight`, the share of a pixel's view of the gate's water that the target
        stops, at the place where the pixel's line of sight crosses the target's depth [1]
        (over a rough sea, with the laser's light it stops: `_through_facets`).
    unlit : ndarray or None
        On `gate_grid`, the share of the laser's light that the target keeps from the
        gate's water along the line of sight through each cell [1] (None over a rough
        sea: in `unseen`).

    Notes
    -----
    A line of sight through the target's silhouette loses the share h of the gate's
    single-scattering return lying behind the target's surface
    (`workers.setup.gates.hidden_fraction`), h split as √(1 − h) between the way down and the
    way up (exact without scattering: the water behind is neither lit nor seen), so each
    way's deficit is δ = 1 − √(1 − h), taken over each cell's footprint (the target
    rasterised on the cell, `workers.targets.impostor.Impostor`). Scattering moves light around the
    target, by small-angle transport: each path's lateral displacement is the sum of its
    scatterings' angles times their lever arms (Wells 1973), with the water's own phase
    function (`workers.optics.water.WaterOptics.mtf_exponent` D and its angular transform
    Σ(ψ) = d(ψD)/dψ).

    - *Seen*: a pixel's line, traced back down, is displaced where it crosses the
      target's depth z_t by the scatterings above it: δ blurred by the normalised one-way
      MTF :math:`e^{b_f z_t (D(f z_t) - 1)}`.
    - *Lit*: the light the target stops at z_t is missing below it, displaced over
      Δz = z_g − z_t by the angle each path already had (the scatterings above z_t) and
      by the scatterings between: δ blurred by
      :math:`e^{b_f z_t (\Sigma(f\Delta z) - 1) + b_f \Delta z (D(f\Delta z) - 1)}`,
      read at the pixel's line. (Averaging it also over the pixel's view of the gate's
      plane, the one-way MTF to z_g, reads the coastal shadows of the transport
      references 0.1 shallower than transport; read at the line, they agree within
      0.06: ``docs/model.md`` §10.)

    The pixel keeps (1 − unseen)(1 − unlit) of the gate's light. Over a rough sea the slopes
    below the finest grid (`workers.setup.compiled.Setup.subgrid_sway`) sway the lines: the laser's
    light, refracted by facets of its own, reaches the water behind the target from
    directions that sway its shadow over Δz, so `unlit` is blurred by that; and the view
    of that water and the water itself move with the same facet of the pixel's view, at
    z_t and at z_g, so the kept share is the expectation of the product over that facet
    (`_through_facets`), returned as `unseen` and read along the pixels' lines through the
    resolved sea. The water's absorption and
    backscatter (K) act alike with and without the target, so only the shapes enter.
    Convolutions are linear (zero-padded FFTs) on each plane's fine grid.
    """
    water = setup.water
    unseen = _deficit(setup, sensor, sight, paths, setup.impostor(sight))
    unlit = _deficit(
        setup,
        sensor,
        gate_grid,
        paths,
        setup.impostor(_seen_through(sensor, gate_grid, target_grid)),
    )
    if not (unseen.any() or unlit.any()):
        return None, None
    z_t, drop = target_grid.depth, max(gate_grid.depth - target_grid.depth, 0.0)
    b_f = water.forward_scattering

    def one_way(f, distance):
        return b_f * distance * (water.mtf_exponent(f * distance) - 1.0)

    def behind(f):
        psi = f * drop
        steps = (water.mtf_exponent(psi * np.exp(s * _LOG_STEP)) for s in (1, -1))
        sigma = water.mtf_exponent(psi) + (next(steps) - next(steps)) / (2 * _LOG_STEP)
        return b_f * z_t * (sigma - 1.0) + one_way(f, drop)

    unseen = _blurred(sight, unseen, lambda f: one_way(f, z_t))
    unlit = _blurred(gate_grid, unlit, behind, sway=setup.subgrid_sway(gate_grid, distance=drop))
    unit = setup.subgrid_sway(sight, distance=1.0)
    if unit is None:
        return unseen, unlit
    through = _through_facets(sensor, sight, unseen, gate_grid, unlit, target_grid, sway=unit)
    return through, None


FACET_NODES = 8
"""Gauss–Hermite nodes per axis over a pixel's sub-grid facets (`_through_facets`)."""

NODE_FLOOR = 1e-4
"""Least weight of a node of the product rule kept (32 of the 64)."""

SHADOW_FLOOR = 1e-3
"""Deficit below which a cell's light is taken as whole (the blurs' FFT ring)."""


def _through_facets(sensor, sight, unseen, gate_grid, unlit, target_grid, *, sway) -> np.ndarray:
    r"""The share of a pixel's view of the gate's water the target stops, through facets.

    A pixel looks through many facets below the sea's grid; a facet of slope s moves its
    straight line in the water by :math:`\boldsymbol\delta = (1 - 1/n)\,d\,\mathbf s`
    at depth d (covariance d² `sway`). The gate's water at depth z_g seen through it lies
    at δ(z_g) from the pixel's line; the view to it is stopped where the same line
    crosses the target's depth, at δ(z_t), and the laser's light to it where that
    light's own line crosses it (`unlit`, read at the point). The pixel keeps
    :math:`E_s[(1 - B(\mathbf x + \boldsymbol\delta(z_t)))\,
    (1 - L(\mathbf x_g + \boldsymbol\delta(z_g)))]`, B the view's deficit on `sight`
    (`unseen`), L the light's on `gate_grid` (`unlit`), x and x_g the line's crossings of
    the two planes along the flat sea; the two deficits come through the same facet, so
    the expectation is taken of their product (a product of the two expectations reads
    the shadows 1.1–1.4 times too deep, `benchmarks.shadow_sway`). Returned on `sight`
    (1 − the kept share), to be read where the pixel's line crosses the target's depth.
    """
    nodes, weights = np.polynomial.hermite_e.hermegauss(FACET_NODES)
    weights = weights / weights.sum()
    zeta = np.stack(np.meshgrid(nodes, nodes, indexing="ij"), axis=-1).reshape(-1, 2)
    shares = np.outer(weights, weights).ravel()
    used = shares >= NODE_FLOOR  # the outermost nodes hold 8e-4 of the weight
    shares, zeta = shares[used] / shares[used].sum(), zeta[used]
    steps = zeta @ np.linalg.cholesky(sway).T  # (u, v) per metre of depth, per node
    axes = np.array([sight.axis_u, sight.axis_v])  # rows: u and v in world (x, y)
    x, y = sight.cell_centres()
    points = np.stack([x, y], axis=-1)
    window = _window(sight, unseen, gate_grid, unlit, points, np.abs(steps).max(axis=0))
    points = points[window]
    if not points.size:  # no deficit above the floor reaches the sight grid
        return np.zeros(sight.shape, dtype=np.float32)
    # the flat-sea lines through the sight grid's cells, where they cross the gate's plane
    # (as `_seen_through`: about the central ray, scaled by the planes' pitches)
    centre_t, centre_g = (sensor.central_point(g.depth) for g in (target_grid, gate_grid))
    scale = np.array(
        [
            gate_grid.spacing_u / target_grid.spacing_u,
            gate_grid.spacing_v / target_grid.spacing_v,
        ]
    )
    crossing = centre_g[:2] + (((points - centre_t[:2]) @ axes.T) * scale) @ axes
    # the grids share their axes: each cell's (row, col) on both, a row's the same along it
    on_sight = sight.cell_coordinates(points[..., 0], points[..., 1])
    on_gate = gate_grid.cell_coordinates(crossing[..., 0], crossing[..., 1])
    kept = np.zeros(points.shape[:2])
    for step, share in zip(steps, shares, strict=True):
        unseen_at = _read(unseen, on_sight, target_grid.depth * step, sight)
        unlit_at = _read(unlit, on_gate, gate_grid.depth * step, gate_grid)
        kept += share * (1.0 - unseen_at) * (1.0 - unlit_at)
    deficit = np.zeros(sight.shape, dtype=np.float32)
    deficit[window] = np.clip(1.0 - kept, 0.0, 1.0)
    return deficit


def _window(sight, unseen, gate_grid, unlit, points, reach) -> tuple[slice, slice]:
    """The cells of `sight` whose lines a facet can take to either deficit (the others: 0).

    `reach` is the largest displacement per metre of depth along u and v [m]; the light's
    deficit is placed on `sight` by its cells' world positions scaled about the grids'
    common centre (its plane is deeper: its lines spread more, so this holds it).
    """
    margin = gate_grid.depth * reach / np.array([sight.spacing_u, sight.spacing_v]) + 2
    rows, cols = [], []
    for grid, field in ((sight, unseen), (gate_grid, unlit)):
        held = np.argwhere(field > SHADOW_FLOOR)
        if held.size:
            x, y = grid.cell_centres()
            row, col = sight.cell_coordinates(x[tuple(held.T)], y[tuple(held.T)])
            rows += [row.min(), row.max()]
            cols += [col.min(), col.max()]
    if not rows:
        return slice(0, 0), slice(0, 0)
    first = np.floor([min(rows) - margin[1], min(cols) - margin[0]]).astype(int)
    last = np.ceil([max(rows) + margin[1], max(cols) + margin[0]]).astype(int) + 1
    first = np.maximum(first, 0)
    return slice(first[0], last[0]), slice(first[1], last[1])


def _seen_through(sensor, grid: PlaneGrid, target_grid: PlaneGrid) -> PlaneGrid:
    """`grid`'s cells where their flat-sea lines of sight cross the target's plane.

    Both grids hold one laser ray a cell about the central ray, so a cell's lines cross
    the target's plane in the cell at the same place of the lattice.
    """
    centre, centre_t = (sensor.central_point(g.depth) for g in (grid, target_grid))
    offset = np.subtract(grid.origin, centre)
    origin = centre_t
    for axis, ratio in (
        (grid.axis_u, target_grid.spacing_u / grid.spacing_u),
        (grid.axis_v, target_grid.spacing_v / grid.spacing_v),
    ):
        origin = origin + ratio * (offset @ axis) * np.asarray(axis)
    return replace(
        grid,
        depth=target_grid.depth,
        origin=(float(origin[0]), float(origin[1])),
        spacing_u=target_grid.spacing_u,
        spacing_v=target_grid.spacing_v,
    )


def _deficit(setup, sensor, grid: PlaneGrid, paths, impostor) -> np.ndarray:
    """δ = 1 − √(1 − h) per cell of `grid` (lines of sight through its cells)."""
    cells = np.flatnonzero(impostor.occupancy > 0)
    top, bottom = sensor.gate_bounds(sensor.lines_of_sight(grid, cells), paths)
    hidden = hidden_fraction(
        impostor.surface_depth.ravel()[cells],
        impostor.occupancy.ravel()[cells],
        top=top,
        bottom=bottom,
        diffuse_attenuation=setup.water.diffuse_attenuation * setup.secant,
    )
    deficit = np.zeros(grid.shape)
    deficit.ravel()[cells] = 1.0 - np.sqrt(np.maximum(1.0 - hidden.astype(np.float64), 0.0))
    return deficit


def _read(field: np.ndarray, cells, shift, grid: PlaneGrid) -> np.ndarray:
    """`field` on `grid` read bilinearly at its (row, col) `cells` moved by `shift` (u, v) [m].

    The rows of `cells` hold one row coordinate and its columns one column coordinate
    (the points lie on a grid of `grid`'s axes), so the read is separable: four gathers.
    Zero beyond the field.
    """
    padded = np.pad(field, 1)
    rows = _linear(cells[0][:, 0] + shift[1] / grid.spacing_v, field.shape[0])
    cols = _linear(cells[1][0, :] + shift[0] / grid.spacing_u, field.shape[1])
    total = np.zeros((rows[0][0].size, cols[0][0].size))
    for row, row_weight in rows:
        for col, col_weight in cols:
            total += row_weight[:, None] * col_weight[None, :] * padded[np.ix_(row, col)]
    return total


def _linear(position: np.ndarray, size: int) -> tuple:
    """The two (index, weight) pairs of a linear read at `position` of a zero-padded axis.

    Indices are into the axis padded by one zero on each side (its 0 and size + 1).
    """
    low = np.floor(position)
    part = position - low
    index = low.astype(int) + 1
    return (
        (np.clip(index, 0, size + 1), 1.0 - part),
        (np.clip(index + 1, 0, size + 1), part),
    )


def _blurred(grid: PlaneGrid, field: np.ndarray, exponent, *, sway=None) -> np.ndarray:
    """`field` convolved (linear, zero-padded) with the kernel of transfer e^exponent(f).

    And with the Gaussian of covariance `sway` (`PlaneGrid.convolved`) when given.
    """
    out = grid.convolved(field, lambda frequency: np.exp(exponent(frequency)), sway=sway)
    return np.clip(out, 0.0, 1.0).astype(np.float32)
