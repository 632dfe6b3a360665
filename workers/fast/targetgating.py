"""The target's plane: what each gate holds of the target's cells as the sea lifts them.

`TargetGating` (built once per scene and frame by `workers.fast.planes.frame_geometry`) keeps,
per level of the target's plane, the cells the target covers, their lit reflectance and
each gate's depth bounds along their lines of sight, and gives each sample's
`TargetLight` for the gates' shift under its sea (`gate_shift`). The model is in
``docs/model.md`` §5 and §6.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field, replace

import numpy as np

from workers.backends.backend import Backend, moved
from workers.fast.delays import return_delays
from workers.fast.spread import Levels
from workers.setup.compiled import Setup
from workers.setup.geometry import PlaneGrid
from workers.setup.sensor import Sensor
from workers.targets.impostor import Impostor


@dataclass(frozen=True)
class TargetLight:
    """The target's reflectance maps per gate: gates cutting it alike share one map.

    Each map is a pair (fine, coarse); the coarse one holds the part of a large target
    outside the fine grid (None when the target lies within it). `rows` spans the fine
    rows where any map is non-zero.
    """

    weights: tuple[tuple[np.ndarray, np.ndarray | None], ...]
    gates: tuple[tuple[int, ...], ...]
    rows: slice

    def on(self, backend: Backend) -> TargetLight:
        """The maps on `backend` (itself on numpy)."""
        if backend.name == "numpy":
            return self
        return replace(self, weights=moved(self.weights, backend))


def _gated(setup, grid, impostor, top, bottom, *, delays, shares) -> np.ndarray:
    """Share of each cell's return a gate [top, bottom] holds, on time and late."""
    on = impostor.occupancy > 0
    held = setup.gated_share(grid, top, bottom, on=on, delays=delays, shares=shares)
    if held is None:
        depth = np.asarray(impostor.surface_depth, dtype=np.float64)
        held = sum(
            share * ((depth + delay >= top) & (depth + delay <= bottom) & on)
            for delay, share in zip(delays, shares, strict=True)
        )
    return held


SHIFT_STEP = 0.01
"""Step of the gate shifts at which a target's gated shares are computed [m]; a sample's
shift is interpolated linearly between the two nearest (`TargetGating.light`)."""


