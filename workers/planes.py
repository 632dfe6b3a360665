"""The in-water planes of a frame: two-level grids, spreads, beam tail, target maps, hiding.

`frame_geometry` builds them once per scene and frame (cached); every sample
`workers.render.render` draws reuses them. The model is in ``docs/model.md``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field, replace

import numpy as np

from workers.backend import Backend
from workers.caches import lru_bytes
from workers.delays import return_delays
from workers.geometry import LaserRays, Located, PlaneGrid, flat_sea_point
from workers.interface import ray_components
from workers.kernels import Cells
from workers.optics import fresnel_reflectance
from workers.scene import Scene
from workers.sensor import (
    Sensor,
    Setup,
    central_point,
    fine_grid,
    gate_bounds,
    gated_share_on,
    impostor_on,
    lines_of_sight,
    scene_setup,
    sensor_at,
    sight_grid,
    subgrid_sway,
)
from workers.shadows import gate_shadow
from workers.spread import (
    NEAR_SUPPORT,
    SPREAD_FRACTION,
    Levels,
    Spread,
    coarse_factor,
    encircled_radius,
)
from workers.target import Impostor

GUARD = 0.125
"""Least guard band on each side of an in-water plane, as a fraction of the image size."""

BEAM_EXTENT = 2.5
"""Half-width of the traced beam in units of its 1/e radius (e^-6.25: 0.2 % lies beyond)."""

TAIL_STEP = 2
"""Pitch of the beam tail's lattice, in laser-lattice steps (1 for an odd lattice, so the
tail's cells end where the traced lattice's begin)."""

SWAY_FLOOR = 1e-4
"""Share of a pixel's view below which the swayed silhouette is none (the FFT's ring)."""

LATTICE_MARGIN = 8
"""Laser rays traced through the wavy surface beyond the field, on each side."""


@dataclass(frozen=True)
class Plane:
    """An in-water plane: its two-level grid, spread, and the beam tail's light on it.

    `tail` is the light of the beam's tail (which crosses the mean sea, the same in every
    sample) already spread: ``(near, far, outside)`` as from `Spread.filtered`, with
    `outside` only on the target's plane. For a gate, `spread` is the round trip (the
    slab's reflectance times MTF²); where the target hides part of the gate's water
    (`workers.shadows.gate_shadow`), `occlusion` is the share of the laser's light the
    gate's water keeps, per cell of this fine grid, and `seen` the share of a pixel's view
    the target stops, per cell of the target plane's fine grid: a pixel keeps
    (1 − seen)·occlusion, each read where its line of sight crosses the plane.
    """

    levels: Levels
    spread: Spread
    tail: tuple[np.ndarray, np.ndarray, np.ndarray | None] | None
    occlusion: np.ndarray | None = None
    seen: np.ndarray | None = None

    @property
    def grid(self) -> PlaneGrid:
        """The fine grid."""
        return self.levels.fine

    def on(self, backend: Backend) -> Plane:
        """The plane with its fields and spread on `backend` (itself on numpy)."""
        if backend.name == "numpy":
            return self
        return replace(
            self,
            levels=self.levels.on(backend),
            spread=self.spread.on(backend),
            tail=_moved(self.tail, backend),
            occlusion=_moved(self.occlusion, backend),
            seen=_moved(self.seen, backend),
        )


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
        return replace(self, weights=_moved(self.weights, backend))


@dataclass(frozen=True)
class Resample:
    """Bilinear resampling of a plane's fields onto a grid of the same axes and depth.

    `fine` and `coarse` each hold a pair of matrices (rows, columns), float32: a field
    ``f`` on the source level reads ``rows @ f @ columns.T`` on the target level (zero
    beyond the source grid). `first` and `last` hold, per target fine row, the first and
    last + 1 source fine rows it reads.
    """

    fine: tuple[np.ndarray, np.ndarray]
    coarse: tuple[np.ndarray, np.ndarray]
    first: tuple[int, ...]
    last: tuple[int, ...]

    @classmethod
    def between(cls, source: Levels, target: Levels) -> Resample:
        """The resampling from `source`'s levels onto `target`'s."""
        fine = _interpolation(source.fine, target.fine)
        rows = fine[0] > 0
        first = np.argmax(rows, axis=1)
        last = rows.shape[1] - np.argmax(rows[:, ::-1], axis=1)
        last = np.where(rows.any(axis=1), last, first)
        return cls(
            fine=fine,
            coarse=_interpolation(source.coarse, target.coarse),
            first=tuple(int(f) for f in first),
            last=tuple(int(f) for f in last),
        )

    def source_rows(self, rows: slice) -> slice:
        """The source fine rows that the target fine `rows` read."""
        if rows.start >= rows.stop:
            return slice(0, 0)
        return slice(min(self.first[rows]), max(self.last[rows]))

    def on(self, backend: Backend) -> Resample:
        """The matrices on `backend` (itself on numpy)."""
        if backend.name == "numpy":
            return self
        return replace(self, fine=_moved(self.fine, backend), coarse=_moved(self.coarse, backend))


def _interpolation(source: PlaneGrid, target: PlaneGrid) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation matrices (rows, columns) from `source`'s nodes to `target`'s."""
    offset = np.asarray(target.origin) - np.asarray(source.origin)
    matrices = []
    for axis, size, spacing, count, step in (
        (target.axis_v, target.shape[0], target.spacing_v, source.shape[0], source.spacing_v),
        (target.axis_u, target.shape[1], target.spacing_u, source.shape[1], source.spacing_u),
    ):
        position = (offset @ np.asarray(axis) + np.arange(size) * spacing) / step
        low = np.floor(position).astype(int)
        part = position - low
        matrix = np.zeros((size, count))
        for node, weight in ((low, 1.0 - part), (low + 1, part)):
            inside = (node >= 0) & (node < count)
            matrix[np.flatnonzero(inside), node[inside]] += weight[inside]
        matrices.append(matrix.astype(np.float32))
    return matrices[0], matrices[1]


