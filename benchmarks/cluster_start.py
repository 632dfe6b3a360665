"""What a run pays before its first sample: the embedded cluster's start, as `validate` counts it.

Starts `service.cluster.embedded_cluster` (the run's own: loopback, `QUIET`, the
`service.cluster` preload) with 1 and with 2 workers and times, in rounds, until every
worker has imported the renderer (``service.run`` and ``workers.render``: numpy, scipy,
numba, what a worker's first task imports), then the cluster's close. Prints each round
and the median; `service.cli.run_commands.CLUSTER_START` is set from these medians.

The renderer's kernels are not compiled here: `validate` times their compilation itself
(or the load from numba's cache), on the sweep's own scene.

2026-11-25, the shared 2-core machine under load (load average 7.5, other engineers'
tests), ``--rounds 3``: 1 worker 3.28 / 3.40 / 3.46 s (median 3.40), closed in 0.7-1.2 s;
2 workers 6.78 / 3.67 / 4.11 s (median 4.11), closed in 0.9-1.9 s.

Usage: ``python benchmarks/cluster_start.py [--rounds 3]``
"""

from __future__ import annotations

import argparse
import os
import statistics
import time


def _import_renderer() -> None:
    import service.run  # noqa: F401
    import workers.render  # noqa: F401


def started(workers: int) -> tuple[float, float]:
    """Seconds to start a cluster of `workers` until each imported the renderer; to close."""
    from distributed import Client

    from service.cluster import embedded_cluster

    begun = time.perf_counter()
    cluster = embedded_cluster(workers=workers)
    client = Client(cluster)
    client.wait_for_workers(workers)
    client.run(_import_renderer)
    ready = time.perf_counter()
    client.close()
    cluster.close()
    return ready - begun, time.perf_counter() - ready


def main() -> None:
    """Print the start and close times of 1- and 2-worker clusters, per round and median."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    import service.cluster  # noqa: F401  (this process's own imports are not the run's)

    print(f"cpus {os.cpu_count()}, load average {os.getloadavg()[0]:.1f}")
    for workers in (1, 2):
        starts = []
        for round_ in range(args.rounds):
            start, close = started(workers)
            starts.append(start)
            print(f"{workers} worker(s), round {round_}: start {start:.2f} s, close {close:.2f} s")
        print(f"{workers} worker(s): median start {statistics.median(starts):.2f} s")


if __name__ == "__main__":
    main()
