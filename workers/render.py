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

from workers import montecarlo
from workers.gates import hidden_fraction
from workers.interface import Projected, through_surface
from workers.kernels import Cells, gather_levels, sample, span, splat_levels
from workers.labels import labelled_dataset, rendered_arrays, target_mask
from workers.noise import shot_noise
from workers.planes import FrameGeometry, Plane, frame_geometry
from workers.scene import Scene
from workers.seeds import SampleSeed
from workers.sensor import Setup, scene_setup

__all__ = ["render", "render_arrays", "render_images"]


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
        the signal means, the target's effect and ``target_visibility`` (frame, gate),
        ``target_present`` (), coordinates ``gate_top``, ``gate_bottom`` (gate), ``time``
        and the platform position (frame), and ``surface_elevation`` (frame, sy, sx)
        when ``scene.save_surface`` is set.
    """
    return labelled_dataset(scene, render_arrays(scene, seed=seed))


def render_arrays(scene: Scene, *, seed: int | SampleSeed) -> dict[str, np.ndarray]:
    """The rendered variables of `render`, as arrays, without the labels the scene fixes.

    What a store's task writes (`service.run.render_shard`): the same values as
    `render`'s, without building a dataset (about 1 ms a sample).

    A scene with a target is rendered twice: as it is, and as its target-free twin
    (`workers.scene.Scene.without_target`) on the same sea (the surface is drawn once)
    and, by Monte Carlo, the same photons, for the target's effect and its visibility
    labels (`workers.labels.target_effect`). The twin costs about a target-free sample's
    render (a target sample takes 1.6-1.9 times as long with the fast renderer, twice as
    long by Monte Carlo: ``docs/model.md`` §8); only its expected images are kept.

    Parameters
    ----------
    scene : Scene
        All parameters of the sample.
    seed : int or SampleSeed
        As for `render`.

    Returns
    -------
    dict
        `workers.labels.rendered_arrays`: ``image``, ``expected``, ``target_mask``,
        the signal means, the target's effect, ``target_visibility`` (and
        ``surface_elevation``).
    """
    seed = seed if isinstance(seed, SampleSeed) else SampleSeed(root=int(seed))
    surface, expected, masks, stderr, image = _render_sample(scene, seed)
    free = expected
    if scene.target.shape != "none":
        free = _render_frames(scene_setup(scene.without_target()), surface, seed)[0]
    return rendered_arrays(scene, expected, image, masks, surface, free=free, stderr=stderr)


def render_images(scene: Scene, *, seed: int | SampleSeed) -> tuple[np.ndarray, np.ndarray]:
    """A sample's noise-free and noisy images alone: `render_arrays`'s, without its twin.

    What `service.detect` renders again for a store without its ``expected`` images: the
    target-free twin, which a target sample's labels need, would cost it 0.6-1 times as
    much again.

    Parameters
    ----------
    scene : Scene
        All parameters of the sample.
    seed : int or SampleSeed
        As for `render`.

    Returns
    -------
    expected, image : ndarray, shape (frame, gate, y, x)
        The values of `render_arrays`'s ``expected`` and ``image`` (float32 here).
    """
    seed = seed if isinstance(seed, SampleSeed) else SampleSeed(root=int(seed))
    _, expected, _, _, image = _render_sample(scene, seed)
    return expected, image


def _render_sample(scene: Scene, seed: SampleSeed):
    """The sample's sea, expected images, masks, Monte Carlo error and noisy images."""
    setup = scene_setup(scene)
    surface = setup.surface(seed, np.arange(scene.sequence.frames) * scene.sequence.interval)
    expected, masks, stderr = _render_frames(setup, surface, seed)
    noise = scene.noise
    if scene.radiometry.photoelectrons:
        image = shot_noise(
            expected, rng=seed.noise_rng(), gain=noise.gain, excess_noise=noise.excess_noise
        )
    else:
        image = expected.copy()
    return surface, expected, masks, stderr, image


