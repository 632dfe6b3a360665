"""Analysis through xarray: a gate's mean and a per-point mean image over the detection study.

Builds (unless it exists) a store with the layout of ``configs/detection-study.yaml`` (24
points x 1000 realisations, 32 x 32 pixels, three gates: the template `create_store`
writes, shards as `service.store.layout.shard_size` chooses), its images and masks filled
with random counts straight into the shards (nothing rendered), every sample marked
complete. Then times, through `service.dataset.open_dataset` and through plain
``xr.open_zarr``: the mean of one gate's images over the whole store, and the mean image
of each point (``groupby("point").mean()``). The first read warms the page cache; each
figure is the fastest of ``--repeat``. Dask's threaded scheduler (the default: no
distributed client). Usage: ``python benchmarks/analysis.py [--store PATH] [--repeat 2]
[--skip-plain]``.

Figures, the 2-core machine shared (load about 2.5), 2026-11-25:
see the report of the change that added this script (issue #27 item 5).
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
        ways["xr.open_zarr"] = lambda: xr.open_zarr(args.store)
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
