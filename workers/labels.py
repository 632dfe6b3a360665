"""The labels of a sample and the dataset that carries them.

`sample_labels` holds what a scene fixes whatever the seed (target presence, gate depths,
platform track); `target_mask` marks the pixels a target covers; `target_effect` measures
what the target changes in each gate's noise-free image against the sample's target-free
twin, and `visibility` labels each gate from it; `rendered_arrays` types one sample's
rendered variables and `labelled_dataset` labels them. The rules are in ``docs/model.md``
§8.
"""

from __future__ import annotations

import numpy as np
import xarray as xr
from scipy.ndimage import maximum_filter

from workers.optics import fresnel_reflectance
from workers.radiometry import lidar_equation
from workers.scene import Scene
from workers.sensor import platform_position, receiver_terms, scene_setup
from workers.surface import centred_axis

__all__ = [
    "COUNT_HEADROOM",
    "RING_FRACTION",
    "VISIBILITY",
    "count_dtype",
    "labelled_dataset",
    "rendered_arrays",
    "rendered_variables",
    "sample_labels",
    "signal_means",
    "surface_axis",
    "target_effect",
    "target_mask",
    "visibility",
    "white_plane_count",
]

VISIBILITY = {"none": 0, "in_gate": 1, "shadow": 2, "unseen": 3}
"""The flags of ``target_visibility`` (`visibility`)."""
RING_FRACTION = 0.1
"""Width of the background ring around the target mask, as a fraction of the image."""
COUNT_HEADROOM = 16.0
"""Largest expected count of a pixel over the brightest thing a scene shows (`count_dtype`):
room for the focusing of light by waves and for shading that returns more than a flat
plate (a white sphere under ``shading: paper``: twice). Not a strict bound: a count beyond
the store's type is caught when the sample is stored (``valid_max``), never wrapped."""


def target_mask(silhouette: np.ndarray) -> np.ndarray:
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


def white_plane_count(scene: Scene) -> float:
    """Mean photoelectrons per pixel from a white plane just under a flat sea, at nadir.

    ``normalised`` radiometry: `white_plane_photons` by definition. ``absolute``: the lidar
    equation (`workers.radiometry.lidar_equation`, ρ = 1, d = 0) with the platform at its
    lowest during the sequence.
    """
    r = scene.radiometry
    if r.mode == "normalised":
        return float(r.white_plane_photons)
    times = np.arange(scene.sequence.frames) * scene.sequence.interval
    lowest = min(float(platform_position(scene, t)[2]) for t in times)
    n_w = scene.water.refractive_index
    laser = np.radians(scene.laser.field_of_view_deg or scene.receiver.field_of_view_deg)
    return float(
        lidar_equation(
            **receiver_terms(scene),
            beam_divergence=np.tan(0.5 * laser),
            altitude=max(lowest, 1e-3),
            depth=0.0,
            reflectance=1.0,
            attenuation=0.0,
            refractive_index=n_w,
            transmittance=1.0 - float(fresnel_reflectance(1.0, n1=1.0, n2=n_w)),
        )
    )


def count_dtype(scene: Scene) -> np.dtype | None:
    """The unsigned integer type that holds every photoelectron count of `scene`'s images.

    The narrowest of uint8, uint16 and uint32 holding the largest possible count:
    `COUNT_HEADROOM` times the count of the brightest thing the scene shows, plus ten
    standard deviations of its Poisson noise. The brightest thing, in units of a white
    plane just under a flat sea (`white_plane_count`), is the brightest gate's water (its
    effective reflectance) or the target's top, its reflectance attenuated by e^(-2Kd).

    A Monte Carlo render (`workers.montecarlo`) holds uint32 counts: one rare large
    local estimate can make a pixel's expected count many times the brightest thing's.

    Returns
    -------
    numpy.dtype or None
        None when the images are not photoelectron counts (no photon budget, or an ICCD
        gain stage whose output is not whole photoelectrons): they stay float32.

    Raises
    ------
    ValueError
        Naming ``radiometry``, if the counts could exceed what uint32 holds.
    """
    noise = scene.noise
    if not scene.radiometry.photoelectrons or noise.gain != 1.0 or noise.excess_noise != 1.0:
        return None
    if scene.transport.method == "monte_carlo":
        return np.dtype(np.uint32)
    setup = scene_setup(scene)
    brightest = max(setup.reflectances)
    target = scene.target
    if target.shape != "none":
        top = max(target.depth - target.radius, 0.0)
        k = setup.water.diffuse_attenuation
        brightest = max(brightest, target.reflectance * np.exp(-2.0 * k * top))
    white = white_plane_count(scene)
    mean = COUNT_HEADROOM * brightest * white
    largest = mean + 10.0 * np.sqrt(mean) + 10.0
    for dtype in (np.uint8, np.uint16, np.uint32):
        if largest <= np.iinfo(dtype).max:
            return np.dtype(dtype)
    raise ValueError(
        f"radiometry: a white plane under the sea would give {white:.3g} photoelectrons "
        f"per pixel, so counts could reach {largest:.3g}, more than the "
        f"{np.iinfo(np.uint32).max} an unsigned 32-bit count holds (lower pulse_energy "
        "or white_plane_photons)"
    )