def _render_frames(setup: Setup, surface, seed: SampleSeed):
    """Every frame's expected image, (frame, gate, y, x), mask and Monte Carlo error.

    The error is None for the fast renderer (deterministic).
    """
    expected, masks, errors = [], [], []
    for frame in range(setup.scene.sequence.frames):
        if setup.scene.transport.method == "monte_carlo":
            transported = montecarlo.render_frame(setup, surface, frame, seed)
            signal, mask = transported.expected, transported.mask
            errors.append(transported.stderr)
        else:
            geometry = frame_geometry(setup.scene, frame)
            signal, mask = _render_frame(setup, geometry, surface, frame)
        expected.append(signal)
        masks.append(mask)
    return np.stack(expected), np.stack(masks), np.stack(errors) if errors else None


def _render_frame(setup: Setup, geometry: FrameGeometry, surface, frame: int):
    n_w = setup.water.refractive_index
    K = setup.water.diffuse_attenuation
    down = through_surface(geometry.laser_rays, surface, frame, n_w)
    axes_grid = (geometry.target_plane or geometry.gate_planes[0]).grid
    down_axes = down.on_axes(axes_grid, K)
    down_excess = down.air - np.float32(geometry.central_air)
    monostatic = geometry.pixel_block is not None
    if monostatic:
        # the pixels' lines of sight are laser rays: take them and their gains
        up_axes = down_axes.select(geometry.pixels)
        up_transmittance = geometry.pixels(down.transmittance)
    else:
        up = through_surface(geometry.pixel_rays, surface, frame, n_w)
        up_axes, up_transmittance = up.on_axes(axes_grid, K), up.transmittance
        up_excess = up.air - np.float32(geometry.central_air)
    power = geometry.laser_power * down.transmittance

    pixels = setup.scene.receiver.pixels
    images = np.zeros((len(setup.gates), pixels * pixels), dtype=np.float32)
    mask = np.zeros(pixels * pixels, dtype=np.uint8)
    impostor = geometry.impostor
    lit = np.empty(0, dtype=np.intp)
    if impostor is not None:
        plane = geometry.target_plane
        levels = plane.levels
        cells = Cells.of(levels)
        box = _support(impostor.occupancy)
        occupancy = _sample(down_axes, cells, (impostor.occupancy,), box)[0]
        lit = np.flatnonzero(occupancy)
        # the rays meeting the target, for its hiding of the gates' water
        on_target = down_axes.select(lambda values: values[lit])
        whole = (0, *levels.fine.shape[:1], 0, levels.fine.shape[1])
        surface_depth = _sample(on_target, cells, (impostor.surface_depth,), whole)[0]
        mask = target_mask(_sample(up_axes, cells, (impostor.occupancy,), box)[0])
        extra = down_axes.extra(levels.fine.depth)
        sight_extra = up_axes.extra(levels.fine.depth)
        light = geometry.target_light
        rows = light.rows
        wide = any(coarse is not None for _, coarse in light.weights)
        (fine, source, rows_in), window = _splat(
            plane, down_axes, power * extra, geometry.pixel_block
        )
        near, far, beyond = plane.spread.filtered(
            fine, source, rows_in=rows_in, rows_out=(rows, levels.coarse_rows(rows)), far_out=wide
        )
        if plane.tail is not None:
            near += plane.tail[0][rows]
            far += plane.tail[1]
            if wide:
                beyond += plane.tail[2]
        near += levels.upsample(far, rows=rows)
        inside = (rows, levels.coarse_rows(rows))
        for (weights, coarse), gates in zip(light.weights, light.gates, strict=True):
            fine[:] = 0.0
            np.multiply(near, weights[rows], out=fine[rows])
            source = levels.downsample(fine, rows)
            if coarse is not None:
                source += beyond * coarse
            seen = np.zeros(pixels * pixels, dtype=np.float32)
            rows_in = inside if coarse is None else (rows, slice(None))
            sources = (fine, source, rows_in)
            _gather(plane, up_axes, sources, up_transmittance * sight_extra, seen, window=window)
            for g in gates:
                images[g] += seen
    down_gains = setup.gate_gains(down_excess)
    up_gains = None if monostatic else setup.gate_gains(up_excess)
    for g, plane in enumerate(geometry.gate_planes):
        gain = down_gains[g]
        ray_power = power * gain
        if plane.bounds is not None and lit.size:
            # rays that meet the target lose the part of the slab behind it
            top, bottom = _sample(on_target, cells, plane.bounds, whole)
            hidden = hidden_fraction(
                surface_depth,
                occupancy[lit],
                top=top,
                bottom=bottom,
                diffuse_attenuation=K * setup.secant,
            )
            ray_power[lit] *= np.sqrt(np.maximum(1.0 - hidden, 0.0))
        up_gain = geometry.pixels(gain) if monostatic else up_gains[g]
        weight = up_transmittance * up_gain
        sources, window = _splat(plane, down_axes, ray_power, geometry.pixel_block)
        _gather(
            plane,
            up_axes,
            sources,
            weight,
            images[g],
            window=window,
            tail=plane.tail,
            occlusion=plane.occlusion,
        )
    # the near and far parts of a spread each ring a little below zero where almost no
    # light lands; their sum is light, never negative
    np.maximum(images, 0.0, out=images)
    images *= np.float32(setup.scale)
    return images.reshape(len(setup.gates), pixels, pixels), mask.reshape(pixels, pixels)


