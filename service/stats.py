"""Statistics of a sweep, per parameter point and gate, with dask reductions.

The statistics dataset sits beside the store (`service.store.stats_url`). Its variables,
over the realisations and frames of each point (samples not yet written are ignored):

- ``image_mean``, ``image_std`` (point, gate, y, x): mean and standard deviation images;
- ``target_signal``, ``background_signal`` (point, gate): mean counts inside and outside
  the target mask;
- ``target_contrast`` (point, gate): (target − background) / background;
- ``cnr`` (point, gate): contrast-to-noise ratio, (target − background) / the standard
  deviation of the background pixels;
- ``visible_fraction`` (point, gate): fraction of samples and frames in which the target is
  in the gate and at least one pixel's ray meets it.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from service import store

__all__ = ["compute_statistics", "write_statistics"]


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
    image = ds["image"].where(written)
    by_point = {"sample": ("point", "realisation_")}

    def per_point(array: xr.DataArray) -> xr.DataArray:
        return array.coarsen(sample=realisations).construct(by_point)

    stacked = per_point(image)
    over = ("realisation_", "frame")
    mask = ds["target_mask"].astype(bool)
    inside = image.where(mask)
    outside = image.where(~mask)
    space = ("y", "x")
    target = per_point(inside.mean(space))
    background = per_point(outside.mean(space))
    noise = per_point(outside.std(space))
    present = mask.any(space) & (ds["target_visibility"] == 1)
    visible = per_point(present.where(written).astype(float))
    stats = xr.Dataset(
        {
            "image_mean": stacked.mean(over).assign_attrs(
                long_name="mean image over realisations and frames",
                units=image.attrs.get("units", "1"),
            ),
            "image_std": stacked.std(over, ddof=1).assign_attrs(
                long_name="standard deviation image over realisations and frames",
                units=image.attrs.get("units", "1"),
            ),
            "target_signal": target.mean(over).assign_attrs(
                long_name="mean counts inside the target mask", units=image.attrs.get("units", "1")
            ),
            "background_signal": background.mean(over).assign_attrs(
                long_name="mean counts outside the target mask",
                units=image.attrs.get("units", "1"),
            ),
            "target_contrast": ((target - background) / background)
            .mean(over)
            .assign_attrs(long_name="target contrast (T - B) / B", units="1"),
            "cnr": ((target - background) / noise)
            .mean(over)
            .assign_attrs(long_name="contrast-to-noise ratio (T - B) / sd(B)", units="1"),
            "visible_fraction": visible.mean(over).assign_attrs(
                long_name="fraction of samples with the target in the gate and in view",
                units="1",
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


def write_statistics(url: str, *, storage_options: dict | None = None) -> str:
    """(Re)compute the statistics of the store at `url` and write them beside it.

    Returns
    -------
    str
        Where the statistics were written.
    """
    ds = store.open_store(url, storage_options=storage_options)
    stats = compute_statistics(ds)
    target = store.stats_url(url)
    store.remove_store(target, storage_options)
    stats.chunk({"point": 1}).to_zarr(
        target, mode="w", consolidated=False, zarr_format=3, storage_options=storage_options
    )
    return target
