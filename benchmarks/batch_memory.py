"""Peak memory a sample in a batch, against the estimate that sizes the batches.

A task renders a shard's samples of one scene in batches of `service.batching.batch_samples`,
counting each sample at `service.batching.sample_memory` (`service.sweep.memory_estimate`).
This prints, for the default scene (sphere, multi-scale sea, ML(DC) gates) at a few sizes,
the peak allocations of `workers.render.render_batch` traced by ``tracemalloc`` (numpy's
arrays; torch's are not traced) for batches of 1 and of `--batch` samples, cold (every
cache of `workers` emptied: the scene's setup counted in) and warm (the scene set up), the
share of a sample in the batch, the estimate, and the time the estimate takes. Usage, from
the repository root: ``python -m benchmarks.batch_memory [--sizes 64 128 256] [--batch 4]``.

2026-11-29, numpy, on the loaded 2-core machine (the batch renders its samples in turn:
issue #39 item 1 is not in yet): the cold peak of a batch of 4 is that of a batch of 1
within 3 MiB (each sample's arrays are freed before the next; the stacked results are
small), so a sample's share falls as 1/N, and the estimate, N times a sample's, stays an
upper bound with a margin of N at least. MiB:

====== ============ ============ ============ ========
pixels batch 1 cold batch 1 warm batch 4 cold estimate
====== ============ ============ ============ ========
64     26.2         4.6          26.2         78.0
128    26.2         8.5          26.2         120.0
256    51.4         22.7         54.2         288.0
====== ============ ============ ============ ========

A warm sample (its scene set up) peaks at 18 to 44 % of a cold one: where a batch holds
its samples' arrays side by side, those past the first should cost about that much, and
N times the estimate overstates the batch the more, the larger N (to measure once the
batched renderer is in). The estimate takes 0.2 to 0.3 ms a scene, once per scene a task.
"""

import argparse
import time
import tracemalloc

from service.batching import sample_memory
from workers.backends.caches import clear_all
from workers.render import render_batch
from workers.settings.scene import Scene
from workers.settings.seeds import SampleSeed


def traced_peak(scene: Scene, samples: int, *, cold: bool) -> int:
    """Peak bytes traced while `samples` samples of `scene` render in one batch."""
    seeds = [SampleSeed(root=1, point=0, realisation=r) for r in range(samples)]
    if cold:
        clear_all()
    else:
        render_batch(scene, seeds[:1])  # the scene set up, its caches filled
    tracemalloc.start()
    try:
        render_batch(scene, seeds)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 128, 256])
    parser.add_argument("--batch", type=int, default=4)
    args = parser.parse_args()
    render_batch(Scene.model_validate({"receiver": {"pixels": 8}}), [0])  # compiled once
    mib = 2**20
    print("pixels  batch 1 cold  batch 1 warm  batch N cold  per sample  estimate  (MiB)")
    for pixels in args.sizes:
        scene = Scene.model_validate({"receiver": {"pixels": pixels}})
        one_cold = traced_peak(scene, 1, cold=True)
        one_warm = traced_peak(scene, 1, cold=False)
        many = traced_peak(scene, args.batch, cold=True)
        started = time.perf_counter()
        estimate = sample_memory(scene)
        seconds = time.perf_counter() - started
        print(
            f"{pixels:6d}  {one_cold / mib:12.1f}  {one_warm / mib:12.1f}  {many / mib:12.1f}"
            f"  {many / args.batch / mib:10.1f}  {estimate / mib:8.1f}"
            f"  (N = {args.batch}; the estimate in {seconds * 1e3:.2f} ms)"
        )


if __name__ == "__main__":
    main()
