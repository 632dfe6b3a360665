"""Analysis through xarray: a gate's mean and a per-point mean image over the detection study.

Builds (unless it exists) a store with the layout of ``configs/detection-study.yaml`` (24
points x 1000 realisations, 32 x 32 pixels, three gates: the template `create_store`
writes, shards as `service.store.layout.shard_size` chooses), its images and masks filled
with random counts straight into the shards (nothing rendered), every sample marked
complete. Then times, through `service.dataset.open_dataset` and through plain
``xr.open_zarr``: the mean of one gate's images over the whole store, and the mean image
of each point (``groupby("point").mean()``). Each figure is the fastest of ``--repeat``
(the first read also warms the page cache); dask's threaded scheduler (the default: no
distributed client). Usage, from the repository root: ``python -m benchmarks.analysis
[--store PATH] [--repeat 2] [--skip-plain]``.

Figures, 2026-11-25, the 2-core machine shared by other runs (load 7 to 10), 94 shards
of 256 samples; open_dataset (two runs) against xr.open_zarr (one run):

==========================================  ==============  ============
                                            open_dataset    xr.open_zarr
==========================================  ==============  ============
opening (labels loaded)                     0.22-0.26 s     0.07 s
dask chunks along sample                    94              24 000
tasks of a gate's mean                      377             96 003
a gate's mean image over the store          0.68-1.25 s     77 s
groupby("point").mean() of a gate's images  0.94-1.04 s     161 s
==========================================  ==============  ============

Before this change open_dataset was xr.open_zarr with the labels loaded: 110 s for the
gate's mean in the same conditions (the issue measured 57 s and 99 s on a quieter machine).
"""

import argparse
import os
import time
from pathlib import Path

import numpy as np
import xarray as xr

from service.dataset import open_dataset
from service.store.location import Store
from service.store.template import create_store
from service.sweep import load_sweep

SWEEP = Path(__file__).resolve().parent.parent / "configs" / "detection-study.yaml"


def build(url: str) -> None:
    """The detection study's store at `url`, random counts in its images and masks."""
    plan = load_sweep(str(SWEEP))
    create_store(plan, Store(url))
    group = Store(url).group("r+")
    shard = group["completed"].chunks[0]
    rng = np.random.default_rng(0)
    for first in range(0, plan.samples, shard):
        last = min(first + shard, plan.samples)
        for name in ("image", "target_mask"):
            array = group[name]
            high = 2 if name == "target_mask" else 30
            values = rng.integers(0, high, size=(last - first, *array.shape[1:]))
            array[first:last] = values.astype(array.dtype)
        group["completed"][first:last] = 1


def plain(url: str) -> xr.Dataset:
    """The store through ``xr.open_zarr``, its ``point`` loaded (to group by it)."""
    ds = xr.open_zarr(url)
    return ds.assign_coords(point=ds["point"].compute())


def timed(compute) -> float:
    """Seconds `compute` takes."""
    start = time.perf_counter()
    compute()
    return time.perf_counter() - start


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--store", default="/tmp/oceanlidar-analysis/detection-study.zarr")
    parser.add_argument("--repeat", type=int, default=2, help="the fastest of REPEAT")
    parser.add_argument("--skip-plain", action="store_true", help="skip xr.open_zarr's")
    args = parser.parse_args()
    if not os.path.exists(args.store):
        start = time.perf_counter()
        build(args.store)
        print(f"built {args.store} in {time.perf_counter() - start:.0f} s")
    ways = {"open_dataset": lambda: open_dataset(args.store)}
    if not args.skip_plain:
        ways["xr.open_zarr"] = lambda: plain(args.store)
    for way, opened in ways.items():
        seconds = timed(opened)
        report(way, seconds, opened()["image"], args.repeat)


def report(way: str, seconds: float, image: xr.DataArray, repeat: int) -> None:
    """Print how `image` was opened and how long its two reductions take."""
    print(
        f"{way}: opened in {seconds:.2f} s; image {image.shape}, "
        f"{image.data.numblocks[0]} dask chunks along sample"
    )
    gate = image.isel(gate=1).mean(("sample", "frame"))
    print(f"  a gate's mean: {len(gate.data.__dask_graph__())} tasks")
    figures = {
        "a gate's mean image over the store": gate.compute,
        "groupby('point').mean() of a gate's images": lambda: (
            image.isel(gate=1).groupby("point").mean().compute()
        ),
    }
    for label, compute in figures.items():
        best = min(timed(compute) for _ in range(repeat))
        print(f"  {label:45} {best:6.2f} s")


if __name__ == "__main__":
    main()
