"""The in-water planes of a frame: two-level grids, spreads, beam tail, target maps, hiding.

`frame_geometry` builds them once per scene and frame (cached); every sample
`workers.render.render` draws reuses them. The model is in ``docs/model.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from workers.backends.backend import Backend, moved
from workers.backends.caches import lru_bytes
from workers.backends.kernels import Cells
from workers.fast.shadows import gate_shadow
from workers.fast.spread import (
    NEAR_SUPPORT,
    SPREAD_FRACTION,
    Levels,
    Spread,
    coarse_factor,
    encircled_radius,
)
from workers.fast.targetgating import TargetGating, TargetLight
from workers.optics.fresnel import fresnel_reflectance
from workers.setup.compiled import Setup
from workers.setup.geometry import LaserRays, Located, PlaneGrid, flat_sea_point
from workers.setup.interface import ray_components
from workers.setup.sensor import Sensor, sensor_at
from workers.targets.impostor import Impostor

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
    (`workers.fast.shadows.gate_shadow`), `lit` is the share of the laser's light the
    gate's water keeps, per cell of this fine grid, and `unseen` the share of a pixel's
    view the target stops, per cell of the target plane's fine grid: a pixel keeps
    (1 − unseen)·lit, each read where its line of sight crosses the plane.
    """

    levels: Levels
    spread: Spread
    tail: tuple[np.ndarray, np.ndarray, np.ndarray | None] | None
    lit: np.ndarray | None = None
    unseen: np.ndarray | None = None

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
            tail=moved(self.tail, backend),
            lit=moved(self.lit, backend),
            unseen=moved(self.unseen, backend),
        )


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
        return replace(self, fine=moved(self.fine, backend), coarse=moved(self.coarse, backend))


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