def _moved(values, backend: Backend):
    """Host arrays (nested in tuples; None kept) as arrays of `backend`; numbers as floats."""
    if values is None:
        return None
    if isinstance(values, tuple):
        return tuple(_moved(v, backend) for v in values)
    if np.ndim(values) == 0:  # a ray origin shared by every ray: a float32 value
        return float(values)
    return backend.asarray(values)


@dataclass(frozen=True)
class FrameGeometry:
    """Geometry of one frame: sensor rays, planes, filters and the target impostor.

    With a target, `sight` is the pixels' own grid at its depth (`workers.sensor.sight_grid`)
    and `sight_occupancy` the target's silhouette on it: each pixel's share, for its mask;
    `sight_support` the first row, last row + 1, first column and last column + 1 of its
    non-zero cells. `target_light` is the target's maps under the flat sea,
    `target_gating` what makes them at any height of the sea over the target.

    `target_plane` is lit by the laser's lattice; the target's maps, and its light's way
    up (`target_rise`: its spread with the sub-grid slopes' sway of the lines of sight,
    `workers.sensor.subgrid_sway`), are on the plane's grid at the pixels' pitch, the
    default lattice's, whatever `laser.rays`: `resample` carries the light from the one
    to the other (None where they are the same grid).
    """

    position: np.ndarray
    central_air: float
    pixel_rays: tuple
    laser_rays: tuple
    laser_power: np.ndarray
    gate_planes: tuple[Plane, ...]
    target_plane: Plane | None
    impostor: Impostor | None
    target_light: TargetLight | None
    target_gating: TargetGating | None = None
    target_rise: Plane | None = None
    resample: Resample | None = None
    sight: PlaneGrid | None = None
    sight_occupancy: np.ndarray | None = None
    sight_support: tuple[int, int, int, int] = (0, 0, 0, 0)
    _on: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @property
    def sight_cells(self) -> Cells:
        """`workers.kernels.Cells` of `sight`: the pixels' own grid at the target's depth."""
        return Cells.of_grid(self.sight)

    def on(self, backend: Backend) -> FrameGeometry:
        """The geometry with what a sample reads on `backend` (cached; itself on numpy).

        The rays, the laser's power, the planes (their spreads, tail, occlusion) and the
        target's maps are moved once; the host's geometry keeps the moved copy while it
        is cached (`frame_geometry`).
        """
        if backend.name == "numpy":
            return self
        if backend not in self._on:
            light = self.target_light
            if light is not None:
                light = light.on(backend)
            self._on[backend] = replace(
                self,
                pixel_rays=_moved(self.pixel_rays, backend),
                laser_rays=_moved(self.laser_rays, backend),
                laser_power=backend.asarray(self.laser_power),
                gate_planes=tuple(plane.on(backend) for plane in self.gate_planes),
                target_plane=None if self.target_plane is None else self.target_plane.on(backend),
                target_rise=None if self.target_rise is None else self.target_rise.on(backend),
                resample=None if self.resample is None else self.resample.on(backend),
                target_light=light,
                sight_occupancy=_moved(self.sight_occupancy, backend),
            )
        return self._on[backend]


