"""The labels of a sample and the dataset that carries them.

`sample_labels` holds what a scene fixes whatever the seed (target presence and visibility
per gate, gate depths, platform track); `target_mask` marks the pixels a target covers;
`labelled_dataset` assembles one sample's variables. The rules are in ``docs/model.md`` §8.
"""

from __future__ import annotations

import functools

import numpy as np
import xarray as xr

from workers.geometry import PlaneGrid, flat_sea_point
from workers.scene import Scene
from workers.sensor import (
    fine_grid,
    gate_bounds,
    impostor_on,
    lines_of_sight,
    platform_position,
    scene_setup,
    sensor_at,
    target_centre,
)
from workers.water import slab_backscatter_reflectance

__all__ = ["VISIBILITY", "labelled_dataset", "rendered_variables", "sample_labels", "target_mask"]

VISIBILITY = {"none": 0, "in_gate": 1, "shadow": 2, "below_gate": 3}


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


def _target_window(setup, sensor) -> PlaneGrid:
    """The part of the image's target-plane grid around the target (a few cells wider).

    The grid of the receiver's footprint at the target's depth (one cell per pixel at the
    image's centre), cut to the target's reach: the labels need no more, whatever the
    image's size.
    """
    scene = setup.scene
    full = fine_grid(sensor, scene.target.depth, setup.water.refractive_index, guard=4, multiple=1)
    row, col = full.cell_coordinates(*target_centre(setup, sensor.camera))
    reach = scene.target.radius / min(full.spacing_u, full.spacing_v) + 3
    rows, cols = full.shape
    r0, r1 = (int(np.clip(v, 0, rows)) for v in (np.floor(row - reach), np.ceil(row + reach) + 1))
    c0, c1 = (int(np.clip(v, 0, cols)) for v in (np.floor(col - reach), np.ceil(col + reach) + 1))
    u, v = np.asarray(full.axis_u), np.asarray(full.axis_v)
    origin = np.asarray(full.origin) + c0 * full.spacing_u * u + r0 * full.spacing_v * v
    return PlaneGrid(
        depth=full.depth,
        origin=(float(origin[0]), float(origin[1])),
        axis_u=full.axis_u,
        axis_v=full.axis_v,
        spacing_u=full.spacing_u,
        spacing_v=full.spacing_v,
        shape=(max(r1 - r0, 2), max(c1 - c0, 2)),
    )


def _in_view(sensor, grid: PlaneGrid, occupancy, refractive_index, block: int = 64) -> bool:
    """Whether any pixel's flat-sea line of sight crosses the silhouette (rows in blocks)."""
    camera = sensor.camera
    for start in range(0, camera.pixels, block):
        sights = flat_sea_point(
            origin=sensor.position,
            direction=camera.pixel_directions(slice(start, start + block)).reshape(-1, 3),
            depth=grid.depth,
            refractive_index=refractive_index,
        )
        if grid.gather(occupancy, grid.locate(sights[:, 0], sights[:, 1])).any():
            return True
    return False


@functools.lru_cache(maxsize=256)
def _visibility(scene: Scene) -> tuple[int, ...]:
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
    setup = scene_setup(scene)
    count = len(setup.gates)
    if scene.target.shape == "none":
        return (VISIBILITY["none"],) * count
    water = setup.water
    sensor = sensor_at(setup, 0)
    grid = _target_window(setup, sensor)
    impostor = impostor_on(setup, grid)
    if not _in_view(sensor, grid, impostor.occupancy, water.refractive_index):
        return (VISIBILITY["none"],) * count
    k = water.diffuse_attenuation * setup.secant
    cells = np.flatnonzero(impostor.occupancy)
    occupancy = impostor.occupancy.ravel()[cells].astype(np.float64)
    depth = impostor.surface_depth.ravel()[cells].astype(np.float64)
    weight = impostor.weight.ravel()[cells]
    sight = lines_of_sight(sensor, grid, water.refractive_index, cells)
    labels = []
    for paths in sensor.paths:
        top, bottom = gate_bounds(sight, paths, water.refractive_index)
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
    setup = scene_setup(scene)
    gates = np.asarray(setup.gates)
    times = np.arange(scene.sequence.frames) * scene.sequence.interval
    position = np.stack([platform_position(scene, t) for t in times])
    data_vars = {
        "target_present": (
            (),
            np.uint8(scene.target.shape != "none"),
            {"long_name": "a target is in the scene", "units": "1"},
        ),
        "target_visibility": (
            ("gate",),
            np.asarray(_visibility(scene), dtype=np.uint8),
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


def rendered_variables(scene: Scene) -> dict[str, tuple[tuple[str, ...], np.dtype, dict]]:
    """The variables a render of `scene` carries beside its labels: one table.

    Parameters
    ----------
    scene : Scene
        The sample's parameters.

    Returns
    -------
    dict
        ``name -> (dimensions, dtype, attributes)`` for ``image``, ``expected`` and
        ``target_mask``, and ``surface_elevation`` when the scene saves its surface (and
        the surface axes ``sx``, ``sy``). Units: photoelectrons (``counts`` for an image
        with ICCD gain) or ``1`` for signals in units of a white plane under the sea.
    """
    photoelectrons = scene.radiometry.photoelectrons
    image_units = "1"
    if photoelectrons:
        image_units = "photoelectrons" if scene.noise.gain == 1.0 else "counts"
    f32, u8 = np.dtype(np.float32), np.dtype(np.uint8)
    table = {
        "image": (
            ("frame", "gate", "y", "x"),
            f32,
            {"long_name": "gated receiver image with shot noise", "units": image_units},
        ),
        "expected": (
            ("frame", "gate", "y", "x"),
            f32,
            {
                "long_name": "expected (noise-free) gated receiver image",
                "units": "photoelectrons" if photoelectrons else "1",
            },
        ),
        "target_mask": (
            ("frame", "y", "x"),
            u8,
            {"long_name": "pixel ray meets the target silhouette", "units": "1"},
        ),
    }
    if scene.save_surface:
        table["surface_elevation"] = (
            ("frame", "sy", "sx"),
            f32,
            {"long_name": "sea surface elevation", "units": "m"},
        )
        table["sx"] = (("sx",), np.dtype(float), {"long_name": "surface grid east", "units": "m"})
        table["sy"] = (("sy",), np.dtype(float), {"long_name": "surface grid north", "units": "m"})
    return table


def labelled_dataset(scene, expected, image, masks, surface):
    """One sample as a dataset: labels, images, mask (and surface), per `rendered_variables`."""
    table = rendered_variables(scene)
    frames = scene.sequence.frames
    ds = sample_labels(scene)
    for name, values in (("image", image), ("expected", expected), ("target_mask", masks)):
        dims, dtype, attrs = table[name]
        ds[name] = (dims, values.astype(dtype, copy=False), attrs)
    if scene.save_surface:
        n, spacing = scene.surface.grid_size, scene.surface_spacing()
        elevation = (
            surface.elevation if surface is not None else np.zeros((frames, n, n), np.float32)
        )
        dims, dtype, attrs = table["surface_elevation"]
        ds["surface_elevation"] = (dims, elevation.astype(dtype), attrs)
        axis = np.arange(n) * spacing
        ds = ds.assign_coords(sx=("sx", axis, table["sx"][2]), sy=("sy", axis, table["sy"][2]))
    return ds