@dataclass(frozen=True, eq=False)
class TargetGating:
    r"""What each gate holds of the target's cells, for any shift of the gates' depths.

    Per level of the target's plane (the fine grid, and the coarse one where a large
    target reaches beyond it): the cells the target covers (`cells`, flat indices), their
    lit reflectance (`lit`: weight × the way up's and down's depth corrections, dense),
    and each gate's depth bounds along their flat-sea lines of sight (`bounds`, shape
    (gate, 2, cells)); the return's parts, on time and late (`delays`, `shares`).

    A sea raised by h over the target moves every gate's depths up by
    h (1 − cos ϑ_w / (n cos ϑ_a)) (`gate_shift`): the light's path in the air is shorter
    by h / cos ϑ_a and in the water longer by h / cos ϑ_w, n times slower. `light` gives
    the maps at such a shift, from shares computed at multiples of `SHIFT_STEP` (kept,
    once each) and interpolated between them.
    """

    setup: Setup
    grids: tuple[PlaneGrid, ...]
    impostors: tuple[Impostor, ...]
    lit: tuple[np.ndarray, ...]
    cells: tuple[np.ndarray, ...]
    bounds: tuple[np.ndarray, ...]
    delays: tuple[float, ...]
    shares: tuple[float, ...]
    _steps: dict = field(default_factory=dict, init=False, repr=False)

    @classmethod
    def build(cls, setup: Setup, sensor: Sensor, levels: Levels) -> TargetGating:
        r"""The target's gating on its plane `levels` for `sensor`'s gates.

        The target plane's light carries the attenuation of the plane through the
        target's centre; a cell whose line meets the target's surface at depth z_s
        (above the centre plane, on the lit cap) is reached by a path shorter by
        (z_c − z_s) sec ϑ each way, so its weight is multiplied by
        :math:`e^{K\sec\vartheta\,(z_c - z_s)}` for the way up, and for the way down
        by the beam's irradiance at z_s over its irradiance at z_c
        (`_beam_depth_ratio`, log-linear in depth between the sphere's top and centre).
        A gate holds the part of each cell's return whose path it holds: the sphere's
        annulus between the gate's depths on the cell's line
        (`workers.targets.impostor.gated_share`), its unscattered share on time and the rest late
        by the path stretch of its scatterings (`workers.fast.delays.return_delays`).
        """
        water = setup.water

        def lit(grid, impostor):
            rise = grid.depth - np.asarray(impostor.surface_depth, dtype=np.float64)
            lift = np.exp(water.diffuse_attenuation * setup.secant * rise)  # the way up
            radius = setup.target.radius
            if setup.target.shape == "sphere":
                ratio = _beam_depth_ratio(setup, sensor, grid, rise=min(radius, grid.depth))
                lift *= ratio ** np.clip(rise / radius, 0.0, 1.0)  # the way down
            return impostor.weight * lift

        fine_impostor = setup.impostor(levels.fine)
        coarse_impostor = setup.impostor(levels.coarse)
        outside = coarse_impostor.occupancy.copy()
        outside[levels.block] = 0.0
        chosen = [(levels.fine, fine_impostor)]
        if outside.any():
            chosen.append((levels.coarse, coarse_impostor))
        cells, bounds = [], []
        for grid, impostor in chosen:
            on = impostor.occupancy > 0
            if grid is levels.coarse:
                on[levels.block] = False
            flat = np.flatnonzero(on)
            sight = sensor.lines_of_sight(grid, flat)
            cells.append(flat)
            bounds.append(
                np.array([sensor.gate_bounds(sight, paths) for paths in sensor.paths]).reshape(
                    len(sensor.paths), 2, flat.size
                )
            )
        unscattered, delays = return_delays(
            water,
            path=levels.fine.depth * setup.secant,
            beam_radius=sensor.reference_range * np.tan(0.5 * sensor.laser_fov),
            target_radius=setup.target.radius,
        )
        return cls(
            setup=setup,
            grids=tuple(grid for grid, _ in chosen),
            impostors=tuple(impostor for _, impostor in chosen),
            lit=tuple(lit(grid, impostor) for grid, impostor in chosen),
            cells=tuple(cells),
            bounds=tuple(bounds),
            delays=(0.0, *delays),
            shares=(unscattered, *((1.0 - unscattered) / len(delays),) * len(delays)),
        )

    def _held(self, step: int) -> tuple[np.ndarray, ...]:
        """Per level, each gate's share of its cells' return, gates shallower by `step`.

        A gate that holds the whole target, or none of it, at every delay holds each
        cell's whole return (1, or 0 where it returns nothing), or none: only the gates
        whose depths cut it (one or two) are integrated.
        """
        if step not in self._steps:
            shift = step * SHIFT_STEP
            margin = self.setup.target.radius  # the cells' centre depths, oblique
            late = max(self.delays)
            held = []
            for level, (impostor, cells, bounds) in enumerate(
                zip(self.impostors, self.cells, self.bounds, strict=True)
            ):
                shares = np.zeros((bounds.shape[0], cells.size))
                for g, (top, bottom) in enumerate(bounds - shift):
                    shallowest, deepest = impostor.top - margin, impostor.bottom + margin
                    if bottom.max() <= shallowest or top.min() - late >= deepest:
                        continue
                    if top.max() <= shallowest and bottom.min() - late >= deepest:
                        shares[g] = self._whole[level]
                        continue
                    shares[g] = self._share(level, top, bottom)
                held.append(shares)
            self._steps[step] = tuple(held)
        return self._steps[step]

    @functools.cached_property
    def _whole(self) -> tuple[np.ndarray, ...]:
        """Per level, the share of its cells' return a gate holding all the target holds."""
        far = 1e6  # [m]
        return tuple(
            self._share(level, np.full(cells.size, -far), np.full(cells.size, far))
            for level, cells in enumerate(self.cells)
        )

    def _share(self, level: int, top, bottom) -> np.ndarray:
        """`_gated` on the cells of `level` between depths `top` and `bottom` [m]."""
        grid, cells = self.grids[level], self.cells[level]
        dense = [np.zeros(grid.shape), np.zeros(grid.shape)]
        dense[0].ravel()[cells] = top
        dense[1].ravel()[cells] = bottom
        share = _gated(
            self.setup,
            grid,
            self.impostors[level],
            *dense,
            delays=self.delays,
            shares=self.shares,
        )
        return share.ravel()[cells]

    def light(self, shift: float = 0.0) -> TargetLight:
        """The target's maps per gate, every gate's depths `shift` shallower [m].

        Gates whose maps are alike share one (`TargetLight`); the shares are interpolated
        linearly between the two nearest multiples of `SHIFT_STEP` (exact at 0).
        """
        position = shift / SHIFT_STEP
        step = int(np.floor(position))
        part = position - step
        held = self._held(step)
        if part > 0.0:
            held = tuple(
                (1.0 - part) * low + part * high
                for low, high in zip(held, self._held(step + 1), strict=True)
            )
        maps, members = {}, {}
        for g in range(self.bounds[0].shape[0]):
            pair, signature = [], b""
            for grid, weight, cells, shares in zip(
                self.grids, self.lit, self.cells, held, strict=True
            ):
                share = np.zeros(grid.shape)
                share.ravel()[cells] = np.clip(shares[g], 0.0, 1.0)
                pair.append((weight * share).astype(np.float32))
                signature += share.tobytes()
            if not any(m.any() for m in pair):
                continue
            if signature not in maps:
                maps[signature] = (pair[0], pair[1] if len(pair) > 1 else None)
                members[signature] = []
            members[signature].append(g)
        used = np.flatnonzero(sum((fine.any(axis=1) for fine, _ in maps.values()), start=False))
        return TargetLight(
            weights=tuple(maps.values()),
            gates=tuple(tuple(m) for m in members.values()),
            rows=slice(int(used[0]), int(used[-1]) + 1) if used.size else slice(0, 0),
        )


