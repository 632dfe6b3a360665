"""Render one sample: a sea-surface realisation seen by the gated receivers.

`render` is the seam between the physics and the service: it returns one sample as an
`xarray.Dataset` holding exactly the variables of one ``sample`` of the store
(``docs/model.md``), without the ``sample`` dimension.

The image-formation model, per frame:

1. Laser rays and pixel rays are intersected with the real surface, refracted (Snell) and
   weighted by the Fresnel transmittance. The laser is a Gaussian beam: rays sample it at
   the pixels' pitch over the image and `LATTICE_MARGIN` rays beyond, and its tail beyond
   that (out to `BEAM_EXTENT` times its 1/e radius) is refracted by the mean, flat sea onto
   each plane (`workers.spread`).
2. Each gate opens and closes on slant range (`workers.gates`). A gate's single-scattering
   water backscatter is an effective Lambertian reflectance on a reference plane at the
   central slab's centroid depth: laser rays are splatted where they cross that plane
   (each with the attenuation of its extra slant path), spread by the Wells point-spread
   function down and up in one product (reflectance × MTF², linear, without wrap-around:
   `workers.spread.Spread`) and gathered where each pixel's ray crosses the plane, times
   the exit transmittance. The slant-range timing enters as one gain per laser ray and per
   pixel, from its air path (`_gate_gain`): a ray longer in the air gates a shallower slab.
3. The target is an impostor on the plane through its centre: downwelling irradiance
   there times its reflectance map, attenuated from each cell's true depth on the target
   (not from the centre plane), restricted to the part of the target inside the gate,
   spread up and gathered.
4. Where a ray or a pixel's line of sight meets the target, the water behind the target is
   neither lit nor seen: the slab's backscatter is reduced by the fraction lying behind the
   target's surface, half on the way down and half on the way up (square roots), which is
   exact without scattering and gives a full shadow when the target is above the gate.
5. Images are scaled to photoelectrons (`radiometry.mode`): ``absolute`` by the lidar
   equation's photon budget (`workers.radiometry.photoelectrons_per_signal`), so counts
   fall with altitude as 1/(nH + d)²; ``normalised`` so that a ρ = 1 Lambertian plane just
   under a flat sea at nadir gives `radiometry.white_plane_photons` counts. Then Poisson
   shot noise is drawn.

Approximations beyond the paper's, at oblique views: the Wells spread is computed for the
vertical range to each plane (it underestimates the blur by about 1/cos ϑ in the water),
while attenuation follows each ray's slant path; a gate's slab is weighted with the central
ray's in-water angle and blurred at the central slab's depth wherever slant gating moves
it; the target's own cells are gated on their lines of sight.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import xarray as xr

from workers.conditioning import Kriging
from workers.gates import central_paths, sight_lines, slab_bounds
from workers.geometry import LaserRays, Located, PinholeCamera, PlaneGrid, flat_sea_point
from workers.noise import shot_noise
from workers.optics import fresnel_reflectance
from workers.radiometry import photoelectrons_per_signal, pixel_solid_angle
from workers.scene import Scene
from workers.seeds import SampleSeed
from workers.spread import (
    NEAR_SUPPORT,
    SPREAD_FRACTION,
    Levels,
    Spread,
    coarse_factor,
    encircled_radius,
)
from workers.surface import synthesize
from workers.target import Impostor
from workers.water import (
    WaterOptics,
    slab_backscatter_centroid,
    slab_backscatter_reflectance,
)

__all__ = ["render", "sample_labels"]

GUARD = 0.125
"""Least guard band on each side of an in-water plane, as a fraction of the image size."""

BEAM_EXTENT = 2.5
"""Half-width of the traced beam in units of its 1/e radius (e^-6.25: 0.2 % lies beyond)."""

TAIL_STEP = 2
"""Pitch of the beam tail's lattice, in laser-lattice steps (1 for an odd lattice, so the
tail's cells end where the traced lattice's begin)."""

LATTICE_MARGIN = 8
"""Laser rays traced through the wavy surface beyond the field, on each side."""

SURFACE_ITERATIONS = 8
"""Most fixed-point refinements of each ray's hit on the wavy surface (start at z = 0)."""

SURFACE_TOLERANCE = 1e-3
"""Height change [m] below which the surface hit has converged (1 mm)."""

VISIBILITY = {"none": 0, "in_gate": 1, "shadow": 2, "below_gate": 3}


def render(scene: Scene, *, seed: int | SampleSeed) -> xr.Dataset:
    """Render one sample: six (or however many) gated images per frame.

    Parameters
    ----------
    scene : Scene
        All parameters of the sample.
    seed : int or SampleSeed
        An int is the root seed of a lone sample (point 0, realisation 0). The surface
        depends on ``(root, realisation)`` only, the noise on ``(root, point,
        realisation)``.

    Returns
    -------
    xarray.Dataset
        ``image`` and ``expected`` (frame, gate, y, x), ``target_mask`` (frame, y, x),
        ``target_present`` (), ``target_visibility`` (gate), coordinates ``gate_top``,
        ``gate_bottom`` (gate), ``time`` and the platform position (frame), and
        ``surface_elevation`` (frame, sy, sx) when ``scene.save_surface`` is set.
    """
    if not isinstance(seed, SampleSeed):
        seed = SampleSeed(root=int(seed))
    key = scene.model_dump_json()
    setup = _setup(key)
    frames = scene.sequence.frames
    times = np.arange(frames) * scene.sequence.interval
    surface = None
    if setup.spectrum is not None:
        surface = synthesize(
            setup.spectrum,
            grid_size=scene.surface.grid_size,
            spacing=scene.surface.spacing,
            rng=seed.surface_rng(),
            times=tuple(times),
            max_elevation=scene.surface.max_elevation,
            conditioning=setup.conditioning,
        )
    expected = []
    masks = []
    for frame in range(frames):
        geometry = _frame_geometry(key, frame)
        signal, mask = _render_frame(setup, geometry, surface, frame)
        expected.append(signal)
        masks.append(mask)
    expected = np.stack(expected)
    noise = scene.noise
    if scene.radiometry.photoelectrons:
        image = shot_noise(
            expected, rng=seed.noise_rng(), gain=noise.gain, excess_noise=noise.excess_noise
        )
    else:
        image = expected.copy()
    return _dataset(scene, expected, image, np.stack(masks), surface)