def read_blur(scene: Scene, sensor: Sensor, grid: PlaneGrid, *, uses: int) -> tuple[float, float]:
    r"""The Gaussian a plane's spread adds so that light is read at one scale [m] (u, v).

    Parameters
    ----------
    scene : Scene
        The scene (its receiver's aperture, water index, altitude).
    sensor : Sensor
        The frame's sensor (pixel and ray pitches).
    grid : PlaneGrid
        The plane's fine grid, one ray a cell under a flat sea.
    uses : int
        How many times a ray's light passes the plane's filter between splat and gather
        (1 for a gate's round trip, 2 for the target's plane, spread down and up).

    Returns
    -------
    tuple of float
        Standard deviation along u and v of the Gaussian each use adds [m].

    Notes
    -----
    A pixel reads the light splatted bilinearly from the rays and gathered bilinearly at
    its line of sight: a kernel of variance :math:`h^2/3` per axis, h the ray pitch on
    the plane. Over a rough sea, what a pixel reads of the light that came down through
    the part of the sea it looks through (the double passage) depends on that scale. It
    is held at :math:`\max(p^2/3, D^2/16)`, p the pixel pitch on the plane (the default
    lattice's h) and D the receiver's aperture projected to the plane's depth z,
    :math:`D_r (z/n)/(H + z/n)` (a disc's variance), whatever the ray count: finer
    lattices add the difference as a Gaussian, so that their images converge to the
    same light (docs/model.md §3). The aperture's scale, the physical one, is resolved
    only by lattices finer than it (2–4 times the default rays at 34 m).
    """
    ratio = (np.tan(0.5 * sensor.camera.field_of_view) / sensor.camera.pixels) / (
        np.tan(0.5 * sensor.laser_fov) / sensor.laser_rays
    )
    depth = grid.depth / scene.water.refractive_index
    aperture = scene.radiometry.receiver_aperture * depth / (sensor.position[2] + depth)
    blur = []
    for h in (grid.spacing_u, grid.spacing_v):
        scale = max((ratio * h) ** 2 / 3.0, aperture**2 / 16.0)
        blur.append(float(np.sqrt(max(scale - h**2 / 3.0, 0.0) / uses)))
    return blur[0], blur[1]


def _plane_levels(
    setup: Setup, sensor: Sensor, depth: float, passes: int, *, reach: float = 0.0
) -> tuple[Levels, int]:
    """The two-level grid of a plane, and its fine guard band [cells].

    The coarse margin holds `SPREAD_FRACTION` of the scattered light one way, twice that
    radius for a round trip (two independent spreads); the guard band is at least `reach`
    [m] wide.
    """
    n_w = setup.water.refractive_index
    bare = fine_grid(sensor, depth, n_w, guard=0, multiple=1)
    spacing = min(bare.spacing_u, bare.spacing_v)
    margin = passes * encircled_radius(setup.water, distance=depth, fraction=SPREAD_FRACTION)
    span = max(bare.shape) * spacing
    factor = coarse_factor(spacing=spacing, extent=span + 2 * margin)
    guard = max(
        int(np.ceil(GUARD * sensor.camera.pixels)),
        NEAR_SUPPORT * factor,
        int(np.ceil(reach / spacing)),
    )
    fine = fine_grid(sensor, depth, n_w, guard=guard, multiple=factor)
    return Levels.around(fine, factor=factor, margin=margin), guard