def gate_shift(setup: Setup, height: float) -> float:
    """How much shallower a sea raised by `height` [m] gates every depth [m] (float)."""
    cos_air = np.cos(setup.nadir)
    cos_water = np.cos(setup.refracted_nadir)
    return float(height * (1.0 - cos_water / (setup.water.refractive_index * cos_air)))


def _beam_depth_ratio(setup, sensor, grid: PlaneGrid, *, rise: float) -> np.ndarray:
    r"""The flat sea's beam irradiance `rise` above `grid`'s plane over that on it, per cell.

    The Gaussian beam (1/e radius a at the sea, growing as the rays diverge from the
    platform: a (1 + z sec ϑ / (n R₀)) at depth z, R₀ the slant range; constant for a
    parallel beam), each depth's profile blurred by its normalised one-way point-spread
    function (`workers.optics.water.WaterOptics.mtf`, zero-padded FFT) and attenuated by
    e^(−Kz sec ϑ): what the target's cells above its centre plane receive, relative to
    the plane's light, the same in every sample (the waves move the light, not its
    spread with depth). Cells are placed by their offset from the central ray.
    """
    water = setup.water
    n_w = water.refractive_index
    centre = sensor.central_point(grid.depth)
    x, y = grid.cell_centres()
    squared = (x - centre[0]) ** 2 + (y - centre[1]) ** 2
    radius = sensor.reference_range * np.tan(0.5 * sensor.laser_fov)
    light = []
    for depth in (grid.depth - rise, grid.depth):
        path = depth * setup.secant
        growth = 1.0 + path / (n_w * sensor.reference_range)
        width = radius * (growth if setup.beam == "divergent" else 1.0)
        profile = np.exp(-squared / width**2) * (radius / width) ** 2
        light.append(
            grid.convolved(
                profile, lambda f, path=path: water.mtf(f, distance=path).astype(np.float64)
            )
        )
    top, plane = light
    # where the beam's light is too faint for its FFT's ring (and off the beam), no change
    held = plane > 1e-6 * plane.max()
    ratio = np.divide(top, plane, out=np.ones(grid.shape), where=held)
    return np.maximum(ratio, 0.0)