@dataclass(frozen=True)
class _Setup:
    """What every frame of every sample of a scene shares."""

    scene: Scene
    water: WaterOptics
    spectrum: object
    conditioning: Kriging | None
    gates: tuple[tuple[float, float], ...]
    reference_depths: tuple[float, ...]
    reflectances: tuple[float, ...]
    scale: float
    refracted_nadir: float
    secant: float


@functools.lru_cache(maxsize=32)
def _setup(key: str) -> _Setup:
    scene = Scene.model_validate_json(key)
    w = scene.water
    coefficients = w.coefficients
    coefficients.update(
        phase_function=w.phase_function, theta0=w.theta0, refractive_index=w.refractive_index
    )
    water = WaterOptics(**coefficients)
    gates = scene.receiver.gate_depths
    refracted_nadir = float(
        np.arcsin(np.sin(np.radians(scene.platform.nadir_deg)) / w.refractive_index)
    )
    secant = 1.0 / np.cos(refracted_nadir)
    references = tuple(
        float(
            slab_backscatter_centroid(
                diffuse_attenuation=water.diffuse_attenuation * secant, top=top, bottom=bottom
            )
        )
        for top, bottom in gates
    )
    # Seen at an angle ϑ in the water, a slab's volume return grows as 1/cos²ϑ (the normal
    # irradiance is E/cosϑ and the path through dz is dz/cosϑ) and fades as e^(-2Kz/cosϑ).
    K = water.diffuse_attenuation * secant
    reflectances = tuple(
        float(
            secant**2
            * slab_backscatter_reflectance(
                backscatter_pi=water.backscatter_pi,
                diffuse_attenuation=K,
                top=top,
                bottom=bottom,
                reference=reference,
            )
        )
        for (top, bottom), reference in zip(gates, references, strict=True)
    )
    scale = _photoelectrons_per_signal(scene)
    return _Setup(
        scene=scene,
        water=water,
        spectrum=scene.surface.wave_spectrum(),
        conditioning=scene.surface.kriging(),
        gates=gates,
        reference_depths=references,
        reflectances=reflectances,
        scale=scale,
        refracted_nadir=refracted_nadir,
        secant=float(secant),
    )


def _photoelectrons_per_signal(scene: Scene) -> float:
    """The factor taking the raw signal to photoelectrons (or to white-plane units).

    Absolute: the lidar equation's photon budget for the Gaussian beam's whole pulse
    energy, whose 1/e half-width at the reference range (`_frame_geometry`'s, the slant
    range at the first frame) is that range times tan(laser field/2). Normalised: a ρ = 1
    plane just under a flat sea at nadir, which reads t0² (two-way normal-incidence
    Fresnel transmittance), gives `white_plane_photons` (1 when that is 0).
    """
    r, n_w = scene.radiometry, scene.water.refractive_index
    if r.mode == "normalised":
        t0 = 1.0 - float(fresnel_reflectance(1.0, n1=1.0, n2=n_w))
        return (r.white_plane_photons or 1.0) / t0**2
    p = scene.platform
    reference_range = p.altitude / np.cos(np.radians(p.nadir_deg))
    laser_fov = np.radians(scene.laser.field_of_view_deg or scene.receiver.field_of_view_deg)
    return photoelectrons_per_signal(
        pulse_energy=r.pulse_energy,
        wavelength=r.wavelength,
        aperture_diameter=r.receiver_aperture,
        optics_transmission=r.optics_transmission,
        quantum_efficiency=r.quantum_efficiency,
        solid_angle=pixel_solid_angle(
            field_of_view=np.radians(scene.receiver.field_of_view_deg),
            pixels=scene.receiver.pixels,
        ),
        beam_half_width=reference_range * np.tan(0.5 * laser_fov),
        refractive_index=n_w,
    )


@dataclass(frozen=True)
class _Sensor:
    """Camera, laser and the flat-sea gate timing of one frame (no plane yet)."""

    position: np.ndarray
    camera: PinholeCamera
    laser_fov: float
    laser_rays: int
    reference_range: float
    lattice: tuple
    paths: np.ndarray

    @property
    def central_air(self) -> float:
        """Air path of the central ray to mean sea level [m]."""
        return float(self.position[2] / np.cos(self.camera.nadir))


def _sensor(setup: _Setup, frame: int) -> _Sensor:
    scene = setup.scene
    p, r = scene.platform, scene.receiver
    position = _platform_position(scene, frame * scene.sequence.interval)
    camera = PinholeCamera(
        position=tuple(position),
        nadir=np.radians(p.nadir_deg),
        azimuth=np.radians(p.azimuth_deg),
        field_of_view=np.radians(r.field_of_view_deg),
        pixels=r.pixels,
    )
    laser_fov = float(np.radians(scene.laser.field_of_view_deg or r.field_of_view_deg))
    reference_range = p.altitude / np.cos(np.radians(p.nadir_deg))
    probe = LaserRays.from_platform(
        position=position,
        rotation=camera.rotation,
        beam=scene.laser.beam,
        field_of_view=laser_fov,
        rays=scene.laser_rays,
        reference_range=reference_range,
    )
    paths = central_paths(
        altitude=float(position[2]),
        nadir=np.radians(p.nadir_deg),
        refractive_index=scene.water.refractive_index,
        gates=setup.gates,
    )
    return _Sensor(
        position=position,
        camera=camera,
        laser_fov=laser_fov,
        laser_rays=scene.laser_rays,
        reference_range=reference_range,
        lattice=probe.central(),
        paths=paths,
    )


