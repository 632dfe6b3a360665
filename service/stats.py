"""Statistics of a sweep, per parameter point and gate, with dask reductions.

The statistics dataset sits beside the store (`service.store.stats_url`). Its variables,
over the realisations and frames of each point (samples not yet written are ignored):

- ``image_mean``, ``image_std`` (point, gate, y, x): mean and standard deviation images;
- ``target_signal``, ``background_signal`` (point, gate): mean expected (noise-free)
  signal inside the target mask and in a ring of local background around it;
- ``target_contrast`` (point, gate): (target − background) / background of the expected
  images: what the physics leaves of the target, before noise;
- ``cnr`` (point, gate): contrast-to-noise ratio of the noisy images, (target − background)
  over the standard deviation of the background ring (shot noise and clutter);
- ``visible_fraction`` (point, gate): fraction of samples and frames in which the target is
  in the gate and at least one pixel's ray meets it.
"""

from __future__ import annotations

import warnings

import numpy as np
import xarray as xr

from service import store

__all__ = ["compute_statistics", "write_statistics"]

RING_FRACTION = 0.1
"""Width of the background ring around the target mask, as a fraction of the image."""


def compute_statistics(ds: xr.Dataset) -> xr.Dataset:
    """The statistics of an opened store (lazy; nothing is loaded whole).

    Parameters
    ----------
    ds : xarray.Dataset
        A store opened with `service.store.open_store`.

    Returns
    -------
    xarray.Dataset
        Dask-backed statistics, one entry per parameter point.
    """
    realisations = int(ds.attrs["realisations"])
    points = int(ds.attrs["points"])
    written = ds["completed"].astype(bool)
    units = ds["image"].attrs.get("units", "1")
    image = ds["image"].where(written)
    expected = ds["expected"].where(written)
    mask = ds["target_mask"].astype(bool)
    ring = _ring(mask)
    space = ("y", "x")
    over = ("realisation_", "frame")

    def per_point(array: xr.DataArray) -> xr.DataArray:
        return array.coarsen(sample=realisations).construct(sample=("point", "realisation_"))

    target = per_point(expected.where(mask).mean(space))
    background = per_point(expected.where(ring).mean(space))
    noisy_difference = per_point(image.where(mask).mean(space) - image.where(ring).mean(space))
    noise = per_point(image.where(ring).std(space))
    visible = per_point((mask.any(space) & (ds["target_visibility"] == 1)).where(written))
    stacked = per_point(image)
    stats = xr.Dataset(
        {
            "image_mean": stacked.mean(over).assign_attrs(
                long_name="mean image over realisations and frames", units=units
            ),
            "image_std": stacked.std(over, ddof=1).assign_attrs(
                long_name="standard deviation image over realisations and frames", units=units
            ),
            "target_signal": target.mean(over).assign_attrs(
                long_name="mean expected signal inside the target mask", units=units
            ),
            "background_signal": background.mean(over).assign_attrs(
                long_name="mean expected signal outside the target mask", units=units
            ),
            "target_contrast": ((target - background) / background.where(background > 0))
            .mean(over)
            .assign_attrs(
                long_name="target contrast (T - B) / B of the expected images", units="1"
            ),
            "cnr": (noisy_difference / noise.where(noise > 0))
            .mean(over)
            .assign_attrs(
                long_name="contrast-to-noise ratio (T - B) / sd(B) of the noisy images", units="1"
            ),
            "visible_fraction": visible.astype(float)
            .mean(over)
            .assign_attrs(
                long_name="fraction of samples with the target in the gate and in view", units="1"
            ),
            "samples": per_point(written.astype(np.int32))
            .sum("realisation_")
            .assign_attrs(long_name="realisations written", units="1"),
        }
    )
    first = np.arange(points) * realisations
    coords = {"point": ("point", np.arange(points))}
    for name, coord in ds.coords.items():
        if coord.dims == ("sample",) and name not in ("point", "realisation"):
            coords[name] = ("point", coord.values[first], dict(coord.attrs))
    stats = stats.drop_vars([c for c in stats.coords if c not in ("gate_top", "gate_bottom")])
    stats = stats.assign_coords(coords)
    stats.attrs.update(
        title=ds.attrs.get("title", "") + " statistics",
        Conventions=store.CONVENTIONS,
        sweep_sha256=ds.attrs.get("sweep_sha256", ""),
        oceanlidar_version=store.package_version(),
    )
    return stats


def _ring(mask: xr.DataArray) -> xr.DataArray:
    """The local background: pixels near the target mask but not in it.

    Near means within `RING_FRACTION` of the image width (at least two pixels) in each
    direction. A local background keeps the laser's bright centre and dim edges out of the
    contrast.
    """
    width = max(2, round(RING_FRACTION * mask.sizes["x"]))
    window = 2 * width + 1
    near = mask.astype(np.uint8).rolling(y=window, x=window, center=True, min_periods=1).max()
    return (near > 0) & ~mask


def write_statistics(url: str, *, storage_options: dict | None = None) -> str:
    """(Re)compute the statistics of the store at `url` and write them beside it.

    Returns
    -------
    str
        Where the statistics were written.
    """
    probe = store.open_store(url, storage_options=storage_options)
    # one dask chunk per parameter point: the graph grows with points, not samples
    ds = store.open_store(
        url, storage_options=storage_options, samples_per_chunk=int(probe.attrs["realisations"])
    )
    stats = compute_statistics(ds)
    target = store.stats_url(url)
    store.remove_store(target, storage_options)
    with store.consolidated_v3(), warnings.catch_warnings():
        # points without a target have empty masks: their contrasts are NaN, by design
        warnings.simplefilter("ignore", RuntimeWarning)
        stats.chunk({"point": 1}).to_zarr(
            target, mode="w", consolidated=True, zarr_format=3, storage_options=storage_options
        )
    return target
