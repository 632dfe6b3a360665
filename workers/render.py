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
   there times its reflectance map, lit and attenuated at each cell's true depth on the
   target (not at the centre plane), restricted to each cell's share of the return inside
   the gate (on time and delayed by scattering), spread up and gathered.
4. Where a pixel's line of sight meets the target, the water behind the target is
   neither lit nor seen: the slab's backscatter loses the fraction lying behind the
   target's surface, half on the way down and half on the way up (square roots), each
   blurred by small-angle scattering around the target (`workers.shadows`): exact
   without scattering, a full shadow when the target is above the gate.
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
from workers.interface import Projected, through_surface
from workers.kernels import Cells, gather_levels, sample, span, splat_levels
from workers.labels import labelled_dataset, rendered_arrays, target_mask
from workers.noise import shot_noise
from workers.planes import FrameGeometry, Plane, frame_geometry
from workers.scene import Scene
from workers.seeds import SampleSeed
from workers.sensor import Setup, scene_setup

__all__ = ["render", "render_arrays", "render_images", "render_pair"]


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

    A scene with a target yields its target-free twin (`workers.scene.Scene.without_target`)
    on the same sea too, for the target's effect and its visibility labels
    (`workers.labels.target_effect`): the fast renderer reads the same spread light a
    second time without the target's light and shadow (in the same pass, bit for bit the
    twin rendered apart); by Monte Carlo it is a second transport of the same photons
    (twice the time: ``docs/model.md`` §8). Only its expected images are kept.

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
    surface, expected, masks, stderr, free, image = _render_sample(scene, seed)
    if scene.target.shape == "none":
        free = expected
    elif free is None:  # Monte Carlo: the twin's own photons, the same streams
        free = _render_frames(scene_setup(scene.without_target()), surface, seed)[0]
    return rendered_arrays(scene, expected, image, masks, surface, free=free, stderr=stderr)