def _splat(plane: Plane, rays: Projected, power: np.ndarray, pixels=None):
    """Rays onto a plane: its fine field, the coarse source of its far spread, their rows.

    With `pixels` (`FrameGeometry.pixel_block`: the pixels' lines of sight are a block of
    the rays), also the pixels' window on the fine grid (`workers.kernels.span`), found in
    the same pass; else None.
    """
    levels = plane.levels
    fine = np.zeros(levels.fine.shape, dtype=np.float32)
    source = np.zeros(levels.coarse.shape, dtype=np.float32)
    grids = (levels.fine, levels.coarse)
    densities = tuple(np.float32(1.0 / (g.spacing_u * g.spacing_v)) for g in grids)
    block = tuple(b.start for b in levels.block)
    side, lines = pixels if pixels is not None else (0, slice(0, 0))
    spans = splat_levels(
        rays.lines,
        power,
        Cells.of(levels),
        densities,
        fine,
        source,
        block,
        (side, lines.start, lines.stop),
    )
    window = spans[4:] if pixels is not None else None
    return (fine, source, (slice(*spans[:2]), slice(*spans[2:4]))), window


_NONE = np.zeros((0, 0), dtype=np.float32)


def _gather(plane, sight, sources, weight, out, *, window=None, tail=None, occlusion=None):
    """Spread light on a plane and add it, times `weight`, at the pixels' sights to `out`.

    `sources` is ``(fine, source, rows)`` as from `_splat`; the light of the beam's `tail`
    (`Plane.tail`) is added to the spread. Only the rows that the sights reach (their
    `window`, `workers.kernels.span`: found here when None) are brought back from the
    spectra.
    """
    levels = plane.levels
    cells, shape = Cells.of(levels), plane.grid.shape
    fine, source, rows_in = sources
    if window is None:
        window = span(sight.lines, cells, shape)
    rows = slice(*window[:2])
    near, far, _ = plane.spread.filtered(
        fine, source, rows_in=rows_in, rows_out=(rows, levels.coarse_rows(rows))
    )
    tails = (_NONE, _NONE) if tail is None else tail[:2]
    occlusion = _NONE if occlusion is None else occlusion
    parts = (near, window, far, tails)
    gather_levels(sight.lines, cells, shape, parts, levels.lift, occlusion, weight, out)


def _sample(rays: Projected, cells: Cells, fields, box) -> np.ndarray:
    """`workers.kernels.sample`: the fields at the rays, shape (len(fields), rays)."""
    out = np.empty((len(fields), rays.base_u.size), dtype=np.float32)
    sample(rays.lines, cells, tuple(fields), box, out)
    return out


def _support(field: np.ndarray) -> tuple[int, int, int, int]:
    """First row, last row + 1, first column, last column + 1 of a field's non-zero cells."""
    rows, cols = (np.flatnonzero(field.any(axis=axis)) for axis in (1, 0))
    if not rows.size:
        return 0, 0, 0, 0
    return int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
