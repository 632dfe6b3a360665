"""Read throughput of a store: the training reader against xarray, samples per second.

Renders a sweep of 128-pixel six-gate samples with noise into a local store (shards as
`service.store.layout.shard_size` chooses by default: 40 samples), then reads every sample in a
shuffled order, as a training epoch does: `service.dataset.SampleDataset` in batches
(``__getitems__``, what a ``torch.utils.data.DataLoader`` with a batch sampler calls), by a
reader made for the epoch (each shard's index and small arrays read as it goes) and by one
that has read them, one item at a time (``__getitem__``), with the image converted to float32
(``image_dtype``), and checking the CRC-32 of a store
written before issue #26 instead of the CRC32C; ``xr.open_zarr`` in batches and one sample
at a time. Each read returns the noisy image and the target mask, each sample checked
against its checksum (over every rendered array). Rendering is excluded; the store is read
once before timing, so the figures are for a warm page cache; each is the fastest of
``--repeat`` reads (the machine is shared). Usage: ``python benchmarks/read.py
[--samples 512] [--pixels 128] [--batch 32] [--repeat 3]``.

Figures, one run each on the 2-core machine (load 0.9), 2026-11-24, counts compressed by
zstd (before) and by LZ4 after a bit shuffle (Blosc, now): 121.9 → 94.1 KiB a sample on
disk; SampleDataset in batches 1765 → 3341 samples/s, one item at a time 1731 → 3226;
``xr.open_zarr`` in batches 223 (both), one sample at a time 75 → 80.

Every sample checked against its checksum (issue #26), 2026-11-25, the 2-core machine
shared (load 4 to 6: ``xr.open_zarr`` reads at 60 % of the speed above), before → after,
the same script back to back: SampleDataset in batches 2661 → 2399 samples/s, one item at
a time 2417 → 2198, a new reader 1903 → 1837, checking the CRC-32 of an older store 1948.
The same reads interleaved in one process, fastest of five (image and mask alone, then
checked): 3580 → 2721 samples/s (279 → 367 µs a sample: 27 µs of CRC32C over the 400 KiB
of a sample's arrays, the rest reading its small arrays and flags); by the CRC-32 of
older stores 2225 (449 µs: zlib's CRC-32 runs at 2.3 GB/s here, CRC32C at 28).

Writable arrays of the item's own (issue #27: each chunk decompressed into a new array, not
viewed read-only; labels copied) and ``image_dtype=np.float32``, 2026-11-25, the 2-core
machine shared (load 5 to 8), the three readers interleaved in one process in batches of 32,
fastest of 9 and of 15 in two runs: read-only views 3426 and 2914 samples/s (292, 343 µs a
sample), writable 3015 and 3036 (332, 329 µs), float32 images 2935 and 2947 (341, 339 µs):
writable arrays cost nothing measurable (the two runs disagree by more), the conversion
about 10 µs a sample. This script back to back, after → before, at load 10 to 14 (every
figure less than half the quiet machine's: ``xr.open_zarr`` in batches 108 → 145): in batches
1147 → 1164 samples/s, one item at a time 1197 → 1040, a new reader 1456 → 1076, float32
images 1174.
"""

import argparse
import os
import tempfile
import time

import numpy as np
import xarray as xr

from service.cluster import dask_client
from service.dataset import SampleDataset
from service.run import run_plan
from service.store.location import Store
from service.store.template import create_store
from service.sweep import parse_sweep

SWEEP = """\
name: read
seed: 1
realisations: {realisations}
output: read.zarr
scene:
  surface: {{grid_size: 64, spacing: 0.064, allow_repeat: true}}
  receiver: {{pixels: {pixels}}}
sweep:
  parameters:
    target.shape: {{values: [sphere, none]}}
"""


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--samples", type=int, default=512)
    parser.add_argument("--pixels", type=int, default=128)
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--repeat", type=int, default=3, help="the fastest of REPEAT reads")
    args = parser.parse_args()
    plan = parse_sweep(SWEEP.format(realisations=args.samples // 2, pixels=args.pixels))
    order = np.random.default_rng(0).permutation(plan.samples)
    batches = [order[i : i + args.batch] for i in range(0, len(order), args.batch)]
    with tempfile.TemporaryDirectory() as folder:
        url = os.path.join(folder, "read.zarr")
        create_store(plan, Store(url))
        with dask_client(workers=2, scheduler=None) as client, open(os.devnull, "w") as quiet:
            run_plan(plan, Store(url), client=client, progress_stream=quiet)
        size = sum(
            os.path.getsize(os.path.join(root, f))
            for root, _, files in os.walk(url)
            for f in files
        )
        print(
            f"{plan.samples} samples of {args.pixels}² pixels, six gates, with noise: "
            f"{size / plan.samples / 1024:.1f} KiB per sample on disk"
        )
        reader = SampleDataset(url)
        reader.__getitems__(order)  # warm the page cache
        ds = xr.open_zarr(url)[["image", "target_mask"]]
        item = reader[0]
        print(
            "an item: "
            + ", ".join(f"{k} {v.dtype} {v.shape}" for k, v in item.items() if v.ndim > 2)
            + f"; each checked against its checksum over {', '.join(reader.checked)}"
        )
        floats = SampleDataset(url, image_dtype=np.float32)
        crc32 = SampleDataset(url)
        crc32.checksum = "checksum"  # as it checks a store written before issue #26
        crc32.__getitems__(order)
        ways = {
            f"SampleDataset, batches of {args.batch}, a new reader": lambda: [
                fresh.__getitems__(batch) for fresh in [SampleDataset(url)] for batch in batches
            ],
            f"SampleDataset, batches of {args.batch}": lambda: [
                reader.__getitems__(batch) for batch in batches
            ],
            "SampleDataset, one item at a time": lambda: [reader[i] for i in order],
            f"SampleDataset, batches of {args.batch}, image as float32": lambda: [
                floats.__getitems__(batch) for batch in batches
            ],
            f"SampleDataset, batches of {args.batch}, CRC-32 (older stores)": lambda: [
                crc32.__getitems__(batch) for batch in batches
            ],
            f"xr.open_zarr, batches of {args.batch}": lambda: [
                ds.isel(sample=np.sort(batch)).load() for batch in batches
            ],
            "xr.open_zarr, one sample at a time": lambda: [
                ds.isel(sample=int(i)).load() for i in order
            ],
        }
        for label, read in ways.items():
            seconds = min(_timed(read) for _ in range(args.repeat))
            print(f"{label:50} {plan.samples / seconds:8.0f} samples/s")


def _timed(read) -> float:
    """Seconds `read` takes."""
    start = time.perf_counter()
    read()
    return time.perf_counter() - start


if __name__ == "__main__":
    main()