def _beam_tail(setup: Setup, sensor: Sensor, levels: Levels, tail: LaserRays, gate=None):
    """The beam tail's irradiance on the fine and coarse grids under the mean (flat) sea.

    For a gate's plane (`gate` its index), each ray carries the gate's timing
    (`gate_gain`) in place of its own path's attenuation.
    """
    if tail.power.size == 0:
        return None
    water, grid = setup.water, levels.coarse
    n_w = water.refractive_index
    points = flat_sea_point(
        origin=tail.origins, direction=tail.directions, depth=grid.depth, refractive_index=n_w
    )
    cos_air = np.clip(-tail.directions[:, 2], 0.0, 1.0)
    cos_water = np.sqrt(1.0 - (1.0 - cos_air**2) / n_w**2)
    transmittance = 1.0 - fresnel_reflectance(cos_air, n1=1.0, n2=n_w)
    if gate is None:
        extra = np.exp(-water.diffuse_attenuation * grid.depth * (1.0 / cos_water - 1.0))
    else:
        air = -(tail.origins[:, 2]) / tail.directions[:, 2]
        extra = setup.gate_gain(air - sensor.central_air, gate)
    power = (tail.power * transmittance * extra).astype(np.float32)
    # rays landing on the fine grid go there (their near spread is the fine grid's); the
    # others on the coarse grid
    fine = levels.fine.locate(points[:, 0], points[:, 1])
    inside = fine.weights.sum(axis=0) > 0
    outside = ~inside
    coarse = grid.locate(points[outside, 0], points[outside, 1])
    return (
        levels.fine.splat(
            Located(fine.corners[:, inside], fine.weights[:, inside]), power[inside]
        ),
        grid.splat(coarse, power[outside]),
    )


GEOMETRY_BYTES = 1 << 30
"""Most bytes of frame geometries a worker process keeps [bytes]. A 128-pixel frame holds
about 4 MB, a 512-pixel one about 90 MB: every frame of a 26-frame sequence stays cached up
to 256 pixels (rebuilding them made each sample of the paper's example 1 twenty times
slower), and a sweep over many scenes does not hold a gigabyte per scene it has met."""


