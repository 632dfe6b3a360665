"""Render one sample: a sea-surface realisation seen by the gated receivers.

`render` is the seam between the physics and the service: it returns one sample as an
`xarray.Dataset` holding exactly the variables of one ``sample`` of the store
(``../shared/DESIGN.md`` §4), without the ``sample`` dimension.

The image-formation model (DESIGN §3.5), per frame:

1. Laser rays and pixel rays are intersected with the real surface, refracted (Snell) and
   weighted by the Fresnel transmittance.
2. Each gate is a slab [top, bottom]. Its single-scattering water backscatter is an
   effective Lambertian reflectance on a reference plane at the slab's centroid depth.
   Laser rays are splatted where they cross that plane (each with the attenuation of its
   extra slant path), convolved with the Wells point-spread function twice (down, then up:
   one product with MTF² in Fourier space), and gathered where each pixel's ray crosses
   the plane, times the exit transmittance.
3. The target is an impostor on the plane through its centre: downwelling irradiance there
   (one MTF) times its reflectance map, restricted to the part of the target inside the
   gate, spread up (one MTF) and gathered.
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
while attenuation follows each ray's slant path; a gate's volume return uses the refracted
central ray's angle for its 1/cos²ϑ gain and slant attenuation.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import scipy.fft
import xarray as xr

from workers.conditioning import Kriging
from workers.geometry import LaserRays, PinholeCamera, PlaneGrid, flat_sea_point
from workers.noise import shot_noise
from workers.optics import fresnel_reflectance
from workers.radiometry import photoelectrons_per_signal, pixel_solid_angle
from workers.scene import Scene
from workers.seeds import SampleSeed
from workers.surface import synthesize
from workers.target import Impostor
from workers.water import (
    WaterOptics,
    slab_backscatter_centroid,
    slab_backscatter_reflectance,
)

__all__ = ["render", "sample_labels"]

GUARD = 0.125
"""Guard band added on each side of an in-water plane, as a fraction of the image size."""

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
    visibility: tuple[int, ...]


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
    # Seen at an angle ϑ in the water, a slab's volume return grows as 1/cos²ϑ (the normal
    # irradiance is E/cosϑ and the path through dz is dz/cosϑ) and fades as e^(-2Kz/cosϑ).
    secant = 1.0 / np.cos(refracted_nadir)
    K = water.diffuse_attenuation * secant
    references = tuple(
        slab_backscatter_centroid(diffuse_attenuation=K, top=top, bottom=bottom)
        for top, bottom in gates
    )
    reflectances = tuple(
        secant**2
        * slab_backscatter_reflectance(
            backscatter_pi=water.backscatter_pi,
            diffuse_attenuation=K,
            top=top,
            bottom=bottom,
            reference=reference,
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
        visibility=tuple(
            _visibility(scene, top, bottom, refracted_nadir=refracted_nadir)
            for top, bottom in gates
        ),
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


def _visible_extent(scene: Scene, *, refracted_nadir: float):
    """Depths of the target's surface that the sensor sees (its lit, upper side) [m].

    A sphere viewed along the refracted central ray shows the cap facing it: from its top,
    d - r, down to d + r sin ϑ at its limb. A disk lies at its depth.
    """
    t = scene.target
    if t.shape == "sphere":
        return t.depth - t.radius, t.depth + t.radius * np.sin(refracted_nadir)
    return t.depth, t.depth


def _visibility(scene: Scene, top: float, bottom: float, *, refracted_nadir: float) -> int:
    """Label of the target against a gate: none, in the gate, shadowing it, or below it.

    "In the gate" means part of the target's visible surface lies in the slab; a target
    whose visible surface lies above the slab shadows it (even where its far side reaches
    into the slab, that side is dark and hides the water behind it).
    """
    if scene.target.shape == "none":
        return VISIBILITY["none"]
    upper, lower = _visible_extent(scene, refracted_nadir=refracted_nadir)
    if lower < top:
        return VISIBILITY["shadow"]
    if upper > bottom:
        return VISIBILITY["below_gate"]
    return VISIBILITY["in_gate"]


@dataclass(frozen=True)
class _Plane:
    """An in-water plane with its Fourier filter and, for gates, the target's occlusion.

    `filter` is the whole round trip for a gate plane (reflectance × MTF², down and up) and
    one way (MTF) for the target plane. Where the target hides part of a gate's water,
    `hiding` names the slab whose backscatter rays lose behind the target (gates the
    target shadows whole share the key ``"shadow"``, so one computation per sample), and
    `occlusion` (on this plane's grid) is the square root of the fraction not hidden, seen
    back through the upwelling point-spread function.
    """

    grid: PlaneGrid
    depth: float
    filter: np.ndarray
    hiding: tuple | None = None
    occlusion: np.ndarray | None = None


@dataclass(frozen=True)
class _FrameGeometry:
    """Geometry of one frame: sensor rays, planes, filters and the target impostor."""

    position: np.ndarray
    pixel_rays: tuple
    laser_rays: tuple
    laser: LaserRays
    monostatic: bool
    gate_planes: tuple[_Plane, ...]
    target_plane: _Plane | None
    impostor: Impostor | None
    target_masks: tuple[np.ndarray | None, ...]


def _platform_position(scene: Scene, time: float) -> np.ndarray:
    p = scene.platform
    nadir, azimuth = np.radians(p.nadir_deg), np.radians(p.azimuth_deg)
    reach = p.altitude * np.tan(nadir)
    start = np.array([-reach * np.sin(azimuth), -reach * np.cos(azimuth), p.altitude])
    return start + time * np.asarray(scene.sequence.velocity, dtype=float)


@functools.lru_cache(maxsize=64)
def _frame_geometry(key: str, frame: int) -> _FrameGeometry:
    setup = _setup(key)
    scene = setup.scene
    p, r, n_w = scene.platform, scene.receiver, scene.water.refractive_index
    position = _platform_position(scene, frame * scene.sequence.interval)
    camera = PinholeCamera(
        position=tuple(position),
        nadir=np.radians(p.nadir_deg),
        azimuth=np.radians(p.azimuth_deg),
        field_of_view=np.radians(r.field_of_view_deg),
        pixels=r.pixels,
    )
    laser_fov = np.radians(scene.laser.field_of_view_deg or r.field_of_view_deg)
    rays = scene.laser_rays
    reference_range = p.altitude / np.cos(np.radians(p.nadir_deg))
    laser = LaserRays.from_platform(
        position=position,
        rotation=camera.rotation,
        beam=scene.laser.beam,
        field_of_view=laser_fov,
        rays=rays,
        reference_range=reference_range,
    )
    lattice = laser.central()
    laser = LaserRays(
        origins=np.ascontiguousarray(laser.origins, dtype=np.float32),
        directions=np.ascontiguousarray(laser.directions, dtype=np.float32),
        power=laser.power.astype(np.float32),
        rays=rays,
    )
    # The default laser (divergent, the receiver's field, one ray per pixel) shares the
    # pixels' lattice of directions: its rays are the pixels' lines of sight, traced once.
    monostatic = bool(
        scene.laser.beam == "divergent" and rays == r.pixels and laser_fov == camera.field_of_view
    )
    water = setup.water

    def grid_and_mtf(depth):
        grid = PlaneGrid.covering(
            camera=camera, lattice=lattice, depth=depth, refractive_index=n_w, guard=GUARD
        )
        return grid, water.mtf(grid.frequency(), distance=depth).astype(np.float32)

    t = scene.target
    pixel_directions = camera.pixel_directions().reshape(-1, 3).astype(np.float32)
    target_plane = impostor = None
    masks = (None,) * len(setup.gates)
    if t.shape != "none":
        grid, mtf = grid_and_mtf(t.depth)
        target_plane = _Plane(grid=grid, depth=t.depth, filter=mtf)
        if t.x is None or t.y is None:
            centre = flat_sea_point(
                origin=_platform_position(scene, 0.0),
                direction=camera.rotation[2],
                depth=t.depth,
                refractive_index=n_w,
            )[:2]
        else:
            centre = (t.x, t.y)
        impostor = Impostor.build(
            grid=target_plane.grid,
            shape=t.shape,
            centre=(float(centre[0]), float(centre[1])),
            radius=t.radius,
            reflectance=t.reflectance,
            shading=t.shading,
            refracted_nadir=setup.refracted_nadir,
        )
        masks = _target_masks(setup, impostor)
    gate_planes = []
    for (top, bottom), depth, reflectance, visibility in zip(
        setup.gates, setup.reference_depths, setup.reflectances, setup.visibility, strict=True
    ):
        grid, mtf = grid_and_mtf(depth)
        filter_ = (np.float32(reflectance) * mtf * mtf).astype(np.float32)
        if impostor is None or visibility == VISIBILITY["below_gate"]:
            gate_planes.append(_Plane(grid=grid, depth=depth, filter=filter_))
            continue
        # The line of sight through a gate-plane cell crossed the target plane nearer the
        # platform, by the depth difference times the tangent of the in-water angle.
        x, y = grid.cell_centres()
        back = (depth - t.depth) * np.tan(setup.refracted_nadir)
        located = target_plane.grid.locate(x + back * grid.axis_v[0], y + back * grid.axis_v[1])
        hidden = _hidden_fraction(
            target_plane.grid.gather(impostor.surface_depth, located),
            target_plane.grid.gather(impostor.occupancy, located),
            top=top,
            bottom=bottom,
            diffuse_attenuation=water.diffuse_attenuation,
        )
        occlusion = _convolve(np.sqrt(np.maximum(1.0 - hidden, 0.0)), mtf / mtf[0, 0])
        gate_planes.append(
            _Plane(
                grid=grid,
                depth=depth,
                filter=filter_,
                hiding=("shadow",) if visibility == VISIBILITY["shadow"] else (top, bottom),
                occlusion=occlusion.astype(np.float32),
            )
        )
    return _FrameGeometry(
        position=position,
        pixel_rays=_ray_components(position, pixel_directions),
        laser_rays=_ray_components(laser.origins, laser.directions),
        laser=laser,
        monostatic=monostatic,
        gate_planes=tuple(gate_planes),
        target_plane=target_plane,
        impostor=impostor,
        target_masks=masks,
    )


def _target_masks(setup: _Setup, impostor: Impostor) -> tuple[np.ndarray | None, ...]:
    """Reflectance of the part of the target inside each gate (None: nothing inside).

    Gates that cut the target the same way share one array, and so one convolution per
    sample.
    """
    masks, by_span = [], {}
    for top, bottom in setup.gates:
        span = (max(top, impostor.top), min(bottom, impostor.bottom))
        if span not in by_span:
            inside = (impostor.surface_depth >= top) & (impostor.surface_depth <= bottom)
            weight = np.where(inside, impostor.weight, 0.0).astype(np.float32)
            by_span[span] = weight if weight.any() else None
        masks.append(by_span[span])
    return tuple(masks)


@dataclass(frozen=True)
class _Transmitted:
    """Rays after the surface: entry point, in-water slopes, Fresnel transmittance."""

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    tan_x: np.ndarray
    tan_y: np.ndarray
    secant: np.ndarray
    transmittance: np.ndarray

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

    def cross(self, grid: PlaneGrid):
        """Located rays on `grid` (at its depth) and their extra-path attenuation."""
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
        return grid.locate_cells(row, col), np.exp(extra, out=extra)


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
        x=np.asarray(ox + travel * dx, dtype=np.float32),
        y=np.asarray(oy + travel * dy, dtype=np.float32),
        z=np.asarray(eta, dtype=np.float32),
        tan_x=np.where(facing, (ratio * dx - coefficient * sx) * secant, 0.0).astype(np.float32),
        tan_y=np.where(facing, (ratio * dy - coefficient * sy) * secant, 0.0).astype(np.float32),
        secant=secant.astype(np.float32),
        transmittance=np.where(facing, transmittance, 0.0).astype(np.float32),
    )


def _hidden_fraction(surface_depth, occupancy, *, top, bottom, diffuse_attenuation):
    """Fraction of a slab's backscatter lying behind the target along each line.

    Lines through the target's silhouette (weighted by `occupancy`) lose the part of the
    single-scattering integral deeper than the target's surface.
    """
    behind = np.clip(surface_depth, top, bottom)

    def slab(upper):
        return slab_backscatter_reflectance(
            backscatter_pi=1.0,
            diffuse_attenuation=diffuse_attenuation,
            top=upper,
            bottom=bottom,
            reference=top,
        )

    return (occupancy * (slab(behind) / slab(top))).astype(np.float32)


def _convolve(field, kernel):
    """Periodic convolution: the field times a filter given on its rfft2 grid."""
    return scipy.fft.irfft2(scipy.fft.rfft2(field) * kernel, s=field.shape)


def _render_frame(setup: _Setup, geometry: _FrameGeometry, surface, frame: int):
    n_w = setup.water.refractive_index
    K = setup.water.diffuse_attenuation
    laser = geometry.laser
    down = _through_surface(geometry.laser_rays, surface, frame, n_w)
    if geometry.monostatic:
        up = down
    else:
        up = _through_surface(geometry.pixel_rays, surface, frame, n_w)
    power = laser.power * down.transmittance

    axes_grid = (geometry.target_plane or geometry.gate_planes[0]).grid
    down_axes = down.on_axes(axes_grid, K)
    up_axes = down_axes if up is down else up.on_axes(axes_grid, K)

    def crossing(plane):
        """Rays and lines of sight on a plane: (rays, sight, ray power, sight weight)."""
        rays, lextra = down_axes.cross(plane.grid)
        if up is down:
            return rays, rays, power * lextra, up.transmittance * lextra
        sight, pextra = up_axes.cross(plane.grid)
        return rays, sight, power * lextra, up.transmittance * pextra

    pixels = setup.scene.receiver.pixels
    images = np.zeros((len(setup.gates), pixels * pixels), dtype=np.float32)
    mask = np.zeros(pixels * pixels, dtype=np.uint8)
    impostor = geometry.impostor
    if impostor is not None:
        plane = geometry.target_plane
        grid = plane.grid
        rays, sight, ray_power, sight_weight = crossing(plane)
        occupancy = grid.gather(impostor.occupancy, rays)
        surface_depth = grid.gather(impostor.surface_depth, rays)
        silhouette = occupancy if sight is rays else grid.gather(impostor.occupancy, sight)
        mask = (silhouette > 0.5).astype(np.uint8)
        irradiance = _convolve(grid.splat(rays, ray_power), plane.filter)
        done = {}
        for g, weights in enumerate(geometry.target_masks):
            if weights is None:
                continue
            if id(weights) not in done:
                radiance = _convolve(irradiance * weights, plane.filter)
                done[id(weights)] = grid.gather(radiance, sight) * sight_weight
            images[g] += done[id(weights)]
    transmitted = {}
    for g, plane in enumerate(geometry.gate_planes):
        rays, sight, ray_power, sight_weight = crossing(plane)
        if plane.hiding is not None:
            if plane.hiding not in transmitted:
                # rays lose the part of the slab behind the target (all of it, in its
                # shadow); only rays that meet the target's silhouette lose anything
                if "lit" not in transmitted:
                    transmitted["lit"] = np.flatnonzero(occupancy)
                lit = transmitted["lit"]
                hidden = occupancy[lit]
                if plane.hiding != ("shadow",):
                    top, bottom = plane.hiding
                    hidden = _hidden_fraction(
                        surface_depth[lit], hidden, top=top, bottom=bottom, diffuse_attenuation=K
                    )
                factor = np.ones_like(occupancy)
                factor[lit] = np.sqrt(np.maximum(1.0 - hidden, 0.0))
                transmitted[plane.hiding] = factor
            ray_power *= transmitted[plane.hiding]
        radiance = _convolve(plane.grid.splat(rays, ray_power), plane.filter)
        if plane.occlusion is not None:
            radiance *= plane.occlusion
        images[g] += plane.grid.gather(radiance, sight) * sight_weight
    images *= np.float32(setup.scale)
    return images.reshape(len(setup.gates), pixels, pixels), mask.reshape(pixels, pixels)


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
            np.asarray(setup.visibility, dtype=np.uint8),
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
