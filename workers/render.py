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
   pixel, from its air path (`gate_gain`): a ray longer in the air gates a shallower slab.
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

import numpy as np
import xarray as xr

from workers.gates import hidden_fraction
from workers.geometry import Located
from workers.interface import through_surface
from workers.labels import labelled_dataset, sample_labels, target_mask
from workers.noise import shot_noise
from workers.planes import FrameGeometry, frame_geometry
from workers.scene import Scene
from workers.seeds import SampleSeed
from workers.sensor import Setup, scene_setup
from workers.surface import synthesize

__all__ = ["render", "sample_labels"]


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
    setup = scene_setup(scene)
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
            conditioning=scene.surface.kriging(),  # cached; None without points
        )
    expected = []
    masks = []
    for frame in range(frames):
        geometry = frame_geometry(scene, frame)
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
    return labelled_dataset(scene, expected, image, np.stack(masks), surface)


def _render_frame(setup: Setup, geometry: FrameGeometry, surface, frame: int):
    n_w = setup.water.refractive_index
    K = setup.water.diffuse_attenuation
    down = through_surface(geometry.laser_rays, surface, frame, n_w)
    if geometry.pixel_index is not None:
        up = down.take(geometry.pixel_index)
    else:
        up = through_surface(geometry.pixel_rays, surface, frame, n_w)
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
        mask = target_mask(grid.gather(impostor.occupancy, sight))
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
        ray_power = power * setup.gate_gain(down_excess, g)
        if plane.bounds is not None and lit.size:
            # rays that meet the target lose the part of the slab behind it
            on_target = Located(target_rays.corners[:, lit], target_rays.weights[:, lit])
            top, bottom = (geometry.target_plane.grid.gather(b, on_target) for b in plane.bounds)
            hidden = hidden_fraction(
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
        seen *= up.transmittance * setup.gate_gain(up_excess, g)
        images[g] += seen
    # the near and far parts of a spread each ring a little below zero where almost no
    # light lands; their sum is light, never negative
    np.maximum(images, 0.0, out=images)
    images *= np.float32(setup.scale)
    return images.reshape(len(setup.gates), pixels, pixels), mask.reshape(pixels, pixels)