def _sight(sensor: _Sensor, grid: PlaneGrid, refractive_index: float, cells=None):
    """Air path and in-water cosine of the flat-sea line of sight to each cell (or `cells`)."""
    x, y = grid.cell_centres()
    if cells is not None:
        x, y = x.ravel()[cells], y.ravel()[cells]
    return sight_lines(
        position=sensor.position, x=x, y=y, depth=grid.depth, refractive_index=refractive_index
    )


def _gate_bounds(sight, paths, refractive_index):
    """Gated depth bounds (top, bottom) [m] along lines of sight (`_sight`)."""
    air, cos_water = sight
    return slab_bounds(
        paths=paths, air=air, cos_water=cos_water, refractive_index=refractive_index
    )


@dataclass(frozen=True)
class _Plane:
    """An in-water plane: its two-level grid, spread, and the beam tail landing on it.

    For a gate, `spread` is the round trip (the slab's reflectance times MTF²); where the
    target hides part of the gate's water, `bounds` holds the gate's slab bounds on the
    target plane's grid (for the rays that meet the target) and `occlusion` the square root
    of the fraction not hidden, seen back through the upwelling point-spread function.
    """

    levels: Levels
    spread: Spread
    tail: tuple[np.ndarray, np.ndarray] | None
    bounds: tuple[np.ndarray, np.ndarray] | None = None
    occlusion: np.ndarray | None = None

    @property
    def grid(self) -> PlaneGrid:
        """The fine grid."""
        return self.levels.fine


@dataclass(frozen=True)
class _TargetLight:
    """The target's reflectance maps per gate: gates cutting it alike share one map.

    Each map is a pair (fine, coarse); the coarse one holds the part of a large target
    outside the fine grid (None when the target lies within it).
    """

    weights: tuple[tuple[np.ndarray, np.ndarray | None], ...]
    gates: tuple[tuple[int, ...], ...]


@dataclass(frozen=True)
class _FrameGeometry:
    """Geometry of one frame: sensor rays, planes, filters and the target impostor."""

    position: np.ndarray
    central_air: float
    pixel_rays: tuple
    laser_rays: tuple
    laser_power: np.ndarray
    pixel_index: np.ndarray | None
    gate_planes: tuple[_Plane, ...]
    target_plane: _Plane | None
    impostor: Impostor | None
    target_light: _TargetLight | None


def _platform_position(scene: Scene, time: float) -> np.ndarray:
    p = scene.platform
    nadir, azimuth = np.radians(p.nadir_deg), np.radians(p.azimuth_deg)
    reach = p.altitude * np.tan(nadir)
    start = np.array([-reach * np.sin(azimuth), -reach * np.cos(azimuth), p.altitude])
    return start + time * np.asarray(scene.sequence.velocity, dtype=float)


def _fine_grid(sensor: _Sensor, depth: float, n_w: float, *, guard: int, multiple: int):
    return PlaneGrid.covering(
        camera=sensor.camera,
        lattice=sensor.lattice,
        depth=depth,
        refractive_index=n_w,
        guard=guard,
        multiple=multiple,
    )


def _plane_levels(setup: _Setup, sensor: _Sensor, depth: float, passes: int) -> tuple[Levels, int]:
    """The two-level grid of a plane, and its fine guard band [cells].

    The coarse margin holds `SPREAD_FRACTION` of the scattered light one way, twice that
    radius for a round trip (two independent spreads).
    """
    n_w = setup.water.refractive_index
    bare = _fine_grid(sensor, depth, n_w, guard=0, multiple=1)
    spacing = min(bare.spacing_u, bare.spacing_v)
    margin = passes * encircled_radius(setup.water, distance=depth, fraction=SPREAD_FRACTION)
    span = max(bare.shape) * spacing
    factor = coarse_factor(spacing=spacing, extent=span + 2 * margin)
    guard = max(int(np.ceil(GUARD * sensor.camera.pixels)), NEAR_SUPPORT * factor)
    fine = _fine_grid(sensor, depth, n_w, guard=guard, multiple=factor)
    return Levels.around(fine, factor=factor, margin=margin), guard


