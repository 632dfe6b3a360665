"""A scene's setup and its sensor per frame: water, gates, scale, camera, laser, timing.

`scene_setup` holds what every sample of a scene shares, `sensor_at` the camera, the laser
and the gates' path lengths at a frame; lines of sight and the target's placement follow.
The model is in ``docs/model.md``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace

import numpy as np

from workers.backends.backend import Backend
from workers.optics.fresnel import fresnel_reflectance
from workers.optics.water import (
    WaterOptics,
    slab_backscatter_centroid,
    slab_backscatter_reflectance,
)
from workers.receiver.radiometry import photoelectrons_per_signal, pixel_solid_angle
from workers.sea.cascades import Sea, subgrid_slope_covariance
from workers.sea.surface import NUMPY, Surface, draw
from workers.settings.scene import Scene
from workers.settings.seeds import SampleSeed
from workers.setup.gates import central_paths, gate_gains, sight_lines, slab_bounds
from workers.setup.geometry import LaserRays, PinholeCamera, PlaneGrid, flat_sea_point
from workers.setup.seasetup import scene_sea, surface_kriging
from workers.targets.base import shape_named
from workers.targets.impostor import Impostor


@dataclass(frozen=True)
class Setup:
    """What every frame of every sample of a scene shares."""

    scene: Scene
    water: WaterOptics
    sea: Sea | None
    gates: tuple[tuple[float, float], ...]
    reference_depths: tuple[float, ...]
    reflectances: tuple[float, ...]
    scale: float
    refracted_nadir: float
    secant: float

    def surface(self, seed: SampleSeed, times, *, backend: Backend = NUMPY) -> Surface | None:
        """The sample's sea at `times` [s]: drawn, conditioned on the scene's data (None: flat).

        Cascade c draws from ``seed.surface_rng(c)``, the measurement noise of the
        conditioning from cascade 0's stream after its normals. The modes are drawn and
        conditioned on the host (the same sea on every backend), then evolved and
        transformed on `backend` (`workers.sea.surface.Modes.surface`), where the returned
        `Surface` keeps its fields and answers at points.
        """
        if self.sea is None:
            return None
        rngs = [seed.surface_rng(c) for c in range(len(self.sea.patches))]
        modes = draw(self.sea, rngs)
        conditioning = surface_kriging(self.scene.surface, self.sea)  # cached; built to render
        if conditioning is not None:
            modes = conditioning.condition(modes, rngs[0])
        return modes.surface(
            times, max_elevation=self.scene.surface.max_elevation, backend=backend
        )

    def gate_gain(self, excess, gate: int):
        """`workers.setup.gates.gate_gain` of this scene's gate number `gate` [1]."""
        return self.gate_gains(excess, (gate,))[0]

    def gate_gains(self, excess, gates=None):
        """`workers.setup.gates.gate_gain` of this scene's gates (default all), in a list [1]."""
        gates = range(len(self.gates)) if gates is None else gates
        return gate_gains(
            excess,
            diffuse_attenuation=self.water.diffuse_attenuation,
            refractive_index=self.water.refractive_index,
            secant=self.secant,
            slabs=[(*self.gates[g], self.reference_depths[g]) for g in gates],
        )


@functools.lru_cache(maxsize=32)
def scene_setup(scene: Scene) -> Setup:
    """What every frame of every sample of a scene shares (cached by the scene, hashable)."""
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
    scale = _signal_scale(scene)
    sea = scene_sea(scene)
    return Setup(
        scene=scene,
        water=water,
        sea=sea,
        gates=gates,
        reference_depths=references,
        reflectances=reflectances,
        scale=scale,
        refracted_nadir=refracted_nadir,
        secant=float(secant),
    )


