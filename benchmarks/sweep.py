"""Sweep throughput: `oceanlidar run` on an embedded cluster against a plain render loop.

Renders the same samples three ways in one run and prints samples/s: an in-process loop
(`render` only, no dask, no zarr), the service with one worker process, and with two. The
overhead of dask and zarr is 1 − (service rate) / (workers × loop rate). Cluster start-up
and the statistics pass are excluded from the rates and printed apart.
Usage: ``python benchmarks/sweep.py [--samples 48] [--pixels 128]``.
"""

import argparse
import os
import tempfile
import time

from service.run import execute
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
    parser.add_argument("--samples", type=int, default=48)
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
            url = os.path.join(folder, f"w{workers}.zarr")
            start = time.perf_counter()
            result = execute(plan, url, workers=workers, batch_size=4, progress_stream=quiet)
            wall = time.perf_counter() - start
            rate = result.written / result.seconds
            overhead = 1 - rate / (workers * loop)
            print(
                f"oceanlidar run, {workers} worker(s): {rate:6.2f} samples/s "
                f"(overhead {100 * overhead:5.1f} %; whole command {wall:5.1f} s, "
                f"of which {wall - result.seconds:4.1f} s cluster start-up and statistics)"
            )


if __name__ == "__main__":
    main()