def _beam_tail(setup: _Setup, sensor: _Sensor, levels: Levels, tail: LaserRays, gate=None):
    """The beam tail's irradiance on the fine and coarse grids under the mean (flat) sea.

    For a gate's plane (`gate` its index), each ray carries the gate's timing
    (`_gate_gain`) in place of its own path's attenuation.
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
        extra = _gate_gain(air - sensor.central_air, setup, gate)
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


@functools.lru_cache(maxsize=64)
def _frame_geometry(key: str, frame: int) -> _FrameGeometry:
    setup = _setup(key)
    scene = setup.scene
    water = setup.water
    sensor = _sensor(setup, frame)
    camera, r = sensor.camera, scene.receiver
    t = scene.target
    depths = ([t.depth] if t.shape != "none" else []) + list(setup.reference_depths)
    passes = ([1] if t.shape != "none" else []) + [2] * len(setup.gates)
    built = [
        _plane_levels(setup, sensor, depth, count)
        for depth, count in zip(depths, passes, strict=True)
    ]
    # the traced lattice reaches LATTICE_MARGIN rays beyond the field; the beam's tail
    # beyond it crosses the mean sea (within the beam's extent)
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
    )
    # The default laser (divergent, the receiver's field, one ray per pixel) shares the
    # pixels' lattice of directions: the pixels' lines of sight are its central block.
    monostatic = bool(
        scene.laser.beam == "divergent"
        and rays == r.pixels
        and sensor.laser_fov == camera.field_of_view
    )
    pixel_index = None
    if monostatic:
        side = rays + 2 * margin
        block = np.arange(margin, margin + rays)
        pixel_index = (block[:, None] * side + block[None, :]).ravel()

    gains = ([1.0] if t.shape != "none" else []) + list(setup.reflectances)
    gate_index = ([None] if t.shape != "none" else []) + list(range(len(setup.gates)))
    planes = []
    for (levels, _), depth, count, gain, gate in zip(
        built, depths, passes, gains, gate_index, strict=True
    ):
        spread = Spread.build(
            water=water,
            levels=levels,
            distance=depth,
            truncation=scene.water.psf_truncation,
            passes=count,
            gain=gain,
        )
        planes.append(
            _Plane(
                levels=levels, spread=spread, tail=_beam_tail(setup, sensor, levels, tail, gate)
            )
        )
    target_plane = impostor = target_light = target_sight = None
    if t.shape != "none":
        target_plane, planes = planes[0], planes[1:]
        impostor = _impostor(setup, target_plane.grid)
        target_light = _target_light(setup, sensor, target_plane.levels)
        target_sight = _sight(sensor, target_plane.grid, water.refractive_index)
    gate_planes = []
    for g, plane in enumerate(planes):
        if impostor is not None:
            plane = _with_hiding(
                setup, sensor, plane, sensor.paths[g], target_plane.grid, target_sight, impostor
            )
        gate_planes.append(plane)
    pixel_directions = camera.pixel_directions().reshape(-1, 3)
    return _FrameGeometry(
        position=sensor.position,
        central_air=sensor.central_air,
        pixel_rays=_ray_components(sensor.position, pixel_directions),
        laser_rays=_ray_components(laser.origins, laser.directions),
        laser_power=laser.power.astype(np.float32),
        pixel_index=pixel_index,
        gate_planes=tuple(gate_planes),
        target_plane=target_plane,
        impostor=impostor,
        target_light=target_light,
    )


def _target_centre(setup: _Setup, camera: PinholeCamera) -> tuple[float, float]:
    t = setup.scene.target
    if t.x is not None and t.y is not None:
        return float(t.x), float(t.y)
    centre = flat_sea_point(
        origin=_platform_position(setup.scene, 0.0),
        direction=camera.rotation[2],
        depth=t.depth,
        refractive_index=setup.water.refractive_index,
    )
    return float(centre[0]), float(centre[1])


def _impostor(setup: _Setup, grid: PlaneGrid) -> Impostor:
    t = setup.scene.target
    camera = _sensor(setup, 0).camera
    return Impostor.build(
        grid=grid,
        shape=t.shape,
        centre=_target_centre(setup, camera),
        radius=t.radius,
        reflectance=t.reflectance,
        shading=t.shading,
        refracted_nadir=setup.refracted_nadir,
    )


def _target_light(setup, sensor, levels: Levels) -> _TargetLight:
    r"""Reflectance of the part of the target each gate holds, from its true depth.

    The target plane's light carries the attenuation of the plane through the target's
    centre; a cell whose line meets the target's surface at depth z_s (above the centre
    plane, on the lit cap) is reached by a path shorter by (z_c − z_s) sec ϑ each way, so
    its weight is multiplied by :math:`e^{2K\sec\vartheta\,(z_c - z_s)}`.
    """
    water = setup.water

    def lit(grid, impostor):
        depth = np.asarray(impostor.surface_depth, dtype=np.float64)
        lift = np.exp(2 * water.diffuse_attenuation * setup.secant * (grid.depth - depth))
        return depth, impostor.weight * lift

    fine_impostor = _impostor(setup, levels.fine)
    coarse_impostor = _impostor(setup, levels.coarse)
    outside = coarse_impostor.occupancy.copy()
    outside[levels.block] = 0.0
    levels_lit = [(levels.fine, fine_impostor, *lit(levels.fine, fine_impostor))]
    if outside.any():
        levels_lit.append((levels.coarse, coarse_impostor, *lit(levels.coarse, coarse_impostor)))
    n_w = water.refractive_index
    sights = [_sight(sensor, grid, n_w) for grid, *_ in levels_lit]
    maps, members = {}, {}
    for g, paths in enumerate(sensor.paths):
        pair, signature = [], b""
        for (grid, impostor, depth, weight), sight in zip(levels_lit, sights, strict=True):
            top, bottom = _gate_bounds(sight, paths, n_w)
            inside = (depth >= top) & (depth <= bottom) & (impostor.occupancy > 0)
            if grid is levels.coarse:
                inside[levels.block] = False
            pair.append(np.where(inside, weight, 0.0).astype(np.float32))
            signature += inside.tobytes()
        if not any(m.any() for m in pair):
            continue
        if signature not in maps:
            maps[signature] = (pair[0], pair[1] if len(pair) > 1 else None)
            members[signature] = []
        members[signature].append(g)
    return _TargetLight(
        weights=tuple(maps.values()), gates=tuple(tuple(m) for m in members.values())
    )


def _with_hiding(setup, sensor, plane, paths, target_grid, target_sight, impostor) -> _Plane:
    """`plane` with the target's hiding of the gate's water, if it hides any."""
    water = setup.water
    k = water.diffuse_attenuation * setup.secant
    top_t, bottom_t = _gate_bounds(target_sight, paths, water.refractive_index)
    grid = plane.grid
    # The line of sight through a gate-plane cell crossed the target plane nearer the
    # platform, by the depth difference times the tangent of the in-water angle.
    x, y = grid.cell_centres()
    back = (grid.depth - target_grid.depth) * np.tan(setup.refracted_nadir)
    located = target_grid.locate(x + back * grid.axis_v[0], y + back * grid.axis_v[1])
    top, bottom = _gate_bounds(
        _sight(sensor, grid, water.refractive_index), paths, water.refractive_index
    )
    hidden = _hidden_fraction(
        target_grid.gather(impostor.surface_depth, located),
        target_grid.gather(impostor.occupancy, located),
        top=top,
        bottom=bottom,
        diffuse_attenuation=k,
    )
    if not hidden.any():
        return plane
    deficit = (1.0 - np.sqrt(np.maximum(1.0 - hidden, 0.0))).astype(np.float32)
    # seen back through the one-way (upwelling) spread, normalised to keep its level
    upwelling = Spread.build(
        water=water,
        levels=plane.levels,
        distance=grid.depth,
        truncation=setup.scene.water.psf_truncation,
    )
    seen, _ = upwelling(deficit, far_out=False)
    occlusion = 1.0 - seen / np.float32(np.exp(-water.diffuse_attenuation * grid.depth))
    return _Plane(
        levels=plane.levels,
        spread=plane.spread,
        tail=plane.tail,
        bounds=(top_t.astype(np.float32), bottom_t.astype(np.float32)),
        occlusion=occlusion.astype(np.float32),
    )


@dataclass(frozen=True)
class _Transmitted:
    """Rays after the surface: entry point, in-water slopes, Fresnel transmittance."""

    air: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    tan_x: np.ndarray
    tan_y: np.ndarray
    secant: np.ndarray
    transmittance: np.ndarray

    def take(self, index: np.ndarray) -> _Transmitted:
        """The rays at `index` (e.g. the pixels' block of the laser lattice)."""
        return _Transmitted(**{name: getattr(self, name)[index] for name in _TRANSMITTED})

    def on_axes(self, grid: PlaneGrid, diffuse_attenuation: float) -> _Projected:
        """The rays in the horizontal axes of `grid`, ready to be crossed with any depth.

        Parameters
        ----------
        grid : PlaneGrid
            Any plane of the frame: they all share the image's axes.
        diffuse_attenuation : float
            K [1/m].

        Returns
        -------
        _Projected
        """
        (u0, u1), (v0, v1) = grid.axis_u, grid.axis_v
        slope_u = self.tan_x * u0 + self.tan_y * u1
        slope_v = self.tan_x * v0 + self.tan_y * v1
        base_u = self.x * u0 + self.y * u1 + self.z * slope_u
        base_v = self.x * v0 + self.y * v1 + self.z * slope_v
        k = -diffuse_attenuation
        return _Projected(
            base_u=base_u,
            slope_u=slope_u,
            base_v=base_v,
            slope_v=slope_v,
            log_extra=(k * self.z) * self.secant,
            log_extra_slope=k * (self.secant - 1.0),
        )


@dataclass(frozen=True)
class _Projected:
    r"""Rays after the surface, as affine functions of the depth z of a plane [m].

    On a plane at depth z a ray that entered at height η with in-water slopes
    (tan_x, tan_y) is at ``base + z·slope`` along each of the image's horizontal axes u
    and v [m] (its entry point moved down by z + η along the slopes). The MTF of a plane
    at depth z already attenuates by exp(-Kz); the ray travels (z + η)/cos ϑ, so it is
    further attenuated by :math:`e^{-K((z + \eta)/\cos\vartheta - z)}
    = \exp(\mathrm{log\_extra} + z\,\mathrm{log\_extra\_slope})`.
    """

    base_u: np.ndarray
    slope_u: np.ndarray
    base_v: np.ndarray
    slope_v: np.ndarray
    log_extra: np.ndarray
    log_extra_slope: np.ndarray

    def cross(self, levels: Levels):
        """Rays on a plane (at its depth) and their extra-path attenuation.

        Returns
        -------
        fine : Located
            The rays on the fine grid (zero weight outside it).
        extra : ndarray
            Attenuation of each ray's extra slant path [1].
        outside : tuple or None
            ``(index, located)``: the rays that miss the fine grid, located on the coarse
            grid; None when every ray lands on the fine grid.
        """
        grid = levels.fine
        z = np.float32(grid.depth)
        (o0, o1), (u0, u1), (v0, v1) = grid.origin, grid.axis_u, grid.axis_v
        col = self.slope_u * z
        col += self.base_u
        col -= np.float32(o0 * u0 + o1 * u1)
        col *= np.float32(1.0 / grid.spacing_u)
        row = self.slope_v * z
        row += self.base_v
        row -= np.float32(o0 * v0 + o1 * v1)
        row *= np.float32(1.0 / grid.spacing_v)
        extra = self.log_extra_slope * z
        extra += self.log_extra
        rows, cols = grid.shape
        missing = np.flatnonzero((row < 0) | (row >= rows - 1) | (col < 0) | (col >= cols - 1))
        outside = None
        if missing.size:
            coarse_row, coarse_col = levels.to_coarse(row[missing], col[missing])
            outside = (missing, levels.coarse.locate_cells(coarse_row, coarse_col))
        return grid.locate_cells(row, col), np.exp(extra, out=extra), outside


def _ray_components(origins, directions):
    """Rays as six contiguous float32 components (ox, oy, oz, dx, dy, dz).

    An origin shared by every ray (a divergent beam, the pinhole) is kept as three
    float32 scalars, which broadcast.
    """
    origins = np.asarray(origins, dtype=np.float32).reshape(-1, 3)
    directions = np.asarray(directions, dtype=np.float32).reshape(-1, 3)
    if origins.shape[0] == 1 or np.all(origins == origins[0]):
        o = tuple(np.float32(v) for v in origins[0])
    else:
        o = tuple(np.ascontiguousarray(origins[:, i]) for i in range(3))
    return (*o, *(np.ascontiguousarray(directions[:, i]) for i in range(3)))


def _through_surface(rays, surface, frame, refractive_index):
    r"""Intersect rays with the surface, refract them and get their Fresnel transmittance.

    Parameters
    ----------
    rays : tuple
        ``(ox, oy, oz, dx, dy, dz)`` from `_ray_components` [m], [1].
    surface : Surface or None
        The sea surface (None: flat).
    frame : int
        Frame index into the surface.
    refractive_index : float
        Refractive index of the water [1].

    Returns
    -------
    _Transmitted

    Notes
    -----
    The hit is found by fixed-point iteration from z = 0: the ray's point at the height η
    of the surface under its previous point; it contracts by |slope · tan(view)| per step
    and stops when the surface under the new point differs from η by less than
    `SURFACE_TOLERANCE` (so the hit is within the tolerance, about, of the exact one).
    Elevation and slopes are those sampled there (the slopes only once, at the end).

    The interface is refracted and weighted inline with the formulas of
    `workers.optics.refract` and `workers.optics.fresnel_reflectance`, specialised to
    air → water (n1 = 1 < n2, no total internal reflection): with the upward normal
    :math:`n = (-s_x, -s_y, 1)/\sqrt{1 + s^2}`, cos i = -ξ·n and
    k = 1 - (1 - cos² i)/n_w², the transmitted direction is
    :math:`\xi/n_w + (\cos i/n_w - \sqrt{k})\,n`. Rays meeting a facet that faces
    away from them (cos i <= 0), and rays the surface would send back up, transmit
    nothing.
    """
    ox, oy, oz, dx, dy, dz = rays
    travel = -oz / dz
    if surface is None:
        eta = np.zeros_like(travel)
        sx = sy = eta
    else:
        eta = surface.elevation_at(ox + travel * dx, oy + travel * dy, frame)
        for _ in range(SURFACE_ITERATIONS):
            travel = (eta - oz) / dz
            x, y = ox + travel * dx, oy + travel * dy
            height = surface.elevation_at(x, y, frame)
            converged = np.max(np.abs(height - eta)) < SURFACE_TOLERANCE
            eta = height
            if converged:
                break
        sx, sy = surface.slopes_at(x, y, frame)
    ratio = 1.0 / refractive_index
    inverse_norm = 1.0 / np.sqrt(1.0 + sx * sx + sy * sy)
    cos_incidence = (dx * sx + dy * sy - dz) * inverse_norm
    cos_i = np.clip(cos_incidence, 0.0, 1.0)
    cos_t = np.sqrt(1.0 - ratio * ratio * (1.0 - cos_i * cos_i))
    coefficient = (ratio * cos_i - cos_t) * inverse_norm
    down = -(ratio * dz + coefficient)
    facing = (cos_incidence > 0) & (down > 0)
    secant = np.where(facing, 1.0 / np.where(facing, down, 1.0), 1.0)
    n_w = refractive_index
    r_s = (cos_i - n_w * cos_t) / (cos_i + n_w * cos_t)
    r_p = (n_w * cos_i - cos_t) / (n_w * cos_i + cos_t)
    transmittance = 1.0 - 0.5 * (r_s * r_s + r_p * r_p)
    return _Transmitted(
        air=np.asarray(travel, dtype=np.float32),
        x=np.asarray(ox + travel * dx, dtype=np.float32),
        y=np.asarray(oy + travel * dy, dtype=np.float32),
        z=np.asarray(eta, dtype=np.float32),
        tan_x=np.where(facing, (ratio * dx - coefficient * sx) * secant, 0.0).astype(np.float32),
        tan_y=np.where(facing, (ratio * dy - coefficient * sy) * secant, 0.0).astype(np.float32),
        secant=secant.astype(np.float32),
        transmittance=np.where(facing, transmittance, 0.0).astype(np.float32),
    )


_TRANSMITTED = ("air", "x", "y", "z", "tan_x", "tan_y", "secant", "transmittance")


def _hidden_fraction(surface_depth, occupancy, *, top, bottom, diffuse_attenuation):
    """Fraction of a slab's backscatter lying behind the target along each line.

    Lines through the target's silhouette (weighted by `occupancy`) lose the part of the
    single-scattering integral deeper than the target's surface. `top` and `bottom` are
    the slab's bounds (scalars, or one per line: slant-range gates). Computed in float64,
    so a float32 depth on a gate bound stays inside the slab.
    """
    top = np.asarray(top, dtype=np.float64)
    bottom = np.maximum(np.asarray(bottom, dtype=np.float64), top)
    behind = np.clip(np.asarray(surface_depth, dtype=np.float64), top, bottom)

    def slab(upper):
        return slab_backscatter_reflectance(
            backscatter_pi=1.0,
            diffuse_attenuation=diffuse_attenuation,
            top=upper,
            bottom=bottom,
            reference=top,
        )

    part, whole = np.broadcast_arrays(slab(behind), slab(top))
    share = np.divide(part, whole, out=np.zeros(part.shape), where=whole > 0)
    return (occupancy * share).astype(np.float32)


def _gate_gain(excess, setup: _Setup, gate: int):
    r"""A laser ray's or a pixel's share of a gate's water return, from its air path.

    A gate opens and closes at fixed times, so the water it holds is set by the optical
    path: a ray that spends τ longer in the air than the central ray (`excess`), down or
    up, has τ/n less water path within the gate. With both paths so delayed, the gated
    slab rises by δ = τ cos ϑ_c / n (ϑ_c the central ray's angle in the water), and its
    single-scattering return changes by

    .. math:: F(\delta) = \frac{\int_{(t-\delta)_+}^{(b-\delta)_+}
              e^{-2K\sec\vartheta_c z}dz}{\int_t^b e^{-2K\sec\vartheta_c z}dz},

    :math:`e^{2K\tau/n}` while the slab stays under the surface, less once the gate opens
    above it (the slab is cut at the surface), 0 if it closes before light reaches the
    water. Each path carries :math:`\sqrt{F}` (exact when the down and up delays are
    equal, as for the monostatic default), times the central ray's attenuation to the
    gate's plane: the gate, not the ray's own slant path, sets how deep the light is.

    Parameters
    ----------
    excess : ndarray
        Air path less the central ray's [m] (through the wavy surface: a crest shortens
        it, and the gate then holds less water: e^(−2Kη/n) for the round trip).
    setup : _Setup
        The scene.
    gate : int
        The gate's index.

    Returns
    -------
    ndarray
        The gain [1], float32, in place of the ray's own extra-path attenuation.
    """
    water = setup.water
    k, n, secant = water.diffuse_attenuation, water.refractive_index, setup.secant
    top, bottom = setup.gates[gate]
    excess = np.asarray(excess, dtype=np.float32)
    gain = np.exp(np.float32(k / n) * excess)
    rise = excess * np.float32(1.0 / (n * secant))
    cut = np.flatnonzero(rise > top)
    if cut.size:
        shifted = rise[cut].astype(np.float64)

        def slab(upper, lower):
            return slab_backscatter_reflectance(
                backscatter_pi=1 / np.pi,
                diffuse_attenuation=k * secant,
                top=upper,
                bottom=lower,
                reference=0.0,
            )

        share = slab(np.maximum(top - shifted, 0.0), np.maximum(bottom - shifted, 0.0))
        gain[cut] = np.sqrt(share / slab(top, bottom))
    depth = setup.reference_depths[gate]
    gain *= np.float32(np.exp(-k * depth * (secant - 1.0)))
    return gain


def _target_mask(silhouette: np.ndarray) -> np.ndarray:
    """Pixels the target covers: at least half, or the most covered if none reaches half.

    `silhouette` is the share of each pixel's line of sight inside the target's outline
    (the rasterised silhouette at the pixel's crossing of the target plane). A target
    smaller than a pixel still marks the pixel(s) it covers most, so a target in view
    never has an empty mask.
    """
    mask = silhouette >= 0.5
    if not mask.any() and silhouette.max(initial=0.0) > 0:
        mask = silhouette >= silhouette.max()
    return mask.astype(np.uint8)


def _render_frame(setup: _Setup, geometry: _FrameGeometry, surface, frame: int):
    n_w = setup.water.refractive_index
    K = setup.water.diffuse_attenuation
    down = _through_surface(geometry.laser_rays, surface, frame, n_w)
    if geometry.pixel_index is not None:
        up = down.take(geometry.pixel_index)
    else:
        up = _through_surface(geometry.pixel_rays, surface, frame, n_w)
    power = geometry.laser_power * down.transmittance

    down_excess = down.air - np.float32(geometry.central_air)
    up_excess = up.air - np.float32(geometry.central_air)
    axes_grid = (geometry.target_plane or geometry.gate_planes[0]).grid
    down_axes = down.on_axes(axes_grid, K)
    up_axes = up.on_axes(axes_grid, K)

    def sources(plane, rays, outside, ray_power):
        """The rays' power on the plane: fine splat, and the coarse light outside it."""
        fine = plane.grid.splat(rays, ray_power)
        coarse = None
        if plane.tail is not None:
            fine += plane.tail[0]
            coarse = plane.tail[1]
        if outside is not None:
            index, located = outside
            spilled = plane.levels.coarse.splat(located, ray_power[index])
            coarse = spilled if coarse is None else coarse + spilled
        return fine, coarse

    def sight_on(plane):
        located, extra, _ = up_axes.cross(plane.levels)
        return located, up.transmittance * extra

    pixels = setup.scene.receiver.pixels
    images = np.zeros((len(setup.gates), pixels * pixels), dtype=np.float32)
    mask = np.zeros(pixels * pixels, dtype=np.uint8)
    impostor = geometry.impostor
    lit = np.empty(0, dtype=np.intp)
    if impostor is not None:
        plane = geometry.target_plane
        grid = plane.grid
        rays, extra, outside = down_axes.cross(plane.levels)
        target_rays = rays
        sight, sight_weight = sight_on(plane)
        occupancy = grid.gather(impostor.occupancy, rays)
        surface_depth = grid.gather(impostor.surface_depth, rays)
        lit = np.flatnonzero(occupancy)
        mask = _target_mask(grid.gather(impostor.occupancy, sight))
        irradiance, beyond = plane.spread(*sources(plane, rays, outside, power * extra))
        light = geometry.target_light
        for (weights, coarse), gates in zip(light.weights, light.gates, strict=True):
            radiance, _ = plane.spread(
                irradiance * weights, None if coarse is None else beyond * coarse, far_out=False
            )
            seen = grid.gather(radiance, sight) * sight_weight
            for g in gates:
                images[g] += seen
    for g, plane in enumerate(geometry.gate_planes):
        rays, _, outside = down_axes.cross(plane.levels)
        sight, _, _ = up_axes.cross(plane.levels)
        ray_power = power * _gate_gain(down_excess, setup, g)
        if plane.bounds is not None and lit.size:
            # rays that meet the target lose the part of the slab behind it
            on_target = Located(target_rays.corners[:, lit], target_rays.weights[:, lit])
            top, bottom = (geometry.target_plane.grid.gather(b, on_target) for b in plane.bounds)
            hidden = _hidden_fraction(
                surface_depth[lit],
                occupancy[lit],
                top=top,
                bottom=bottom,
                diffuse_attenuation=K * setup.secant,
            )
            ray_power[lit] *= np.sqrt(np.maximum(1.0 - hidden, 0.0))
        radiance, _ = plane.spread(*sources(plane, rays, outside, ray_power), far_out=False)
        if plane.occlusion is not None:
            radiance *= plane.occlusion
        seen = plane.grid.gather(radiance, sight)
        seen *= up.transmittance * _gate_gain(up_excess, setup, g)
        images[g] += seen
    images *= np.float32(setup.scale)
    return images.reshape(len(setup.gates), pixels, pixels), mask.reshape(pixels, pixels)


@functools.lru_cache(maxsize=256)
def _visibility(key: str) -> tuple[int, ...]:
    r"""Label of the target against each gate, from what a flat sea's pixels would show.

    On the first frame's target plane under a flat sea, without blur, two sums run over the
    target's silhouette, in units of a white plane just under the surface:

    - the target's return in the gate, :math:`T = \sum w\,e^{-2K\sec\vartheta\,z_s}` over
      the cells whose surface depth z_s lies in the slab the cell's line of sight gates;
    - the gate's water the target hides, :math:`H = \sum o\,\pi\beta(\pi)\sec^2\vartheta
      \int_{\max(z_s, top)}^{bottom} e^{-2K\sec\vartheta\,z}dz`.

    The rule: no target, or no part of its silhouette in the image: ``none``; T > H (the
    target shows brighter than the water it hides): ``in_gate``; otherwise, if it hides
    any of the slab (geometrically, whatever β(π)): ``shadow``; else ``below_gate`` (its
    visible surface lies below the slab: the pixels show nothing of it).
    """
    setup = _setup(key)
    scene = setup.scene
    count = len(setup.gates)
    if scene.target.shape == "none":
        return (VISIBILITY["none"],) * count
    water = setup.water
    sensor = _sensor(setup, 0)
    grid = _fine_grid(sensor, scene.target.depth, water.refractive_index, guard=4, multiple=1)
    impostor = _impostor(setup, grid)
    sights = flat_sea_point(
        origin=sensor.position,
        direction=sensor.camera.pixel_directions().reshape(-1, 3),
        depth=grid.depth,
        refractive_index=water.refractive_index,
    )
    if not grid.gather(impostor.occupancy, grid.locate(sights[:, 0], sights[:, 1])).any():
        return (VISIBILITY["none"],) * count
    k = water.diffuse_attenuation * setup.secant
    cells = np.flatnonzero(impostor.occupancy)
    occupancy = impostor.occupancy.ravel()[cells].astype(np.float64)
    depth = impostor.surface_depth.ravel()[cells].astype(np.float64)
    weight = impostor.weight.ravel()[cells]
    sight = _sight(sensor, grid, water.refractive_index, cells)
    labels = []
    for paths in sensor.paths:
        top, bottom = _gate_bounds(sight, paths, water.refractive_index)
        inside = (depth >= top) & (depth <= bottom)
        shown = float(np.sum(weight * inside * np.exp(-2 * k * depth)))
        slab = setup.secant**2 * slab_backscatter_reflectance(
            backscatter_pi=1.0,
            diffuse_attenuation=k,
            top=np.clip(depth, top, np.maximum(bottom, top)),
            bottom=np.maximum(bottom, top),
            reference=0.0,
        )
        behind = float(np.sum(occupancy * slab))
        if shown > water.backscatter_pi * behind:
            labels.append(VISIBILITY["in_gate"])
        elif behind > 0:
            labels.append(VISIBILITY["shadow"])
        else:
            labels.append(VISIBILITY["below_gate"])
    return tuple(labels)


def sample_labels(scene: Scene) -> xr.Dataset:
    """The part of a sample fixed by its scene alone, whatever the seed.

    Parameters
    ----------
    scene : Scene
        The sample's parameters.

    Returns
    -------
    xarray.Dataset
        ``target_present`` (), ``target_visibility`` (gate) and the coordinates
        ``gate_top``, ``gate_bottom`` (gate), ``time`` and ``platform_x/y/z`` (frame).
    """
    setup = _setup(scene.model_dump_json())
    gates = np.asarray(setup.gates)
    times = np.arange(scene.sequence.frames) * scene.sequence.interval
    position = np.stack([_platform_position(scene, t) for t in times])
    data_vars = {
        "target_present": (
            (),
            np.uint8(scene.target.shape != "none"),
            {"long_name": "a target is in the scene", "units": "1"},
        ),
        "target_visibility": (
            ("gate",),
            np.asarray(_visibility(scene.model_dump_json()), dtype=np.uint8),
            {
                "long_name": "target position relative to the gate",
                "units": "1",
                "flag_values": np.arange(4, dtype=np.uint8),
                "flag_meanings": "none in_gate shadow below_gate",
            },
        ),
    }
    coords = {
        "gate_top": ("gate", gates[:, 0], {"long_name": "gate top depth", "units": "m"}),
        "gate_bottom": ("gate", gates[:, 1], {"long_name": "gate bottom depth", "units": "m"}),
        "time": ("frame", times, {"long_name": "time", "units": "s"}),
        "platform_x": ("frame", position[:, 0], {"long_name": "platform east", "units": "m"}),
        "platform_y": ("frame", position[:, 1], {"long_name": "platform north", "units": "m"}),
        "platform_z": ("frame", position[:, 2], {"long_name": "platform height", "units": "m"}),
    }
    return xr.Dataset(data_vars, coords=coords)


def _dataset(scene, expected, image, masks, surface):
    units = "1"
    if scene.radiometry.photoelectrons:
        units = "photoelectrons" if scene.noise.gain == 1.0 else "counts"
    frames = scene.sequence.frames
    ds = sample_labels(scene)
    ds["image"] = (
        ("frame", "gate", "y", "x"),
        image.astype(np.float32, copy=False),
        {"long_name": "gated receiver image with shot noise", "units": units},
    )
    ds["expected"] = (
        ("frame", "gate", "y", "x"),
        expected.astype(np.float32, copy=False),
        {
            "long_name": "expected (noise-free) gated receiver image",
            "units": "photoelectrons" if scene.radiometry.photoelectrons else "1",
        },
    )
    ds["target_mask"] = (
        ("frame", "y", "x"),
        masks.astype(np.uint8),
        {"long_name": "pixel ray meets the target silhouette", "units": "1"},
    )
    if scene.save_surface:
        n, spacing = scene.surface.grid_size, scene.surface.spacing
        elevation = (
            surface.elevation if surface is not None else np.zeros((frames, n, n), np.float32)
        )
        ds["surface_elevation"] = (
            ("frame", "sy", "sx"),
            elevation.astype(np.float32),
            {"long_name": "sea surface elevation", "units": "m"},
        )
        axis = np.arange(n) * spacing
        ds = ds.assign_coords(
            sx=("sx", axis, {"long_name": "surface grid east", "units": "m"}),
            sy=("sy", axis, {"long_name": "surface grid north", "units": "m"}),
        )
    return ds