@dataclass(frozen=True)
class FrameGeometry:
    """Geometry of one frame: sensor rays, planes, filters and the target impostor.

    With a target, `sight` is the pixels' own grid at its depth
    (`workers.setup.sensor.Sensor.sight_grid`) and `sight_occupancy` the target's
    silhouette on it: each pixel's share, for its mask; `sight_support` the first row,
    last row + 1, first column and last column + 1 of its non-zero cells. `target_light`
    is the target's maps under the flat sea, `target_gating` what makes them at any
    height of the sea over the target.

    `target_plane` is lit by the laser's lattice; the target's maps, and its light's way
    up (`target_rise`: its spread with the sub-grid slopes' sway of the lines of sight,
    `workers.setup.compiled.Setup.subgrid_sway`), are on the plane's grid at the pixels'
    pitch, the default lattice's, whatever `laser.rays`: `resample` carries the light
    from the one to the other (None where they are the same grid). `lattice` holds the
    laser lattice's rays (`workers.setup.interface.ray_components`), `pixel_rays` the
    pixels' lines of sight.
    """

    position: np.ndarray
    central_air: float
    pixel_rays: tuple
    lattice: tuple
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
        """`kernels.Cells` of `sight`: the pixels' own grid at the target's depth."""
        return Cells.of_grid(self.sight)

    def on(self, backend: Backend) -> FrameGeometry:
        """The geometry with what a sample reads on `backend` (cached; itself on numpy).

        The rays, the laser's power, the planes (their spreads, tail, shadows) and the
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
                pixel_rays=moved(self.pixel_rays, backend),
                lattice=moved(self.lattice, backend),
                laser_power=backend.asarray(self.laser_power),
                gate_planes=tuple(plane.on(backend) for plane in self.gate_planes),
                target_plane=None if self.target_plane is None else self.target_plane.on(backend),
                target_rise=None if self.target_rise is None else self.target_rise.on(backend),
                resample=None if self.resample is None else self.resample.on(backend),
                target_light=light,
                sight_occupancy=moved(self.sight_occupancy, backend),
            )
        return self._on[backend]


def read_blur(setup: Setup, sensor: Sensor, grid: PlaneGrid, *, uses: int) -> tuple[float, float]:
    r"""The Gaussian a plane's spread adds so that light is read at one scale [m] (u, v).

    Parameters
    ----------
    setup : Setup
        The scene's setup (its receiver's aperture, its water's index).
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
    depth = grid.depth / setup.water.refractive_index
    aperture = setup.receiver_aperture * depth / (sensor.position[2] + depth)
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
    bare = sensor.fine_grid(depth, guard=0, multiple=1)
    spacing = min(bare.spacing_u, bare.spacing_v)
    margin = passes * encircled_radius(setup.water, distance=depth, fraction=SPREAD_FRACTION)
    span = max(bare.shape) * spacing
    factor = coarse_factor(spacing=spacing, extent=span + 2 * margin)
    guard = max(
        int(np.ceil(GUARD * sensor.camera.pixels)),
        NEAR_SUPPORT * factor,
        int(np.ceil(reach / spacing)),
    )
    fine = sensor.fine_grid(depth, guard=guard, multiple=factor)
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
def frame_geometry(setup: Setup, frame: int) -> FrameGeometry:
    """Sensor rays, planes, filters and target maps of `frame` (cached by setup and frame)."""
    water = setup.water
    sensor = sensor_at(setup, frame)
    camera = sensor.camera
    t = setup.target
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
        if sensor.laser_rays != setup.pixel_pitch_rays:
            sight_sensor = sensor_at(setup, frame, rays=setup.pixel_pitch_rays)
        rise_levels, guard = _plane_levels(setup, sight_sensor, t.depth, 1)
        if sight_sensor is sensor:
            rise_levels = built[0][0]
        else:
            fine = rise_levels.fine
            reach = (guard + 1) * max(fine.spacing_u, fine.spacing_v)
            built[0] = _plane_levels(setup, sensor, t.depth, 1, reach=reach)
    # the traced lattice reaches LATTICE_MARGIN rays beyond the field; the beam's tail
    # beyond it crosses the mean sea (within the beam's extent). The lattice is offset
    # from the pixels' lines of sight (`workers.setup.sensor.lattice_offset`).
    rays = sensor.laser_rays
    margin = min(LATTICE_MARGIN, int(np.ceil(0.5 * (BEAM_EXTENT - 1.0) * rays)))
    laser = LaserRays.from_platform(
        position=sensor.position,
        rotation=camera.rotation,
        beam=setup.beam,
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
        beam=setup.beam,
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
            read_blur(setup, sensor, levels.fine, uses=1)
            if gate is not None
            else read_blur(setup, sight_sensor, rise_levels.fine, uses=2)
        )
        spread = Spread.build(
            water=water,
            levels=levels,
            distance=depth,
            truncation=setup.psf_truncation,
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
        sway = setup.subgrid_sway(rise_levels.fine, distance=t.depth)
        if sway is not None or rise_levels is not target_plane.levels:
            rise = Spread.build(
                water=water,
                levels=rise_levels,
                distance=t.depth,
                truncation=setup.psf_truncation,
                blur=read_blur(setup, sight_sensor, rise_levels.fine, uses=2),
                sway=sway,
            )
        target_rise = Plane(levels=rise_levels, spread=rise, tail=None)
        if rise_levels is not target_plane.levels:
            resample = Resample.between(target_plane.levels, rise_levels)
        impostor = setup.impostor(rise_levels.fine)
        gating = TargetGating.build(setup, sight_sensor, rise_levels)
        target_light = gating.light()
        guard = max(int(np.ceil(GUARD * camera.pixels)), 1)
        sight = sensor.sight_grid(t.depth, guard=guard)
        sway = setup.subgrid_sway(sight, distance=t.depth)
        sight_occupancy = setup.impostor(sight).occupancy
        if sway is not None:  # each pixel's share, as the sub-grid slopes sway its view
            swayed = sight.convolved(sight_occupancy, np.ones_like, sway=sway)
            sight_occupancy = np.where(swayed > SWAY_FLOOR, np.minimum(swayed, 1.0), 0.0)
        sight_occupancy = sight_occupancy.astype(np.float32)
        sight_support = _support(sight_occupancy)
    gate_planes = []
    for g, plane in enumerate(planes):
        if impostor is not None:
            unseen, unlit = gate_shadow(
                setup,
                sensor,
                gate_grid=plane.grid,
                target_grid=target_plane.grid,
                sight=sight,
                paths=sensor.paths[g],
            )
            plane = replace(plane, lit=None if unlit is None else 1.0 - unlit, unseen=unseen)
        gate_planes.append(plane)
    pixel_directions = camera.pixel_directions().reshape(-1, 3)
    return FrameGeometry(
        position=sensor.position,
        central_air=sensor.central_air,
        pixel_rays=ray_components(sensor.position, pixel_directions),
        lattice=ray_components(laser.origins, laser.directions),
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