def _box(mask, grow=0):
    """Rows and columns (slices) holding every pixel of `mask` (..., y, x), widened by `grow`."""
    seen = mask.reshape(-1, *mask.shape[-2:]).any(axis=0)
    rows, cols = np.flatnonzero(seen.any(axis=1)), np.flatnonzero(seen.any(axis=0))
    if not rows.size:
        return slice(0, 0), slice(0, 0)
    return (
        slice(max(int(rows[0]) - grow, 0), int(rows[-1]) + 1 + grow),
        slice(max(int(cols[0]) - grow, 0), int(cols[-1]) + 1 + grow),
    )


def _masked_mean(values, mask):
    """Mean of `values` (..., gate, y, x) over pixels where `mask` (..., y, x) holds.

    Summed in float64 over the box holding the mask's pixels (the others add nothing).
    """
    rows, cols = _box(mask)
    weights = mask[..., np.newaxis, rows, cols]
    count = weights.sum(axis=(-2, -1))
    total = (values[..., rows, cols].astype(np.float64) * weights).sum(axis=(-2, -1))
    return np.divide(total, count, out=np.full(total.shape, np.nan), where=count > 0)


def signal_means(values: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean of images inside the target mask and in a background ring around it.

    Parameters
    ----------
    values : ndarray, shape (..., gates, y, x)
        Images (any units).
    mask : ndarray of bool, shape (..., y, x)
        Pixels whose ray meets the target.

    Returns
    -------
    tuple of ndarray, shape (..., gates)
        The means over the mask and over the ring (pixels within `RING_FRACTION` of the
        image's width of the mask, outside it), float64; NaN where the region is empty.

    Notes
    -----
    The ring is dilated and both means are summed on the box around the mask (widened by
    the ring for the ring), not on the whole image: the same pixels, the float64 sums
    taken in another grouping (they agree to about 1e-16, far below float32 storage).
    """
    width = max(2, round(RING_FRACTION * mask.shape[-1]))
    size = (1,) * (mask.ndim - 2) + (2 * width + 1, 2 * width + 1)
    rows, cols = _box(mask, width)
    near = mask[..., rows, cols]
    ring = np.zeros_like(mask)
    if near.size:
        ring[..., rows, cols] = maximum_filter(near, size=size, mode="constant") & ~near
    return _masked_mean(values, mask), _masked_mean(values, ring)


def target_effect(
    expected: np.ndarray, free: np.ndarray, mask: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    r"""What the target changes in each gate's noise-free image, over its mask.

    .. math::

        \Delta = \langle E \rangle_M - \langle E_0 \rangle_M, \qquad
        \delta = \Delta / \langle E_0 \rangle_M

    with :math:`\langle\cdot\rangle_M` the mean over the target mask M, E the sample's
    expected image and :math:`E_0` its target-free twin's (the same scene, sea and photons
    without the target: `workers.scene.Scene.without_target`).

    Parameters
    ----------
    expected, free : ndarray, shape (..., gates, y, x)
        The noise-free images of the sample and of its target-free twin (photoelectrons,
        or units of a white plane under the sea).
    mask : ndarray of bool, shape (..., y, x)
        The target mask (`target_mask`).

    Returns
    -------
    effect : ndarray, shape (..., gates)
        Δ, in the images' units, float64; NaN where the mask is empty.
    relative : ndarray, shape (..., gates)
        δ [1]; NaN where the mask is empty, ±inf where the twin's mask is dark
        (:math:`\langle E_0 \rangle_M = 0`) and the target is not, 0 where both are.
    """
    shown, bare = _masked_mean(expected, mask), _masked_mean(free, mask)
    effect = shown - bare
    with np.errstate(divide="ignore", invalid="ignore"):
        relative = np.where(bare > 0, effect / bare, np.sign(effect) * np.inf)
    relative[effect == 0] = 0.0
    return effect, relative


def visibility(relative: np.ndarray, mask: np.ndarray, *, threshold: float) -> np.ndarray:
    """The target's label in each gate (`VISIBILITY`), from its relative effect.

    Parameters
    ----------
    relative : ndarray, shape (..., gates)
        The relative change the target makes over its mask (`target_effect`) [1].
    mask : ndarray of bool, shape (..., y, x)
        The target mask.
    threshold : float
        The least relative change that counts as seen (``target.visibility_threshold``)
        [1].

    Returns
    -------
    ndarray of uint8, shape (..., gates)
        ``none`` (0) where the mask is empty (no target, or none of it in view);
        ``in_gate`` (1) where the target brightens its mask by at least `threshold`,
        ``shadow`` (2) where it darkens it by at least `threshold`, ``unseen`` (3) where
        it changes it by less.
    """
    labels = np.full(relative.shape, VISIBILITY["unseen"], dtype=np.uint8)
    labels[relative >= threshold] = VISIBILITY["in_gate"]
    labels[relative <= -threshold] = VISIBILITY["shadow"]
    labels[~mask.any(axis=(-2, -1))] = VISIBILITY["none"]
    return labels


def sample_labels(scene: Scene) -> xr.Dataset:
    """The part of a sample fixed by its scene alone, whatever the seed.

    Parameters
    ----------
    scene : Scene
        The sample's parameters.

    Returns
    -------
    xarray.Dataset
        ``target_present`` () and the coordinates ``gate`` and ``frame`` (indices),
        ``gate_top``, ``gate_bottom`` (gate), ``time`` and ``platform_x/y/z`` (frame).
        The target's visibility per gate is rendered (`rendered_variables`).
    """
    return xr.Dataset(*_label_variables(scene))


def _label_variables(scene: Scene) -> tuple[dict, dict]:
    """The data variables and coordinates of `sample_labels`, as (dims, data, attrs)."""
    setup = scene_setup(scene)
    gates = np.asarray(setup.gates)
    times = np.arange(scene.sequence.frames) * scene.sequence.interval
    position = np.stack([platform_position(scene, t) for t in times])
    data_vars = {
        "target_present": (
            (),
            np.uint8(scene.target.shape != "none"),
            {
                "long_name": "a target is in the scene",
                "units": "1",
                "flag_values": np.arange(2, dtype=np.uint8),
                "flag_meanings": "absent present",
            },
        ),
    }
    coords = {
        "gate": (
            "gate",
            np.arange(len(gates), dtype=np.int32),
            {"long_name": "gate index", "units": "1"},
        ),
        "frame": (
            "frame",
            np.arange(len(times), dtype=np.int32),
            {"long_name": "frame index", "units": "1"},
        ),
        "gate_top": ("gate", gates[:, 0], {"long_name": "gate top depth", "units": "m"}),
        "gate_bottom": ("gate", gates[:, 1], {"long_name": "gate bottom depth", "units": "m"}),
        "time": ("frame", times, {"long_name": "time", "units": "s"}),
        "platform_x": ("frame", position[:, 0], {"long_name": "platform east", "units": "m"}),
        "platform_y": ("frame", position[:, 1], {"long_name": "platform north", "units": "m"}),
        "platform_z": ("frame", position[:, 2], {"long_name": "platform height", "units": "m"}),
    }
    return data_vars, coords


def rendered_variables(scene: Scene) -> dict[str, tuple[tuple[str, ...], np.dtype, dict]]:
    """The variables a render of `scene` carries beside its labels: one table.

    Parameters
    ----------
    scene : Scene
        The sample's parameters.

    Returns
    -------
    dict
        ``name -> (dimensions, dtype, attributes)`` for ``image``, ``expected``,
        ``target_mask``, ``target_signal``, ``background_signal``, ``target_effect``,
        ``target_effect_relative`` and ``target_visibility``, and ``surface_elevation``
        when the scene saves its surface (and the surface axes ``sx``, ``sy``:
        `surface_axis`). Units are CF's: photoelectron counts, ICCD
        output counts and signals in units of a white plane under the sea are all ``1``,
        and the ``long_name`` says which. Photoelectron counts are unsigned integers
        (`count_dtype`, with ``valid_max``); everything else float32.
    """
    photoelectrons = scene.radiometry.photoelectrons
    counts = count_dtype(scene)
    if counts is not None:
        image = {"long_name": "photoelectron count with shot noise"}
    elif photoelectrons:
        image = {"long_name": "ICCD output count (photoelectrons times gain, with noise)"}
    else:
        image = {"long_name": "noise-free signal in units of a white plane under the sea"}
    if counts is not None:
        image["valid_max"] = counts.type(np.iinfo(counts).max)
    signal = (
        "expected photoelectron count"
        if photoelectrons
        else "signal in units of a white plane under the sea"
    )
    f32, u8 = np.dtype(np.float32), np.dtype(np.uint8)
    table = {
        "image": (("frame", "gate", "y", "x"), counts or f32, {**image, "units": "1"}),
        "expected": (
            ("frame", "gate", "y", "x"),
            f32,
            {"long_name": f"{signal} (noise-free)", "units": "1"},
        ),
        "target_mask": (
            ("frame", "y", "x"),
            u8,
            {
                "long_name": "pixel ray meets the target silhouette",
                "units": "1",
                "flag_values": np.arange(2, dtype=np.uint8),
                "flag_meanings": "water target",
            },
        ),
        "target_signal": (
            ("frame", "gate"),
            f32,
            {"long_name": f"mean {signal} inside the target mask (noise-free)", "units": "1"},
        ),
        "background_signal": (
            ("frame", "gate"),
            f32,
            {
                "long_name": f"mean {signal} in the ring around the target mask (noise-free)",
                "units": "1",
            },
        ),
        "target_effect": (
            ("frame", "gate"),
            f32,
            {
                "long_name": f"change of the mean {signal} inside the target mask made by the "
                "target (noise-free; the sample less its target-free twin)",
                "units": "1",
            },
        ),
        "target_effect_relative": (
            ("frame", "gate"),
            f32,
            {
                "long_name": "target_effect over the target-free twin's mean inside the mask",
                "units": "1",
                "comment": "NaN where the mask is empty; +-inf where the twin's mask is dark",
            },
        ),
        "target_visibility": (
            ("frame", "gate"),
            u8,
            {
                "long_name": "what the target shows in the gate",
                "units": "1",
                "flag_values": np.arange(len(VISIBILITY), dtype=np.uint8),
                "flag_meanings": " ".join(VISIBILITY),
                "comment": "from target_effect_relative: in_gate at or above "
                "+target.visibility_threshold (default 0.05), shadow at or below its "
                "negative, unseen between; none where the mask is empty",
            },
        ),
    }
    if scene.transport.method == "monte_carlo":
        error = {"long_name": f"Monte Carlo standard error of the {signal} (noise-free)"}
        table["expected_stderr"] = (("frame", "gate", "y", "x"), f32, {**error, "units": "1"})
    if scene.save_surface:
        table["surface_elevation"] = (
            ("frame", "sy", "sx"),
            f32,
            {"long_name": "sea surface elevation (all cascades) at (sx, sy)", "units": "m"},
        )
        for name, direction in (("sx", "east"), ("sy", "north")):
            table[name] = (
                (name,),
                np.dtype(float),
                {
                    "long_name": f"surface grid {direction} of the first frame's boresight "
                    "sea point",
                    "units": "m",
                },
            )
    return table


def rendered_arrays(
    scene, expected, image, masks, surface, *, free, stderr=None
) -> dict[str, np.ndarray]:
    """One sample's rendered variables as arrays of the types `rendered_variables` gives.

    A count above the image type's ``valid_max`` (beyond `COUNT_HEADROOM`) leaves the
    image in float32, never wrapped, so that the store refuses the sample. The store
    writes these arrays (`workers.render.render_arrays`); `labelled_dataset` labels them.

    Parameters
    ----------
    scene : Scene
        The sample's parameters.
    expected, image : ndarray
        The noise-free and noisy images, (frame, gate, y, x).
    masks : ndarray
        The target mask, (frame, y, x).
    surface : Surface or None
        The sea, for ``surface_elevation`` when the scene saves it.
    free : ndarray
        The noise-free images of the sample's target-free twin, (frame, gate, y, x): the
        target's effect is measured against them (`target_effect`).
    stderr : ndarray, optional
        The Monte Carlo renderer's standard error of `expected`, (frame, gate, y, x):
        ``expected_stderr`` (`workers.montecarlo`).

    Returns
    -------
    dict
        ``name -> array`` for ``image``, ``expected``, ``target_mask``,
        ``target_signal``, ``background_signal``, ``target_effect``,
        ``target_effect_relative``, ``target_visibility`` (and ``surface_elevation``).
    """
    table = rendered_variables(scene)
    mask = masks.astype(bool)
    target, background = signal_means(expected, mask)
    effect, relative = target_effect(expected, free, mask)
    relative = relative.astype(np.float32)  # labelled as stored: re-thresholding agrees
    values = {
        "image": image,
        "expected": expected,
        "target_mask": masks,
        "target_signal": target,
        "background_signal": background,
        "target_effect": effect,
        "target_effect_relative": relative,
        "target_visibility": visibility(
            relative, mask, threshold=scene.target.visibility_threshold
        ),
    }
    if "expected_stderr" in table:
        values["expected_stderr"] = stderr
    arrays = {}
    for name, data in values.items():
        _, dtype, attrs = table[name]
        if "valid_max" in attrs and data.max(initial=0) > attrs["valid_max"]:
            dtype = np.dtype(np.float32)
        arrays[name] = data.astype(dtype, copy=False)
    if scene.save_surface:
        frames, size = scene.sequence.frames, surface_axis(scene).size
        elevation = (
            np.zeros((frames, size, size), np.float32)
            if surface is None
            else surface.centred_elevation
        )
        arrays["surface_elevation"] = elevation.astype(table["surface_elevation"][1])
    return arrays


def labelled_dataset(scene: Scene, arrays: dict[str, np.ndarray]) -> xr.Dataset:
    """One sample as a dataset: its labels and its `rendered_arrays`, per `rendered_variables`.

    The dataset is built in one constructor call (adding variables one by one costs an
    alignment each).
    """
    table = rendered_variables(scene)
    data_vars, coords = _label_variables(scene)
    for name, data in arrays.items():
        dims, _, attrs = table[name]
        data_vars[name] = (dims, data, attrs)
    if scene.save_surface:
        axis = surface_axis(scene)
        coords["sx"] = ("sx", axis, table["sx"][2])
        coords["sy"] = ("sy", axis, table["sy"][2])
    return xr.Dataset(data_vars, coords=coords)


def surface_axis(scene: Scene) -> np.ndarray:
    """Where the stored surface grid lies along x (``sx``) and along y (``sy``) [m].

    `workers.surface.centred_axis` of the finest cascade: N + 1 nodes Δ₀ apart, centred on
    the world origin, where the boresight meets mean sea level in the first frame; those
    of `workers.surface.Surface.centred_elevation`.

    Parameters
    ----------
    scene : Scene
        The sample's parameters.

    Returns
    -------
    numpy.ndarray
        The N + 1 positions, float64 [m].

    Notes
    -----
    The grid stays where the first frame's footprint is: a moving platform's later
    footprints drift off it, and an oblique one's far side reaches past it.
    """
    return centred_axis(grid_size=scene.surface.grid_size, spacing=scene.surface_spacing())