def receiver_terms(scene: Scene) -> dict:
    """The lidar equation's instrument terms of `scene`, by their keyword names.

    Pulse energy [J], wavelength [m], receiver aperture diameter [m], optics transmission
    and quantum efficiency [1], and one pixel's solid angle [sr], as
    `workers.receiver.radiometry.lidar_equation` and `photoelectrons_per_signal` take them.
    """
    r = scene.radiometry
    return {
        "pulse_energy": r.pulse_energy,
        "wavelength": r.wavelength,
        "aperture_diameter": r.receiver_aperture,
        "optics_transmission": r.optics_transmission,
        "quantum_efficiency": r.quantum_efficiency,
        "solid_angle": pixel_solid_angle(
            field_of_view=np.radians(scene.receiver.field_of_view_deg),
            pixels=scene.receiver.pixels,
        ),
    }


def _signal_scale(scene: Scene) -> float:
    """The factor taking the raw signal to photoelectrons (or to white-plane units).

    Absolute: the lidar equation's photon budget for the Gaussian beam's whole pulse
    energy, whose 1/e half-width at the reference range (`frame_geometry`'s, the slant
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
        **receiver_terms(scene),
        beam_half_width=reference_range * np.tan(0.5 * laser_fov),
        refractive_index=n_w,
    )


@dataclass(frozen=True)
class Sensor:
    """Camera, laser and the flat-sea gate timing of one frame (no plane yet)."""

    position: np.ndarray
    camera: PinholeCamera
    laser_fov: float
    laser_rays: int
    reference_range: float
    lattice: tuple
    paths: np.ndarray
    offset: float

    @property
    def central_air(self) -> float:
        """Air path of the central ray to mean sea level [m]."""
        return float(self.position[2] / np.cos(self.camera.nadir))


def sensor_at(setup: Setup, frame: int, *, rays: int | None = None) -> Sensor:
    """Camera, laser and gate timing of `frame` (no plane yet).

    `rays` per side of the laser lattice: the scene's (`Scene.laser_rays`) when None.
    """
    scene = setup.scene
    rays = scene.laser_rays if rays is None else rays
    p, r = scene.platform, scene.receiver
    position = platform_position(scene, frame * scene.sequence.interval)
    camera = PinholeCamera(
        position=tuple(position),
        nadir=np.radians(p.nadir_deg),
        azimuth=np.radians(p.azimuth_deg),
        field_of_view=np.radians(r.field_of_view_deg),
        pixels=r.pixels,
    )
    laser_fov = float(np.radians(scene.laser.field_of_view_deg or r.field_of_view_deg))
    reference_range = p.altitude / np.cos(np.radians(p.nadir_deg))
    offset = lattice_offset(
        pixels=r.pixels,
        field_of_view=camera.field_of_view,
        rays=rays,
        laser_field_of_view=laser_fov,
    )
    lattice = LaserRays.central(
        position=position,
        rotation=camera.rotation,
        beam=scene.laser.beam,
        field_of_view=laser_fov,
        rays=rays,
        reference_range=reference_range,
        offset=offset,
    )
    paths = central_paths(
        altitude=float(position[2]),
        nadir=np.radians(p.nadir_deg),
        refractive_index=scene.water.refractive_index,
        gates=setup.gates,
    )
    return Sensor(
        position=position,
        camera=camera,
        laser_fov=laser_fov,
        laser_rays=rays,
        reference_range=reference_range,
        lattice=lattice,
        paths=paths,
        offset=offset,
    )


def lattice_offset(*, pixels, field_of_view, rays, laser_field_of_view) -> float:
    """Shift of the laser lattice that keeps it farthest from the pixels' lines [steps].

    Parameters
    ----------
    pixels : int
        Pixels per side of the image.
    field_of_view : float
        The receiver's full field [rad].
    rays : int
        Rays per side of the laser lattice across `laser_field_of_view`.
    laser_field_of_view : float
        The laser's full field [rad].

    Returns
    -------
    float
        The shift in [0, 1) of a ray step along both tangent axes
        (`workers.setup.geometry.LaserRays.from_platform`'s `offset`).

    Notes
    -----
    A pixel's line of sight that is a laser ray reads its own ray's light wherever the
    sea sends it, whose share of the pixel's bilinear read does not shrink with the ray
    count: the double passage is overestimated by a fixed bias (docs/model.md §3). The
    lines' positions in the lattice, modulo a step, are sorted and the lattice is moved
    to the middle of their largest gap: midway between the lines when the rays share
    their pitch (the default) or an odd multiple of it, and at the lines' midpoints for
    an even multiple.
    """
    pixel_step = 2.0 * np.tan(0.5 * field_of_view) / pixels
    ray_step = 2.0 * np.tan(0.5 * laser_field_of_view) / rays
    lines = (np.arange(pixels) + 0.5 - 0.5 * pixels) * pixel_step / ray_step + 0.5 * rays - 0.5
    phases = np.unique(np.round(np.mod(lines, 1.0), 9))
    gaps = np.diff(np.append(phases, phases[0] + 1.0))
    widest = int(np.argmax(gaps))
    return float(np.mod(phases[widest] + 0.5 * gaps[widest], 1.0))


def lines_of_sight(sensor: Sensor, grid: PlaneGrid, refractive_index: float, cells=None):
    """Air path and in-water cosine of the flat-sea line of sight to each cell (or `cells`)."""
    x, y = grid.cell_centres()
    if cells is not None:
        x, y = x.ravel()[cells], y.ravel()[cells]
    return sight_lines(
        position=sensor.position, x=x, y=y, depth=grid.depth, refractive_index=refractive_index
    )


def gate_bounds(sight, paths, refractive_index):
    """Gated depth bounds (top, bottom) [m] along lines of sight (`lines_of_sight`)."""
    air, cos_water = sight
    return slab_bounds(
        paths=paths, air=air, cos_water=cos_water, refractive_index=refractive_index
    )


def platform_position(scene: Scene, time: float) -> np.ndarray:
    """Platform position (x, y, z) at `time` [m]: over the origin at t = 0, then moving."""
    p = scene.platform
    nadir, azimuth = np.radians(p.nadir_deg), np.radians(p.azimuth_deg)
    reach = p.altitude * np.tan(nadir)
    start = np.array([-reach * np.sin(azimuth), -reach * np.cos(azimuth), p.altitude])
    return start + time * np.asarray(scene.sequence.velocity, dtype=float)


def central_point(sensor: Sensor, depth: float, n_w: float) -> np.ndarray:
    """World (x, y) where the laser lattice's central ray meets `depth` under a flat sea [m]."""
    origins, directions = sensor.lattice
    return flat_sea_point(
        origin=origins[:1], direction=directions[:1], depth=depth, refractive_index=n_w
    )[0, :2]


def sight_grid(sensor: Sensor, depth: float, n_w: float, *, guard: int) -> PlaneGrid:
    """A grid at `depth` whose nodes are the pixels' flat-sea lines of sight, a pixel apart.

    What is read per pixel at its own scale, whatever the laser lattice (`laser.rays` and
    its offset, `lattice_offset`): the target's mask and the view the target stops, each
    cell holding its pixel's footprint. `guard` cells on every side.
    """
    camera = sensor.camera
    lattice = LaserRays.central(
        position=sensor.position,
        rotation=camera.rotation,
        beam="divergent",
        field_of_view=camera.field_of_view,
        rays=camera.pixels,
        reference_range=sensor.reference_range,
    )
    grid = PlaneGrid.covering(
        camera=camera, lattice=lattice, depth=depth, refractive_index=n_w, guard=guard
    )
    line = flat_sea_point(
        origin=lattice[0][:1], direction=lattice[1][:1], depth=depth, refractive_index=n_w
    )[0, :2]
    origin = np.asarray(grid.origin, dtype=float)
    for axis, spacing in ((grid.axis_u, grid.spacing_u), (grid.axis_v, grid.spacing_v)):
        steps = (line - origin) @ axis / spacing
        origin = origin + (steps - np.round(steps)) * spacing * np.asarray(axis)
    return replace(grid, origin=(float(origin[0]), float(origin[1])))


def fine_grid(sensor: Sensor, depth: float, n_w: float, *, guard: int, multiple: int):
    """The camera's fine plane grid at `depth`, `guard` cells wider on each side."""
    return PlaneGrid.covering(
        camera=sensor.camera,
        lattice=sensor.lattice,
        depth=depth,
        refractive_index=n_w,
        guard=guard,
        multiple=multiple,
    )


def target_centre(setup: Setup, camera: PinholeCamera) -> tuple[float, float]:
    """World (x, y) of the target's centre: as given, or on the central ray [m]."""
    t = setup.scene.target
    if t.x is not None and t.y is not None:
        return float(t.x), float(t.y)
    centre = flat_sea_point(
        origin=platform_position(setup.scene, 0.0),
        direction=camera.rotation[2],
        depth=t.depth,
        refractive_index=setup.water.refractive_index,
    )
    return float(centre[0]), float(centre[1])


def gated_share_on(setup: Setup, grid: PlaneGrid, top, bottom, *, on, delays, shares):
    """The scene's target shape's `gated_share` on `grid`, or None.

    None where the shape has none (`workers.targets.base.TargetShape.gated_share`: a
    disk, or the paper's shading): a cell is then in a gate or not, by its line of sight's
    depth.
    """
    t = setup.scene.target
    return shape_named(t.shape).gated_share(
        grid=grid,
        target=t,
        centre=target_centre(setup, sensor_at(setup, 0).camera),
        refracted_nadir=setup.refracted_nadir,
        top=top,
        bottom=bottom,
        on=on,
        delays=delays,
        shares=shares,
    )


def subgrid_sway(setup: Setup, grid: PlaneGrid, *, distance: float) -> np.ndarray | None:
    r"""Where the sub-grid slopes move a line `distance` below where they tilt it.

    Parameters
    ----------
    setup : Setup
        The scene's setup (its sea and water).
    grid : PlaneGrid
        The plane whose axes the covariance is on.
    distance : float
        The water path d below the tilt [m]: a plane's depth for the lines of sight.

    Returns
    -------
    ndarray or None
        The (u, v) covariance [m²] of :math:`(1 - 1/n)\,d\,\mathbf s`, s the slopes
        below the finest grid (`workers.sea.cascades.subgrid_slope_covariance`): a facet of
        slope s tilts a line refracted into the water by about −(1 − 1/n)s. None over
        a flat sea.

    Notes
    -----
    A pixel looks through many cells of the finest grid, each with its own sub-grid
    slope (`workers.sea.surface.SubgridSlopes`), so it sees a point of the target blurred
    by this Gaussian; its one line of sight would instead read the target at one random
    displacement, the same one that sets its mask (`workers.dataset.labels.target_mask`), and
    keep the target's light inside the mask. The target's light and the view it stops
    are therefore read along the lines through the resolved sea and blurred by it, as
    the Monte Carlo renderer's way up does (docs/model.md §9). The scene's covariance is
    used (`surface.max_elevation`'s rescaling of a sample is not applied to it).
    """
    if setup.sea is None:
        return None
    reach = (1.0 - 1.0 / setup.water.refractive_index) * distance
    return reach**2 * grid.on_axes(subgrid_slope_covariance(setup.sea))


def impostor_on(setup: Setup, grid: PlaneGrid) -> Impostor:
    """The scene's target rasterised on `grid` (`workers.targets.base.TargetShape.impostor`)."""
    t = setup.scene.target
    camera = sensor_at(setup, 0).camera
    return shape_named(t.shape).impostor(
        grid=grid,
        target=t,
        centre=target_centre(setup, camera),
        refracted_nadir=setup.refracted_nadir,
    )
