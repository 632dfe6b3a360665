"""Render one sample: a sea-surface realisation seen by the gated receivers.

`render` is the seam between the physics and the service: it returns one sample as an
`xarray.Dataset` holding exactly the variables of one ``sample`` of the store
(``docs/model.md``), without the ``sample`` dimension.

The image-formation model, per frame:

1. Laser rays and pixel rays are intersected with the real surface, refracted (Snell) and
   weighted by the Fresnel transmittance. The laser is a Gaussian beam: rays sample it at
   the pixels' pitch over the image and `LATTICE_MARGIN` rays beyond, and its tail beyond
   that (out to `BEAM_EXTENT` times its 1/e radius) is refracted by the mean, flat sea onto
   each plane (`workers.fast.spread`).
2. Each gate opens and closes on slant range (`workers.setup.gates`). A gate's single-scattering
   water backscatter is an effective Lambertian reflectance on a reference plane at the
   central slab's centroid depth: laser rays are splatted where they cross that plane
   (each with the attenuation of its extra slant path), spread by the Wells point-spread
   function down and up in one product (reflectance × MTF², linear, without wrap-around:
   `workers.fast.spread.Spread`) and gathered where each pixel's ray crosses the plane, times
   the exit transmittance. The slant-range timing enters as one gain per laser ray and per
   pixel, from its air path (`gate_gain`): a ray longer in the air gates a shallower slab.
3. The target is an impostor on the plane through its centre: downwelling irradiance
   there times its reflectance map, lit and attenuated at each cell's true depth on the
   target (not at the centre plane), restricted to each cell's share of the return inside
   the gate (on time and delayed by scattering), spread up and gathered. Over a rough sea
   it is read along the pixels' lines through the resolved sea, blurred by where the
   sub-grid slopes move them (`workers.setup.compiled.Setup.subgrid_sway`), as is the
   target's mask.
4. Where a pixel's line of sight meets the target, the water behind the target is
   neither lit nor seen: the slab's backscatter loses the fraction lying behind the
   target's surface, half on the way down and half on the way up (square roots), each
   blurred by small-angle scattering around the target (`workers.fast.shadows`): exact
   without scattering, a full shadow when the target is above the gate.
5. Images are scaled to photoelectrons (`radiometry.mode`): ``absolute`` by the lidar
   equation's photon budget (`workers.receiver.radiometry.photoelectrons_per_signal`), so counts
   fall with altitude as 1/(nH + d)²; ``normalised`` so that a ρ = 1 Lambertian plane just
   under a flat sea at nadir gives `radiometry.white_plane_photons` counts. Then Poisson
   shot noise is drawn.

Approximations beyond the paper's, at oblique views: the Wells spread is computed for the
vertical range to each plane (it underestimates the blur by about 1/cos ϑ in the water),
while attenuation follows each ray's slant path; a gate's slab is weighted with the central
ray's in-water angle and blurred at the central slab's depth wherever slant gating moves
it; the target's own cells are gated on their lines of sight.

A batch (`render_batch`) renders the realisations of one scene, each on its own streams:
a sample's bytes do not depend on the batch it is rendered in. The per-frame stages
(`workers.fast.stages`) run on an array backend (`workers.backends.backend`: numpy with the numba
kernels, or PyTorch on the CPU or a CUDA device); the labels are made on the host.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr

from workers.backends.backend import Backend, get_backend
from workers.calibration.timegains import calibrated
from workers.dataset.labels import labelled_dataset, rendered_arrays, target_mask
from workers.fast import stages
from workers.fast.planes import frame_geometry
from workers.montecarlo import renderer as montecarlo
from workers.receiver.noise import shot_noise
from workers.settings.scene import Scene
from workers.settings.section import SceneError
from workers.settings.seeds import SampleSeed
from workers.setup.builder import scene_setup, slab_setups, time_resolved
from workers.setup.compiled import Setup

__all__ = ["render", "render_arrays", "render_batch", "render_images", "render_pair"]


@dataclass(frozen=True)
class SampleLight:
    """One sample's light, on the backend (the masks and the Monte Carlo error on the host).

    Attributes
    ----------
    surface : Surface or None
        The sample's sea (None: flat).
    expected : array, shape (frame, gate, y, x)
        The noise-free images [photoelectrons], float32.
    masks : ndarray, shape (frame, y, x)
        The target mask, uint8.
    stderr : ndarray or None
        The Monte Carlo renderer's standard error of `expected` (None: the fast renderer).
    free : array or None
        The fast renderer's expected images of the target-free twin (None: no target,
        or Monte Carlo).
    image : array
        The noisy images.
    """

    surface: object
    expected: object
    masks: np.ndarray
    stderr: np.ndarray | None
    free: object
    image: object


def render(
    scene: Scene, *, seed: int | SampleSeed, backend: str = "numpy", device: str = "cpu"
) -> xr.Dataset:
    """Render one sample: six (or however many) gated images per frame.

    Parameters
    ----------
    scene : Scene
        All parameters of the sample.
    seed : int or SampleSeed
        An int is the root seed of a lone sample (point 0, realisation 0). The surface
        depends on ``(root, realisation)`` only, the noise on ``(root, point,
        realisation)``.
    backend, device : str, optional
        Where it is rendered (`workers.backends.backend.get_backend`): ``numpy`` on the ``cpu``
        (the default), or ``torch`` on the ``cpu`` or ``cuda`` (``cuda:N``).

    Returns
    -------
    xarray.Dataset
        ``image`` and ``expected`` (frame, gate, y, x), ``target_mask`` (frame, y, x),
        the signal means, the target's effect and ``target_visibility`` (frame, gate),
        ``target_present`` (), coordinates ``gate_top``, ``gate_bottom`` (gate), ``time``
        and the platform position (frame), and ``surface_elevation`` (frame, sy, sx)
        when ``scene.save_surface`` is set.

    Raises
    ------
    ValueError
        A backend or device that cannot run here (`get_backend`).
    SceneError
        A Monte Carlo scene (``transport.method``) on a backend other than numpy.
    """
    arrays = render_arrays(scene, seed=seed, backend=backend, device=device)
    return labelled_dataset(scene, arrays)


def render_batch(
    scene: Scene, seeds, *, backend: str = "numpy", device: str = "cpu"
) -> dict[str, np.ndarray]:
    """The `render_arrays` of several realisations of one scene, stacked.

    Each sample is rendered with its own seed's streams (its sea, its noise: the noise of
    a torch sample from a generator seeded from its noise stream), so its bytes are those
    it has alone, whatever else the batch holds; the same seeds give the same bytes on
    every run of a backend and device.

    Parameters
    ----------
    scene : Scene
        All parameters of the samples.
    seeds : sequence of int or SampleSeed
        One per sample, as `render`'s `seed`; at least one.
    backend, device : str, optional
        As for `render`.

    Returns
    -------
    dict
        ``name -> array``: `render_arrays`' values, a new leading axis the sample (host
        numpy, the store's types). A sample whose counts overflow the image type keeps
        its image in float32 (`workers.dataset.labels.rendered_arrays`): stacked, the batch's
        images are then all float32, and a store refuses them.

    Raises
    ------
    ValueError
        No seeds, or a backend or device that cannot run here.
    SceneError
        A Monte Carlo scene on a backend other than numpy.
    """
    chosen = _backend(scene, backend, device)
    seeds = [_sample_seed(seed) for seed in seeds]
    if not seeds:
        raise ValueError("seeds: a batch renders at least one sample")
    samples = [_sample_arrays(scene, seed, chosen) for seed in seeds]
    return {name: np.stack([sample[name] for sample in samples]) for name in samples[0]}


def render_arrays(
    scene: Scene, *, seed: int | SampleSeed, backend: str = "numpy", device: str = "cpu"
) -> dict[str, np.ndarray]:
    """The rendered variables of `render`, as arrays, without the labels the scene fixes.

    What a store's task writes (`service.run.render_shard`): the same values as
    `render`'s, without building a dataset (about 1 ms a sample); a batch of one
    (`render_batch`).

    A scene with a target yields its target-free twin
    (`workers.settings.scene.Scene.without_target`)
    on the same sea too, for the target's effect and its visibility labels
    (`workers.dataset.labels.target_effect`): the fast renderer reads the same spread light a
    second time without the target's light and shadow (in the same pass, bit for bit the
    twin rendered apart); by Monte Carlo it is a second transport of the same photons
    (twice the time: ``docs/model.md`` §8). Only its expected images are kept.

    Parameters
    ----------
    scene : Scene
        All parameters of the sample.
    seed : int or SampleSeed
        As for `render`.
    backend, device : str, optional
        As for `render`.

    Returns
    -------
    dict
        `workers.dataset.labels.rendered_arrays`: ``image``, ``expected``, ``target_mask``,
        the signal means, the target's effect, ``target_visibility`` (and
        ``surface_elevation``).
    """
    batch = render_batch(scene, [seed], backend=backend, device=device)
    return {name: values[0] for name, values in batch.items()}


def render_images(
    scene: Scene, *, seed: int | SampleSeed, backend: str = "numpy", device: str = "cpu"
) -> tuple[np.ndarray, np.ndarray]:
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
    backend, device : str, optional
        As for `render`.

    Returns
    -------
    expected, image : ndarray, shape (frame, gate, y, x)
        The values of `render_arrays`'s ``expected`` and ``image`` (float32 here).
    """
    chosen = _backend(scene, backend, device)
    light = _render_sample(scene, _sample_seed(seed), chosen)
    return chosen.to_numpy(light.expected), chosen.to_numpy(light.image)