def render_images(scene: Scene, *, seed: int | SampleSeed) -> tuple[np.ndarray, np.ndarray]:
    """A sample's noise-free and noisy images alone: `render_arrays`'s, without its twin.

    What `service.detect` renders again for a store without its ``expected`` images: the
    labels, which need the target-free twin (by Monte Carlo a second transport), are not
    rendered again.

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
    _, expected, _, _, _, image = _render_sample(scene, seed)
    return expected, image


def render_pair(
    scene: Scene, *, seed: SampleSeed, twin_seed: SampleSeed
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """A sample's images and those of its target-free twin at another point, in one render.

    What `service.detect` renders again for a point with a target and its target-free
    point (`Scene.without_target`) of the same realisation: the fast renderer gathers the
    twin's light in the same pass (`render_arrays`'s target effect), on the same sea, so
    the twin's expected images are those of the target-free point's own render; its
    noise is drawn with `twin_seed` (the target-free point's streams).

    Parameters
    ----------
    scene : Scene
        All parameters of the sample, with a target.
    seed, twin_seed : SampleSeed
        The sample's and its twin's, of the same realisation (the same sea).

    Returns
    -------
    tuple of ndarray or None
        ``expected, image, twin_expected, twin_image``, each (frame, gate, y, x) as
        `render_images`'s; None when the renderer makes no twin (no target, Monte Carlo).
    """
    if seed.root != twin_seed.root or seed.realisation != twin_seed.realisation:
        raise ValueError("a twin is of the same root seed and realisation (the same sea)")
    _, expected, _, _, free, image = _render_sample(scene, seed)
    if free is None:
        return None
    return expected, image, free, _noisy(scene, free, twin_seed)


def _render_sample(scene: Scene, seed: SampleSeed):
    """The sample's sea, expected images, masks, Monte Carlo error, twin and noisy images."""
    setup = scene_setup(scene)
    surface = setup.surface(seed, np.arange(scene.sequence.frames) * scene.sequence.interval)
    expected, masks, stderr, free = _render_frames(setup, surface, seed)
    return surface, expected, masks, stderr, free, _noisy(scene, expected, seed)


def _noisy(scene: Scene, expected: np.ndarray, seed: SampleSeed) -> np.ndarray:
    """The noisy images of `expected` [photoelectrons] with the noise streams of `seed`."""
    noise = scene.noise
    if scene.radiometry.photoelectrons:
        return shot_noise(
            expected, rng=seed.noise_rng(), gain=noise.gain, excess_noise=noise.excess_noise
        )
    return expected.copy()


def _render_frames(setup: Setup, surface, seed: SampleSeed):
    """Every frame's expected image, (frame, gate, y, x), mask, Monte Carlo error and twin.

    The error is None for the fast renderer (deterministic). The twin, the expected image
    without the target, comes with the fast renderer's when there is a target (the same
    spread light gathered without the target's light and shadow); None otherwise.
    """
    expected, masks, errors, twins = [], [], [], []
    for frame in range(setup.scene.sequence.frames):
        if setup.scene.transport.method == "monte_carlo":
            transported = montecarlo.render_frame(setup, surface, frame, seed)
            signal, mask = transported.expected, transported.mask
            errors.append(transported.stderr)
        else:
            geometry = frame_geometry(setup.scene, frame)
            signal, mask, twin = _render_frame(setup, geometry, surface, frame)
            if twin is not None:
                twins.append(twin)
        expected.append(signal)
        masks.append(mask)
    stack = [np.stack(values) if values else None for values in (errors, twins)]
    return np.stack(expected), np.stack(masks), *stack


def _render_frame(setup: Setup, geometry: FrameGeometry, surface, frame: int):
    n_w = setup.water.refractive_index
    K = setup.water.diffuse_attenuation
    down = through_surface(geometry.laser_rays, surface, frame, n_w)
    axes_grid = (geometry.target_plane or geometry.gate_planes[0]).grid
    down_axes = down.on_axes(axes_grid, K)
    down_excess = down.air - np.float32(geometry.central_air)
    # the pixels' lines of sight are never laser rays (`workers.sensor.lattice_offset`)
    up = through_surface(geometry.pixel_rays, surface, frame, n_w)
    up_axes, up_transmittance = up.on_axes(axes_grid, K), up.transmittance
    up_excess = up.air - np.float32(geometry.central_air)
    power = geometry.laser_power * down.transmittance

    pixels = setup.scene.receiver.pixels
    images = np.zeros((len(setup.gates), pixels * pixels), dtype=np.float32)
    free = np.zeros_like(images) if geometry.impostor is not None else None
    mask = np.zeros(pixels * pixels, dtype=np.uint8)
    impostor = geometry.impostor
    if impostor is not None:
        plane = geometry.target_plane
        levels = plane.levels
        cells = Cells.of(levels)
        sight_cells = geometry.sight_cells
        occupancy = geometry.sight_occupancy
        mask = target_mask(_sample(up_axes, sight_cells, (occupancy,), _support(occupancy))[0])
        extra = down_axes.extra(levels.fine.depth)
        sight_extra = up_axes.extra(levels.fine.depth)
        light = geometry.target_light
        rows = light.rows
        wide = any(coarse is not None for _, coarse in light.weights)
        fine, source, rows_in = _splat(plane, down_axes, power * extra)
        window = span(up_axes.lines, cells, levels.fine.shape)
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
            weight = up_transmittance * sight_extra
            _gather(plane, up_axes, sources, ((weight, seen, None),), window=window)
            for g in gates:
                images[g] += seen
    down_gains = setup.gate_gains(down_excess)
    up_gains = setup.gate_gains(up_excess)
    for g, plane in enumerate(geometry.gate_planes):
        gain = down_gains[g]
        ray_power = power * gain
        weight = up_transmittance * up_gains[g]
        outputs = [(weight, free[g], None)] if impostor is not None else []
        if plane.seen is not None:
            # the pixels whose lines of sight the target stops, where they cross it
            whole = (0, *plane.seen.shape[:1], 0, plane.seen.shape[1])
            weight = weight * (1.0 - _sample(up_axes, sight_cells, (plane.seen,), whole)[0])
        outputs.append((weight, images[g], plane.occlusion))
        _gather(plane, up_axes, _splat(plane, down_axes, ray_power), outputs, tail=plane.tail)
    # the near and far parts of a spread each ring a little below zero where almost no
    # light lands; their sum is light, never negative
    shape = (len(setup.gates), pixels, pixels)
    for values in (images,) if free is None else (images, free):
        np.maximum(values, 0.0, out=values)
        values *= np.float32(setup.scale)
    twin = None if free is None else free.reshape(shape)
    return images.reshape(shape), mask.reshape(pixels, pixels), twin


def _splat(plane: Plane, rays: Projected, power: np.ndarray):
    """Rays onto a plane: its fine field, the coarse source of its far spread, their rows."""
    levels = plane.levels
    fine = np.zeros(levels.fine.shape, dtype=np.float32)
    source = np.zeros(levels.coarse.shape, dtype=np.float32)
    grids = (levels.fine, levels.coarse)
    densities = tuple(np.float32(1.0 / (g.spacing_u * g.spacing_v)) for g in grids)
    block = tuple(b.start for b in levels.block)
    spans = splat_levels(rays.lines, power, Cells.of(levels), densities, fine, source, block)
    return fine, source, (slice(*spans[:2]), slice(*spans[2:]))


_NONE = np.zeros((0, 0), dtype=np.float32)


def _gather(plane, sight, sources, outputs, *, window=None, tail=None):
    """Spread light on a plane and add it at the pixels' sights to each of `outputs`.

    `sources` is ``(fine, source, rows)`` as from `_splat`; the light of the beam's `tail`
    (`Plane.tail`) is added to the spread. `outputs` holds ``(weight, out, occlusion)``
    triples: the light, times the cells' `occlusion` (None: 1) and each pixel's
    `weight`, is added to `out`; the spread is computed once for them all. Only the rows
    that the sights reach (their `window`, `workers.kernels.span`: found here when None)
    are brought back from the spectra.
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
    parts = (near, window, far, tails)
    for weight, out, occlusion in outputs:
        occlusion = _NONE if occlusion is None else occlusion
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
