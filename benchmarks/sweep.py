"""Sweep throughput: `oceanlidar run` on an embedded cluster against a plain render loop.

Renders the same samples four ways and prints samples/s: an in-process loop
(`workers.render.render_arrays`, what a task renders; no dask, no zarr; until 2026-11-24 the
loop called `render`, which builds a dataset too, about 1 ms a 128-pixel sample), the
service's task in-process (`service.run.render_shard`: render, check, checksum, compress,
write; no dask), and the service with one worker process and
with two. The overhead is 1 − (service rate) / (workers × loop rate). On a shared machine
the wall clock drifts with other load, so the sweep is split into rounds (a different seed
each) and every round runs all four ways in turn; the rates sum over rounds. The workers
are warmed by a first run; cluster start-up is excluded and the statistics pass printed
apart. CPU time a sample splits the overhead: the workers' (render and service path,
dask's task handling), and that of this process (client and scheduler), which shares the
cores with two workers on a two-core machine. The default 192 samples are 24 shards of 8,
an even split between two workers (25 shards would leave one worker idle for the last).

Two render loops side by side (two processes, each half the samples) measure what two
cores give without the service: on the shared 2-core machine 1.57–1.71 times one loop, so
the overhead against workers × loop cannot fall below 15–20 % there whatever the service
does; the overhead against the two loops is printed too.

Usage: ``python benchmarks/sweep.py [--samples 192] [--rounds 3] [--pixels 128] [--batch N]``
(``--batch``: samples a shard and a task, as ``oceanlidar run --batch``; by default the
store's choice, `service.store.layout.shard_size`: 8 for the default 64-sample rounds, 40 with
``--samples 960``).

Third session of 2026-11-24, the quiet machine (load 0.5–1.4), ``--samples 960``, shards
of 40, two runs (the second after `service.store.shards.write_shard` stopped comparing chunks
with the fill value: 0.25–0.3 ms less a sample in `write_shard` alone, within this script's
noise): loop 57.0 / 57.2 samples/s (17.5 ms CPU), two loops side by side 1.90 times one;
``render_shard`` in-process 9.5 / 8.6 %; **1 worker 12.1 / 9.8 %**; 2 workers 17.4 /
18.7 % against 2 × loop, **12.9 / 14.5 % against the two loops**; client and scheduler
0.3–0.5 ms a sample. What is left is the write path (+1.8–1.9 ms a sample: zarr's
per-chunk machinery on the two sharded arrays ≈ 0.85 ms, the shard's other arrays and
flags ≈ 0.25, checks 0.2, checksums 0.12) and, with two workers, the cores' contention
(+2.4–2.7 ms a sample on the workers against +1.9–2.5 with one).

Figures after the embedded cluster dropped the dashboard's monitors (`service.cluster.QUIET`:
no worker profiler, slow resource monitor and tick) and tasks stopped building a dataset a
sample (`render_arrays`, which the loop now times too), 2026-11-24, ``--samples 960``,
shards of 40, one run at load 0.1–1.2 (two runs beside a helper's tests, load 3–3.9, gave
1 worker 4.9 and 12.0 % and no usable 2-worker figure: two loops side by side only 0.99–1.11
times one):

====================== ============= ============== ==================================
way                    samples/s     overhead       CPU a sample (workers over loop)
====================== ============= ============== ==================================
render loop            54.1          —              18.5 ms
two loops side by side 97.0          (1.79×)        18.8 ms
run, 1 worker          47.6          12.0 %         +2.5 ms; client+sched. 0.6
run, 2 workers         81.3          24.8 %         +2.9 ms; client+sched. 0.4
2 workers vs two loops —             16.2 %         —
====================== ============= ============== ==================================

Against the table below: the service's samples/s rose 39–40 → 47.6 (1 worker) and
63–71 → 81.3 (2 workers); the client and scheduler's CPU fell from 1.2–2.3 to 0.4–0.6 ms a
sample; the loop itself got 2–3 ms cheaper (no dataset), so the same service costs read as
a larger share of it. The in-process write path is still +2.2 ms (10.5 %), most of it
zarr's per-inner-chunk machinery.

Figures after Blosc-compressed counts, shards sized by bytes and the compiled Poisson
draws (2026-11-24, ``--samples 960``: 320-sample rounds, shards of 40; two runs back to
back on the shared machine, load 1.0–1.8, the second noisier):

====================== ============= ============== ==================================
way                    samples/s     overhead       CPU a sample (workers over loop)
====================== ============= ============== ==================================
render loop            45.9 / 49.0   —              21.8 / 20.4 ms
two loops side by side 74.5 / 77.0   (1.62 / 1.57×) 23.3 / 22.0 ms
run, 1 worker          39.2 / 39.8   14.6 / 18.7 %  +4.1 / +5.0 ms; client+sched. 2.3 / 1.9
run, 2 workers         70.7 / 63.3   22.9 / 35.4 %  +3.1 / +7.4 ms; client+sched. 1.2 / 1.2
2 workers vs two loops —             5.0 / 17.9 %   —
====================== ============= ============== ==================================

The benchmark's own ``render_shard`` line read +5.1–5.3 ms in these two runs (beside its
two idle clusters and pools); measured in one process with nothing beside it
(``render_shard`` on shards of 40 against the loop, 80 samples): +2.1–2.3 ms a sample,
10–12 %: LZ4 of the counts 0.2 ms, zarr's per-chunk write machinery about 1.3 ms (two
sharded arrays a sample), `invalid_values` 0.23 ms, checksums 0.11 ms. Before this
session's changes (zstd, shards of 8, in the same process): +5.9 ms.

Earlier figures:

Figures (128 px, 256² surface, batch 8), one run on the otherwise idle 2-core machine
(load 0.9–1.2), 2026-11-24, after the render of issue #10 got 14–25 % cheaper:

====================== ========= ========= ======================================
way                    samples/s overhead  CPU a sample
====================== ========= ========= ======================================
render loop            42.8      —         23.3 ms
render_shard in-proc.  32.1      24.9 %    +8.6 ms (checks, checksums, zstd, writes)
run, 1 worker          30.8      28.0 %    worker 33.4 ms (+10.1), client+sched. 2.8
run, 2 workers         53.1      38.0 %    workers 32.9 ms (+9.6), client+sched. 1.9
====================== ========= ========= ======================================

Before (the first quiet run of this session, the benchmark's earlier form, 200 samples):
loop 29.6/s, one worker 32.0 %, two 40.1 %. Opening each array once in `write_shard`
(every lookup in the group parsed its metadata again) took its cost from 6.5 to 5.9 ms a
sample. Where the rest goes (measured in-process): zstd (level 3) of the uint32 counts
2.2–2.3 ms, inherent to the stored bytes; zarr's write machinery (each inner chunk an
asyncio task on zarr's loop thread, a shard read back before it is replaced) about 3 ms;
opening the group and its arrays per task 0.55 ms; reading the shard's completion flags
and checksums 0.3 ms; `invalid_values` 0.4 ms; CRC-32 and copies 0.35 ms; dask's task
handling 0.2–0.7 ms. Encoding a shard's files directly (the bytes zarr writes, checked file
for file) halved `write_shard` (7.9–8.6 → 4.2–4.4 ms, one worker 25 → 17 % overhead in a
trial), but re-implements zarr's sharded writer on its private ``zarr.core.sync``: left
out. With two workers on two cores the client and scheduler (this process) take 1.6–2.8
ms CPU a sample, about 5 points of the two-worker overhead. Per-task costs fall with
larger shards (``--batch 32``: +2.6 ms in-process over the loop, at load 5).
"""

