"""Bytes per sample on disk for the shipped sweeps (the README's dataset section).

For each config, the first parameter point's scene renders a few realisations into a
store of its own (in this process, one shard), with and without the noise-free
``expected`` images; the per-sample arrays' files (shards, completion records, checksums,
signal means) are summed and divided by the samples. Labels written with the template
(a few bytes per sample) are left out. Usage:
``python benchmarks/storage.py [--samples 8] [configs ...]``.
"""

import argparse
import dataclasses
import os
import tempfile
from pathlib import Path

from service.run import render_shard, task_batches
from service.store.location import Store
from service.store.template import create_store
from service.sweep import load_sweep
from workers.dataset.variables import rendered_order

ROOT = Path(__file__).resolve().parent.parent
PER_SAMPLE = (*rendered_order(), "completed", "checksum")


def stored_bytes(url: str, names=PER_SAMPLE) -> int:
    """Bytes of the chunk files of the arrays `names` of the store at `url`."""
    total = 0
    for name in names:
        folder = Path(url, name)
        if folder.is_dir():
            total += sum(p.stat().st_size for p in folder.iterdir() if p.name != "zarr.json")
    return total


def per_sample(plan, samples: int, *, expected: bool, folder: str) -> tuple[float, float]:
    """Mean bytes per sample of `samples` realisations of the plan's first point, and the
    part of them that is the sea surface (``save_surface``)."""
    sweep = plan.sweep.model_copy(
        update={
            "realisations": samples,
            "store": plan.sweep.store.model_copy(update={"expected": expected}),
        }
    )
    one = dataclasses.replace(plan, sweep=sweep, points=plan.points[:1], scenes=plan.scenes[:1])
    url = os.path.join(folder, f"{plan.sweep.name}-{expected}.zarr")
    create_store(one, Store(url), samples_per_shard=samples)
    for _, jobs in task_batches(one, range(samples), samples):
        render_shard(Store(url), jobs)
    return stored_bytes(url) / samples, stored_bytes(url, ["surface_elevation"]) / samples


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--samples", type=int, default=8)
    parser.add_argument("configs", nargs="*")
    args = parser.parse_args()
    configs = args.configs or sorted(map(str, ROOT.glob("configs/**/*.yaml")))
    print(
        f"{'config':32} {'pixels':>6} {'image':>7} {'KiB/sample':>10} {'of it surface':>13} "
        f"{'with expected':>13}"
    )
    with tempfile.TemporaryDirectory() as folder:
        for path in configs:
            plan = load_sweep(path, max_memory=None)
            scene = plan.scenes[0]
            bare, surface = per_sample(plan, args.samples, expected=False, folder=folder)
            full, _ = per_sample(plan, args.samples, expected=True, folder=folder)
            image = plan.image_dtype().name
            name = str(Path(path).resolve().relative_to(ROOT))
            print(
                f"{name:32} {scene.receiver.pixels:6d} {image:>7} {bare / 1024:10.1f} "
                f"{surface / 1024:13.1f} {full / 1024:13.1f}",
                flush=True,
            )


if __name__ == "__main__":
    main()