def render_pair(
    scene: Scene,
    *,
    seed: SampleSeed,
    twin_seed: SampleSeed,
    backend: str = "numpy",
    device: str = "cpu",
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
    backend, device : str, optional
        As for `render`.

    Returns
    -------
    tuple of ndarray or None
        ``expected, image, twin_expected, twin_image``, each (frame, gate, y, x) as
        `render_images`'s; None when the renderer makes no twin (no target, Monte Carlo).
    """
    if seed.root != twin_seed.root or seed.realisation != twin_seed.realisation:
        raise ValueError("a twin is of the same root seed and realisation (the same sea)")
    chosen = _backend(scene, backend, device)
    light = _render_sample(scene, seed, chosen)
    if light.free is None:
        return None
    twin_image = _noisy(scene, light.free, twin_seed, chosen)
    images = (light.expected, light.image, light.free, twin_image)
    return tuple(chosen.to_numpy(values) for values in images)


def _backend(scene: Scene, name: str, device: str) -> Backend:
    """`get_backend(name, device)`, checked to render `scene`."""
    backend = get_backend(name, device)
    if scene.transport.method == "monte_carlo" and backend.name != "numpy":
        raise SceneError(
            f"transport.method: monte_carlo renders on the numpy backend only, not {name!r}"
        )
    return backend


def _setup(scene: Scene) -> Setup:
    """The scene's setup, with transport's gains where the fast renderer takes them.

    `workers.setup.builder.scene_setup`, its gates' reflectances calibrated by photon
    transport of its water (`workers.calibration.timegains.calibrated`) where
    `workers.setup.builder.time_resolved`: water that scatters many times, the paper's
    phase function (docs/model.md §5).
    """
    setup = scene_setup(scene)
    if not time_resolved(scene):
        return setup
    fast, transport = slab_setups(scene)
    return calibrated(setup, fast=fast, transport=transport)


def _sample_seed(seed: int | SampleSeed) -> SampleSeed:
    """A sample's seed: an int is the root seed of a lone sample."""
    return seed if isinstance(seed, SampleSeed) else SampleSeed(root=int(seed))


def _sample_arrays(scene: Scene, seed: SampleSeed, backend: Backend) -> dict[str, np.ndarray]:
    """One sample's `render_arrays`, rendered on `backend`, labelled on the host."""
    light = _render_sample(scene, seed, backend)
    free = light.free
    if scene.target.shape == "none":
        free = light.expected
    elif free is None:  # Monte Carlo: the twin's own photons, the same streams
        free = _render_frames(scene.without_target(), light.surface, seed, backend).expected
    host = backend.to_numpy
    return rendered_arrays(
        scene,
        host(light.expected),
        host(light.image),
        light.masks,
        light.surface,
        free=host(free),
        stderr=light.stderr,
    )


def _render_sample(scene: Scene, seed: SampleSeed, backend: Backend) -> SampleLight:
    """The sample's light: its sea, each frame's light, its noise."""
    setup = _setup(scene)
    times = np.arange(scene.sequence.frames) * scene.sequence.interval
    surface = setup.surface(seed, times, backend=backend)
    light = _render_frames(scene, surface, seed, backend)
    image = _noisy(scene, light.expected, seed, backend)
    return SampleLight(surface, light.expected, light.masks, light.stderr, light.free, image)


def _noisy(scene: Scene, expected, seed: SampleSeed, backend: Backend):
    """The noisy images of `expected` [photoelectrons] with the noise streams of `seed`."""
    noise = scene.noise
    if not scene.radiometry.photoelectrons:
        return backend.xp.asarray(expected, copy=True)
    if backend.name == "numpy":
        rng = seed.noise_rng()
    else:
        rng = backend.generator(seed.noise_seed())
    return shot_noise(expected, rng=rng, gain=noise.gain, excess_noise=noise.excess_noise)


def _render_frames(scene: Scene, surface, seed: SampleSeed, backend: Backend) -> SampleLight:
    """Every frame's expected image (frame, gate, y, x), mask, Monte Carlo error and twin.

    The error is None for the fast renderer (deterministic). The twin, the expected image
    without the target, comes with the fast renderer's when there is a target (the same
    spread light gathered without the target's light and shadow); None otherwise. The
    result has no image (None): the noise is drawn after.
    """
    xp = backend.xp
    setup = _setup(scene)
    expected, masks, errors, twins = [], [], [], []
    for frame in range(scene.sequence.frames):
        if scene.transport.method == "monte_carlo":
            transported = montecarlo.render_frame(setup, surface, frame, seed)
            expected.append(transported.expected)
            masks.append(transported.mask)
            errors.append(transported.stderr)
            continue
        geometry = frame_geometry(setup, frame).on(backend)
        light = stages.frame_light(setup, geometry, surface, frame, backend)
        expected.append(light.images)
        pixels = scene.receiver.pixels
        if light.silhouette is None:
            masks.append(np.zeros((pixels, pixels), dtype=np.uint8))
        else:
            masks.append(target_mask(backend.to_numpy(light.silhouette)))
        if light.free is not None:
            twins.append(light.free)
    return SampleLight(
        surface=surface,
        expected=xp.stack(expected),
        masks=np.stack(masks),
        stderr=np.stack(errors) if errors else None,
        free=xp.stack(twins) if twins else None,
        image=None,
    )