import argparse
import contextlib
import multiprocessing
import os
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor

from service.cluster import dask_client
from service.run import render_shard, run_plan, task_batches
from service.stats import write_statistics
from service.store import layout
from service.store.location import Store
from service.store.template import create_store
from service.sweep import parse_sweep
from service.tuning import tune_allocator
from workers.render import render_arrays
from workers.settings.seeds import SampleSeed

SWEEP = """\
name: bench
seed: {seed}
realisations: {realisations}
output: bench.zarr
scene:
  surface: {{grid_size: 256, spacing: 0.016}}
  receiver: {{pixels: {pixels}}}
sweep:
  parameters:
    target.shape: {{values: [sphere, none]}}
"""
WORKERS = (1, 2)
HALVES = ((0, 2), (1, 2))
"""The samples of each of two render loops side by side (``part`` of `in_process`)."""


def in_process(way: str, text: str, url: str, batch: int, part=(0, 1)) -> tuple[float, float]:
    """Render the sweep `text` in this process: a `render_arrays` loop or the service's tasks.

    Runs in a process of its own (no scheduler threads beside it); the loop renders the
    samples ``part[0]::part[1]`` (one of two processes side by side: ``part=(i, 2)``).
    Returns the wall and CPU time taken [s].
    """
    tune_allocator()
    plan = parse_sweep(text)
    if way == "inline":
        create_store(plan, Store(url), samples_per_shard=batch)
    start, cpu = time.perf_counter(), time.process_time()
    if way == "loop":
        for sample in range(part[0], plan.samples, part[1]):
            point, realisation = divmod(sample, plan.realisations)
            seed = SampleSeed(root=plan.sweep.seed, point=point, realisation=realisation)
            render_arrays(plan.scenes[point], seed=seed)
    else:
        for _, jobs in task_batches(plan, range(plan.samples), batch):
            render_shard(Store(url), jobs)
    return time.perf_counter() - start, time.process_time() - cpu


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--samples", type=int, default=192)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--pixels", type=int, default=128)
    parser.add_argument(
        "--batch", type=int, default=None, help="samples a shard (default: the store's choice)"
    )
    args = parser.parse_args()
    tune_allocator()
    per_round = args.samples // args.rounds // 2
    plans = [
        parse_sweep(SWEEP.format(seed=seed, realisations=per_round, pixels=args.pixels))
        for seed in range(1, args.rounds + 1)
    ]
    args.batch = layout.shard_size(plans[0], args.batch)
    ways = ["loop", "pair", "inline", *WORKERS]
    wall = dict.fromkeys(ways, 0.0)
    cpu = dict.fromkeys(ways, 0.0)  # this process
    worker_cpu = dict.fromkeys(WORKERS, 0.0)
    stats = dict.fromkeys(WORKERS, 0.0)
    samples = sum(plan.samples for plan in plans)
    loads = [os.getloadavg()[0]]
    with contextlib.ExitStack() as stack, tempfile.TemporaryDirectory() as folder:
        quiet = stack.enter_context(open(os.devnull, "w"))
        alone = stack.enter_context(
            ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"))
        )
        pair = stack.enter_context(
            ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn"))
        )
        warm = os.path.join(folder, "warm.zarr")  # imports, per-scene caches
        alone.submit(in_process, "inline", plans[0].text, warm, args.batch).result()
        for half in [pair.submit(in_process, "loop", plans[0].text, "", 0, h) for h in HALVES]:
            half.result()
        clients = {n: stack.enter_context(dask_client(workers=n, scheduler=None)) for n in WORKERS}
        for n, client in clients.items():
            client.run(tune_allocator)
            warm = os.path.join(folder, f"warm{n}.zarr")  # imports, per-scene caches
            create_store(plans[0], Store(warm), samples_per_shard=args.batch)
            run_plan(plans[0], Store(warm), client=client, progress_stream=quiet)
        for i, plan in enumerate(plans):
            for way in ways:
                url = os.path.join(folder, f"{way}-{i}.zarr")
                if way in WORKERS:
                    create_store(plan, Store(url), samples_per_shard=args.batch)
                    before = clients[way].run(time.process_time)
                    start, cpu0 = time.perf_counter(), time.process_time()
                    result = run_plan(plan, Store(url), client=clients[way], progress_stream=quiet)
                    assert result.written == plan.samples
                    seconds = time.perf_counter() - start, time.process_time() - cpu0
                elif way == "pair":  # two loops side by side: what two cores give
                    halves = [
                        pair.submit(in_process, "loop", plan.text, url, args.batch, h)
                        for h in HALVES
                    ]
                    both = [half.result() for half in halves]
                    seconds = max(s[0] for s in both), sum(s[1] for s in both)
                else:
                    seconds = alone.submit(in_process, way, plan.text, url, args.batch).result()
                wall[way] += seconds[0]
                cpu[way] += seconds[1]
                if way in WORKERS:
                    after = clients[way].run(time.process_time)
                    worker_cpu[way] += sum(after[w] - before[w] for w in before)
                    start = time.perf_counter()
                    write_statistics(Store(url))
                    stats[way] += time.perf_counter() - start
            loads.append(os.getloadavg()[0])
    rate = {way: samples / wall[way] for way in ways}
    ms = {way: 1e3 * cpu[way] / samples for way in ways}
    print(
        f"{samples} samples of {args.pixels}² px, six gates, 256² surface, {args.rounds} rounds, "
        f"shards of {args.batch}"
    )
    print(f"load average (1 min) by round: {' '.join(f'{x:.2f}' for x in loads)}")
    print(
        f"in-process render loop:  {rate['loop']:6.2f} samples/s, {ms['loop']:.1f} ms CPU a sample"
    )
    print(
        f"two render loops, side by side: {rate['pair']:6.2f} samples/s "
        f"({rate['pair'] / rate['loop']:.2f} times one), {ms['pair']:.1f} ms CPU a sample"
    )
    print(
        f"render_shard in-process: {rate['inline']:6.2f} samples/s, overhead "
        f"{100 * (1 - rate['inline'] / rate['loop']):5.1f} %; CPU a sample "
        f"{ms['inline'] - ms['loop']:+.1f} ms over the loop (checks, checksums, compression, "
        "writes)"
    )
    for n in WORKERS:
        work = 1e3 * worker_cpu[n] / samples
        print(
            f"oceanlidar run, {n} worker(s): {rate[n]:6.2f} samples/s, overhead "
            f"{100 * (1 - rate[n] / (n * rate['loop'])):5.1f} %; CPU a sample: workers "
            f"{work:.1f} ms ({work - ms['loop']:+.1f} over the loop), client and scheduler "
            f"{ms[n]:.1f} ms "
            f"(statistics passes {stats[n]:.1f} s)"
        )
    print(
        f"two workers against two loops side by side: overhead "
        f"{100 * (1 - rate[2] / rate['pair']):5.1f} %"
    )


if __name__ == "__main__":
    main()
