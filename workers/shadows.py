"""The target's shadow in a gate: the water it hides from the pixels and from the laser.

`gate_shadow` builds, once per scene, frame and gate (with `workers.planes.frame_geometry`),
two deficit maps: what the pixels' lines of sight lose where they cross the target's depth
(`seen`, on the target's plane, sampled at each pixel's line through the actual sea) and
what the laser's light loses on the gate's plane (`lit`, sampled where the pixel's line
crosses it). The model is in ``docs/model.md`` §6; it is held to photon transport by
``tests/test_transport_reference.py``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from workers.gates import hidden_fraction
from workers.geometry import PlaneGrid
from workers.sensor import central_point, gate_bounds, impostor_on, lines_of_sight, subgrid_sway

__all__ = ["gate_shadow"]

_LOG_STEP = 1e-3
"""Half-step in ln ψ of the central difference giving Σ(ψ) = D + dD/dln ψ."""


def gate_shadow(setup, sensor, *, gate_grid, target_grid, sight, paths):
    r"""The deficits of a gate's water behind the target: seen, and lit (None if none).

    Parameters
    ----------
    setup : workers.sensor.Setup
        The scene's setup.
    sensor : workers.sensor.Sensor
        The frame's sensor.
    gate_grid, target_grid : PlaneGrid
        The fine grids of the gate's plane and of the plane through the target's centre.
    sight : PlaneGrid
        The pixels' own grid at the target's depth (`workers.sensor.sight_grid`).
    paths : tuple of float
        The gate's opening and closing path lengths (`workers.sensor.Sensor.paths`) [m].

    Returns
    -------
    seen : ndarray or None
        On `sight`, the share of a pixel's view of the gate's water that the target
        stops, at the place where the pixel's line of sight crosses the target's depth [1].
    lit : ndarray or None
        On `gate_grid`, the share of the laser's light that the target keeps from the
        gate's water along the line of sight through each cell [1].

    Notes
    -----
    A line of sight through the target's silhouette loses the share h of the gate's
    single-scattering return lying behind the target's surface
    (`workers.gates.hidden_fraction`), h split as √(1 − h) between the way down and the
    way up (exact without scattering: the water behind is neither lit nor seen), so each
    way's deficit is δ = 1 − √(1 − h), taken over each cell's footprint (the target
    rasterised on the cell, `workers.target.Impostor`). Scattering moves light around the
    target, by small-angle transport: each path's lateral displacement is the sum of its
    scatterings' angles times their lever arms (Wells 1973), with the water's own phase
    function (`workers.water.WaterOptics.mtf_exponent` D and its angular transform
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

    Over a rough sea the slopes below the finest grid (`workers.sensor.subgrid_sway`)
    sway the lines: `seen` is read along the pixels' lines through the resolved sea,
    blurred by the sway over z_t; the laser's light, refracted by facets of its own,
    reaches the water behind the target from directions that sway the shadow over Δz,
    so `lit` is blurred by that too (and read along the pixel's line with its own
    sub-grid slope, as the gate's light is).

    The pixel keeps (1 − seen)(1 − lit) of the gate's light. The water's absorption and
    backscatter (K) act alike with and without the target, so only the shapes enter.
    Convolutions are linear (zero-padded FFTs) on each plane's fine grid.
    """
    water = setup.water
    seen = _deficit(setup, sensor, sight, paths, impostor_on(setup, sight))
    lit = _deficit(
        setup,
        sensor,
        gate_grid,
        paths,
        impostor_on(setup, _seen_through(sensor, gate_grid, target_grid, water.refractive_index)),
    )
    if not (seen.any() or lit.any()):
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

    return (
        _blurred(
            sight, seen, lambda f: one_way(f, z_t), sway=subgrid_sway(setup, sight, distance=z_t)
        ),
        _blurred(gate_grid, lit, behind, sway=subgrid_sway(setup, gate_grid, distance=drop)),
    )


def _seen_through(sensor, grid: PlaneGrid, target_grid: PlaneGrid, n_w: float) -> PlaneGrid:
    """`grid`'s cells where their flat-sea lines of sight cross the target's plane.

    Both grids hold one laser ray a cell about the central ray, so a cell's lines cross
    the target's plane in the cell at the same place of the lattice.
    """
    centre, centre_t = (central_point(sensor, g.depth, n_w) for g in (grid, target_grid))
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
    n_w = setup.water.refractive_index
    cells = np.flatnonzero(impostor.occupancy > 0)
    top, bottom = gate_bounds(lines_of_sight(sensor, grid, n_w, cells), paths, n_w)
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


def _blurred(grid: PlaneGrid, field: np.ndarray, exponent, *, sway=None) -> np.ndarray:
    """`field` convolved (linear, zero-padded) with the kernel of transfer e^exponent(f).

    And with the Gaussian of covariance `sway` (`PlaneGrid.convolved`) when given.
    """
    out = grid.convolved(field, lambda frequency: np.exp(exponent(frequency)), sway=sway)
    return np.clip(out, 0.0, 1.0).astype(np.float32)