@lru_bytes(GEOMETRY_BYTES)
def frame_geometry(scene: Scene, frame: int) -> FrameGeometry:
    """Sensor rays, planes, filters and target maps of `frame` (cached by scene and frame)."""
    setup = scene_setup(scene)
    water = setup.water
    sensor = sensor_at(setup, frame)
    camera = sensor.camera
    t = scene.target
    depths = ([t.depth] if t.shape != "none" else []) + list(setup.reference_depths)
    passes = ([1] if t.shape != "none" else []) + [2] * len(setup.gates)
    built = [
        _plane_levels(setup, sensor, depth, count)
        for depth, count in zip(depths, passes, strict=True)
    ]
    # the target's maps and its light's way up on the default lattice's grid (the pixels'
    # pitch), lit from the laser's lattice on a grid reaching beyond it
    sight_sensor, rise_levels = sensor, None
    if t.shape != "none":
        if sensor.laser_rays != scene.pixel_pitch_rays:
            sight_sensor = sensor_at(setup, frame, rays=scene.pixel_pitch_rays)
        rise_levels, guard = _plane_levels(setup, sight_sensor, t.depth, 1)
        if sight_sensor is sensor:
            rise_levels = built[0][0]
        else:
            fine = rise_levels.fine
            reach = (guard + 1) * max(fine.spacing_u, fine.spacing_v)
            built[0] = _plane_levels(setup, sensor, t.depth, 1, reach=reach)
    # the traced lattice reaches LATTICE_MARGIN rays beyond the field; the beam's tail
    # beyond it crosses the mean sea (within the beam's extent). The lattice is offset
    # from the pixels' lines of sight (`workers.sensor.lattice_offset`).
    rays = sensor.laser_rays
    margin = min(LATTICE_MARGIN, int(np.ceil(0.5 * (BEAM_EXTENT - 1.0) * rays)))
    laser = LaserRays.from_platform(
        position=sensor.position,
        rotation=camera.rotation,
        beam=scene.laser.beam,
        field_of_view=sensor.laser_fov,
        rays=rays,
        reference_range=sensor.reference_range,
        margin=margin,
        offset=sensor.offset,
    )
    step = 2.0 * np.tan(0.5 * sensor.laser_fov) / rays
    tail = LaserRays.beam_tail(
        position=sensor.position,
        rotation=camera.rotation,
        beam=scene.laser.beam,
        field_of_view=sensor.laser_fov,
        reference_range=sensor.reference_range,
        inner=(0.5 * rays + margin) * step,
        step=(TAIL_STEP if rays % 2 == 0 else 1) * step,
        extent=BEAM_EXTENT,
        centre=sensor.offset * step,
    )

    gains = ([1.0] if t.shape != "none" else []) + list(setup.reflectances)
    gate_index = ([None] if t.shape != "none" else []) + list(range(len(setup.gates)))
    planes = []
    for (levels, _), depth, count, gain, gate in zip(
        built, depths, passes, gains, gate_index, strict=True
    ):
        # a gate's round trip is one filter; the target's plane spreads down and up, read
        # at the pixels' pitch
        blur = (
            read_blur(scene, sensor, levels.fine, uses=1)
            if gate is not None
            else read_blur(scene, sight_sensor, rise_levels.fine, uses=2)
        )
        spread = Spread.build(
            water=water,
            levels=levels,
            distance=depth,
            truncation=scene.water.psf_truncation,
            passes=count,
            gain=gain,
            blur=blur,
        )
        light = _beam_tail(setup, sensor, levels, tail, gate)
        if light is not None:
            fine, coarse = light
            source = levels.downsample(fine) + coarse
            light = spread.filtered(fine, source, far_out=gate is None)
        planes.append(Plane(levels=levels, spread=spread, tail=light))
    target_plane = target_rise = resample = None
    impostor = target_light = gating = sight = sight_occupancy = None
    sight_support = (0, 0, 0, 0)
    if t.shape != "none":
        target_plane, planes = planes[0], planes[1:]
        rise = target_plane.spread  # the target's light's way up
        sway = subgrid_sway(setup, rise_levels.fine, distance=t.depth)
        if sway is not None or rise_levels is not target_plane.levels:
            rise = Spread.build(
                water=water,
                levels=rise_levels,
                distance=t.depth,
                truncation=scene.water.psf_truncation,
                blur=read_blur(scene, sight_sensor, rise_levels.fine, uses=2),
                sway=sway,
            )
        target_rise = Plane(levels=rise_levels, spread=rise, tail=None)
        if rise_levels is not target_plane.levels:
            resample = Resample.between(target_plane.levels, rise_levels)
        impostor = impostor_on(setup, rise_levels.fine)
        gating = TargetGating.build(setup, sight_sensor, rise_levels)
        target_light = gating.light()
        guard = max(int(np.ceil(GUARD * camera.pixels)), 1)
        sight = sight_grid(sensor, t.depth, water.refractive_index, guard=guard)
        sway = subgrid_sway(setup, sight, distance=t.depth)
        sight_occupancy = impostor_on(setup, sight).occupancy
        if sway is not None:  # each pixel's share, as the sub-grid slopes sway its view
            swayed = sight.convolved(sight_occupancy, np.ones_like, sway=sway)
            sight_occupancy = np.where(swayed > SWAY_FLOOR, np.minimum(swayed, 1.0), 0.0)
        sight_occupancy = sight_occupancy.astype(np.float32)
        sight_support = _support(sight_occupancy)
    gate_planes = []
    for g, plane in enumerate(planes):
        if impostor is not None:
            seen, lit = gate_shadow(
                setup,
                sensor,
                gate_grid=plane.grid,
                target_grid=target_plane.grid,
                sight=sight,
                paths=sensor.paths[g],
            )
            plane = replace(plane, occlusion=None if lit is None else 1.0 - lit, seen=seen)
        gate_planes.append(plane)
    pixel_directions = camera.pixel_directions().reshape(-1, 3)
    return FrameGeometry(
        position=sensor.position,
        central_air=sensor.central_air,
        pixel_rays=ray_components(sensor.position, pixel_directions),
        laser_rays=ray_components(laser.origins, laser.directions),
        laser_power=laser.power.astype(np.float32),
        gate_planes=tuple(gate_planes),
        target_plane=target_plane,
        impostor=impostor,
        target_light=target_light,
        target_gating=gating,
        target_rise=target_rise,
        resample=resample,
        sight=sight,
        sight_occupancy=sight_occupancy,
        sight_support=sight_support,
    )


