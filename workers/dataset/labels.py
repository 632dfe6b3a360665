"""The labels of a sample and the dataset that carries them.

`sample_labels` holds what a scene fixes whatever the seed (target presence, gate depths,
platform track); `target_mask` marks the pixels a target covers; `target_effect` measures
what the target changes in each gate's noise-free image against the sample's target-free
twin, and `visibility` labels each gate from it; `rendered_arrays` types one sample's
rendered variables and `labelled_dataset` labels them, both as the table of variables
says (`workers.dataset.variables`). The rules are in ``docs/model.md`` §8.
"""

from __future__ import annotations

import numpy as np
import xarray as xr
from scipy.ndimage import maximum_filter

from workers.dataset.variables import Role, Visibility, variables
from workers.sea.surface import centred_axis
from workers.settings.scene import Scene
from workers.setup.builder import scene_setup

__all__ = [
    "RING_FRACTION",
    "image_axes",
    "labelled_dataset",
    "rendered_arrays",
    "sample_labels",
    "signal_means",
    "surface_axis",
    "target_effect",
    "target_mask",
    "visibility",
]

RING_FRACTION = 0.1
"""Width of the background ring around the target mask, as a fraction of the image."""


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
    without the target: `workers.settings.scene.Scene.without_target`).

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
    """The target's label in each gate (`workers.dataset.variables.Visibility`), from its effect.

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
    labels = np.full(relative.shape, Visibility.unseen, dtype=np.uint8)
    labels[relative >= threshold] = Visibility.in_gate
    labels[relative <= -threshold] = Visibility.shadow
    labels[~mask.any(axis=(-2, -1))] = Visibility.none
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
        ``target_present`` () and the coordinates ``gate`` (numbers from 1, the
        shallowest: the ML(DC) cameras 1–6) and ``frame`` (indices from 0),
        ``gate_top``, ``gate_bottom`` (gate), ``time`` and ``platform_x/y/z`` (frame),
        the pixels' ``y`` and ``x`` (`image_axes`).
        The target's visibility per gate is rendered (`rendered_arrays`).
    """
    return xr.Dataset(*_label_variables(scene))


def _label_variables(scene: Scene) -> tuple[dict, dict]:
    """The data variables and coordinates of `sample_labels`, as (dims, data, attrs).

    The labels (`workers.dataset.variables.Role.LABEL`) are data variables; the platform track
    and the gates' and frames' coordinates are coordinates.
    """
    setup = scene_setup(scene)
    gates = np.asarray(setup.gates)
    times = np.arange(scene.sequence.frames) * scene.sequence.interval
    position = np.stack([setup.platform_position(t) for t in times])
    values = {
        "target_present": scene.target.shape != "none",
        "gate": np.arange(1, len(gates) + 1),
        "frame": np.arange(len(times)),
        "gate_top": gates[:, 0],
        "gate_bottom": gates[:, 1],
        "time": times,
        "platform_x": position[:, 0],
        "platform_y": position[:, 1],
        "platform_z": position[:, 2],
    }
    values["y"], values["x"] = image_axes(scene)
    table = variables(scene)
    data_vars, coords = {}, {}
    for name, data in values.items():
        variable = table[name]
        where = data_vars if variable.role is Role.LABEL else coords
        where[name] = (variable.dims, np.asarray(data, variable.dtype), variable.attrs)
    return data_vars, coords


def rendered_arrays(
    scene, expected, image, masks, surface, *, free, stderr=None
) -> dict[str, np.ndarray]:
    """One sample's rendered variables as arrays of the types `workers.dataset.variables` gives.

    A count above the image type's ``valid_max`` (beyond
    `workers.dataset.variables.COUNT_HEADROOM`) leaves the image in float32, never wrapped, so
    that the store refuses the sample. The store writes these arrays
    (`workers.render.render_arrays`); `labelled_dataset` labels them.

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
        ``expected_stderr`` (`workers.montecarlo.renderer`).

    Returns
    -------
    dict
        ``name -> array`` for ``image``, ``expected``, ``target_mask``,
        ``target_signal``, ``background_signal``, ``target_effect``,
        ``target_effect_relative``, ``target_visibility`` (and ``expected_stderr``,
        ``surface_elevation``).
    """
    table = variables(scene)
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
        dtype, attrs = table[name].dtype, table[name].attrs
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
        arrays["surface_elevation"] = elevation.astype(table["surface_elevation"].dtype)
    return arrays


def labelled_dataset(scene: Scene, arrays: dict[str, np.ndarray]) -> xr.Dataset:
    """One sample as a dataset: its labels and its `rendered_arrays`, per `variables`.

    The dataset is built in one constructor call (adding variables one by one costs an
    alignment each).
    """
    table = variables(scene)
    data_vars, coords = _label_variables(scene)
    for name, data in arrays.items():
        data_vars[name] = (table[name].dims, data, table[name].attrs)
    if scene.save_surface:
        axis = surface_axis(scene)
        for name in ("sx", "sy"):
            coords[name] = (name, axis, table[name].attrs)
    return xr.Dataset(data_vars, coords=coords)


def image_axes(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Where the pixel centres' lines of sight meet mean sea level, in the first frame [m].

    Offsets from the boresight's sea point on the image's axes: ``x`` to the image's
    right, ``y`` up the image (row 0, the far edge, has the largest ``y``), so that an
    image plotted against them stands as `service.plots.preview_figure` shows it. Looking
    straight down (``platform.nadir_deg`` 0) these are exact, and east and north when
    ``platform.azimuth_deg`` is 0 (the frame of ``sx``, ``sy``); an oblique view's are
    on the plane across the boresight at its sea point, where its footprint is a
    trapezium on the sea.

    Parameters
    ----------
    scene : Scene
        The sample's parameters.

    Returns
    -------
    y, x : numpy.ndarray
        The rows' and the columns' positions, ``receiver.pixels`` each, float64 [m].
    """
    p, r = scene.platform, scene.receiver
    boresight = p.altitude / np.cos(np.radians(p.nadir_deg))
    pitch = 2.0 * np.tan(0.5 * np.radians(r.field_of_view_deg)) / r.pixels
    offsets = (np.arange(r.pixels) + 0.5 - 0.5 * r.pixels) * pitch * boresight
    return -offsets, offsets


def surface_axis(scene: Scene) -> np.ndarray:
    """Where the stored surface grid lies along x (``sx``) and along y (``sy``) [m].

    `workers.sea.surface.centred_axis` of the finest cascade: N + 1 nodes Δ₀ apart, centred on
    the world origin, where the boresight meets mean sea level in the first frame; those
    of `workers.sea.surface.Surface.centred_elevation`.

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
