"""Sweep throughput: `oceanlidar run` on an embedded cluster against a plain render loop.

Renders the same samples three ways in one run and prints samples/s: an in-process loop
(`render` only, no dask, no zarr), the service with one worker process, and with two. The
overhead of dask and zarr is 1 − (service rate) / (workers × loop rate). The workers are
warmed by a first run; cluster start-up is excluded and the statistics pass printed apart.
Usage: ``python benchmarks/sweep.py [--samples 48] [--pixels 128]``.
"""

import argparse
import os
import tempfile
import time

from service import store
from service.cluster import dask_client
from service.run import run_plan
from service.stats import write_statistics
from service.sweep import parse_sweep
from service.tuning import tune_allocator
from workers.render import render
from workers.seeds import SampleSeed

SWEEP = """\
name: bench
seed: 1
realisations: {realisations}
output: bench.zarr
scene:
  surface: {{grid_size: 256, spacing: 0.016}}
  receiver: {{pixels: {pixels}}}
sweep:
  parameters:
    target.shape: {{values: [sphere, none]}}
"""


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--samples", type=int, default=200)
    parser.add_argument("--pixels", type=int, default=128)
    args = parser.parse_args()
    tune_allocator()
    plan = parse_sweep(SWEEP.format(realisations=args.samples // 2, pixels=args.pixels))
    render(plan.scenes[0], seed=0)
    start = time.perf_counter()
    for sample in range(plan.samples):
        point, realisation = divmod(sample, plan.realisations)
        render(plan.scenes[point], seed=SampleSeed(root=1, point=point, realisation=realisation))
    loop = plan.samples / (time.perf_counter() - start)
    print(f"{plan.samples} samples of {args.pixels}² pixels, six gates, 256² surface")
    print(f"in-process render loop: {loop:6.2f} samples/s")
    with tempfile.TemporaryDirectory() as folder, open(os.devnull, "w") as quiet:
        for workers in (1, 2):
            with dask_client(workers=workers, scheduler=None) as client:
                # a first, small run warms the workers (imports, per-scene caches)
                warm = os.path.join(folder, f"warm{workers}.zarr")
                store.create_store(plan, warm)
                client.run(tune_allocator)
                run_plan(plan, warm, client=client, progress_stream=quiet)
                url = os.path.join(folder, f"w{workers}.zarr")
                store.create_store(plan, url)
                result = run_plan(plan, url, client=client, progress_stream=quiet)
                start = time.perf_counter()
                write_statistics(url)
                stats = time.perf_counter() - start
            rate = result.written / result.seconds
            print(
                f"oceanlidar run, {workers} worker(s): {rate:6.2f} samples/s, overhead "
                f"{100 * (1 - rate / (workers * loop)):5.1f} % (statistics pass {stats:.1f} s)"
            )


if __name__ == "__main__":
    main()