def _support(field: np.ndarray) -> tuple[int, int, int, int]:
    """First row, last row + 1, first column, last column + 1 of a field's non-zero cells."""
    rows, cols = (np.flatnonzero(field.any(axis=axis)) for axis in (1, 0))
    if not rows.size:
        return 0, 0, 0, 0
    return int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1


def _gated(setup, grid, impostor, top, bottom, *, delays, shares) -> np.ndarray:
    """Share of each cell's return a gate [top, bottom] holds, on time and late."""
    on = impostor.occupancy > 0
    held = gated_share_on(setup, grid, top, bottom, on=on, delays=delays, shares=shares)
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
        (`workers.target.gated_share`), its unscattered share on time and the rest late
        by the path stretch of its scatterings (`workers.delays.return_delays`).
        """
        water = setup.water

        def lit(grid, impostor):
            rise = grid.depth - np.asarray(impostor.surface_depth, dtype=np.float64)
            lift = np.exp(water.diffuse_attenuation * setup.secant * rise)  # the way up
            radius = setup.scene.target.radius
            if setup.scene.target.shape == "sphere":
                ratio = _beam_depth_ratio(setup, sensor, grid, rise=min(radius, grid.depth))
                lift *= ratio ** np.clip(rise / radius, 0.0, 1.0)  # the way down
            return impostor.weight * lift

        fine_impostor = impostor_on(setup, levels.fine)
        coarse_impostor = impostor_on(setup, levels.coarse)
        outside = coarse_impostor.occupancy.copy()
        outside[levels.block] = 0.0
        chosen = [(levels.fine, fine_impostor)]
        if outside.any():
            chosen.append((levels.coarse, coarse_impostor))
        n_w = water.refractive_index
        cells, bounds = [], []
        for grid, impostor in chosen:
            on = impostor.occupancy > 0
            if grid is levels.coarse:
                on[levels.block] = False
            flat = np.flatnonzero(on)
            sight = lines_of_sight(sensor, grid, n_w, flat)
            cells.append(flat)
            bounds.append(
                np.array([gate_bounds(sight, paths, n_w) for paths in sensor.paths]).reshape(
                    len(sensor.paths), 2, flat.size
                )
            )
        unscattered, delays = return_delays(
            water,
            path=levels.fine.depth * setup.secant,
            beam_radius=sensor.reference_range * np.tan(0.5 * sensor.laser_fov),
            target_radius=setup.scene.target.radius,
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
            margin = self.setup.scene.target.radius  # the cells' centre depths, oblique
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
    scene = setup.scene
    cos_air = np.cos(np.radians(scene.platform.nadir_deg))
    cos_water = np.cos(setup.refracted_nadir)
    return float(height * (1.0 - cos_water / (scene.water.refractive_index * cos_air)))


def _beam_depth_ratio(setup, sensor, grid: PlaneGrid, *, rise: float) -> np.ndarray:
    r"""The flat sea's beam irradiance `rise` above `grid`'s plane over that on it, per cell.

    The Gaussian beam (1/e radius a at the sea, growing as the rays diverge from the
    platform: a (1 + z sec ϑ / (n R₀)) at depth z, R₀ the slant range; constant for a
    parallel beam), each depth's profile blurred by its normalised one-way point-spread
    function (`workers.water.WaterOptics.mtf`, zero-padded FFT) and attenuated by
    e^(−Kz sec ϑ): what the target's cells above its centre plane receive, relative to
    the plane's light, the same in every sample (the waves move the light, not its
    spread with depth). Cells are placed by their offset from the central ray.
    """
    water = setup.water
    n_w = water.refractive_index
    scene = setup.scene
    centre = central_point(sensor, grid.depth, n_w)
    x, y = grid.cell_centres()
    squared = (x - centre[0]) ** 2 + (y - centre[1]) ** 2
    radius = sensor.reference_range * np.tan(0.5 * sensor.laser_fov)
    light = []
    for depth in (grid.depth - rise, grid.depth):
        path = depth * setup.secant
        growth = 1.0 + path / (n_w * sensor.reference_range)
        width = radius * (growth if scene.laser.beam == "divergent" else 1.0)
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
