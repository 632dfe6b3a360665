"""Cost of a no-op ``run --resume`` and of ``info`` on a big store, seconds and peak RSS.

Builds a synthetic store of ``--samples`` samples (``--points`` random target depths,
``samples // points`` realisations each; 8-pixel one-gate images; ``--shard`` samples a
shard, 40 as for 128-pixel six-gate samples) without rendering: the template written as a
run writes it, then every sample's completion flag and checksums (those of a sample whose
arrays all hold the fill value, which is what a shard file never written reads as) and
statistics that count every sample, as a complete run leaves them. Then, each in a process
of its own (``python -c``, one dask worker), it times the command and reads the peak
resident memory of its process (its dask worker apart): ``run --resume`` and ``info`` of
the complete store, then of the same store with ``--missing`` of its shards (1 %, spread
over it) marked incomplete, whose resume renders them. ``--code DIR`` times another
checkout's commands on the same store (main's, to compare). Usage, from the checkout's
root: ``PYTHONPATH=. python benchmarks/resume.py [--samples 200000] [--points 20000]
[--shard 40] [--missing 0.01] [--code DIR]``.

Figures, the 2-core machine shared (load 4 to 9), 2026-11-25, defaults (200 000 samples,
20 000 points, 5000 shards), one run each, main (commit 300b4a1) → this branch, the same
store (its statistics' counts in one chunk, as this branch writes them: main reads a
chunk a point of those it wrote itself, which these figures leave out): a no-op resume
166 s and 563 MiB → 62 s and 328 MiB (what is left: validating 20 000 points, as every
run does); 50 shards lost, 2000 samples rendered on one worker: 253 s and 566 MiB → 133 s
and 330 MiB; ``info`` 6.0 s and 260 MiB → 8.2 s and 240 MiB (mostly imports; runs differ
by 2 to 5 s). At 20 000 samples of 2000 points: resume 36.0 → 18.8 s.

Then (issue #26 item 8, the rest), 2026-11-25, load 3 to 4, defaults, one run each, main
(commit be42ef7, with ``--code``) → the branch that builds only the scenes a resume renders
(`service.points.Scenes`) and reads the completion flags once: a no-op resume 37.1 s and
348 MiB → 7.4 s and 273 MiB (what is left: imports and the cluster's start, about 5 s,
and every point's memory estimate from its raw values, about 1 s); 50 shards lost, 2000
samples of 200 points rendered on one worker: 55.3 s and 353 MiB → 30.3 s and 279 MiB;
``info`` 3.8 to 5.3 s and 239 MiB on both. cProfile of main's no-op resume (98 s
profiled): parsing the sweep 73 s (per point: ``count_dtype``'s scene set-up 31 s, the
scene's validation 24 s, mostly its footprint check, the raw values' copies and memory
estimates 8 s), the cluster 11 s, the flags read three times 6 s, imports 6 s.
"""

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from service.stats import create_statistics
from service.store.layout import shard_samples
from service.store.location import Store
from service.store.shards import CHECKSUMS, sample_checksum, sample_identity
from service.store.template import create_store
from service.sweep import parse_sweep
from workers.dataset.variables import rendered_order

ROOT = Path(__file__).resolve().parent.parent
SWEEP = """\
name: resume
seed: 1
realisations: {realisations}
output: resume.zarr
scene:
  surface: {{grid_size: 16, spacing: 0.1, allow_repeat: true}}
  receiver: {{pixels: 8, gates: [[2.0, 6.0]]}}
  radiometry: {{mode: normalised, white_plane_photons: 100}}
sweep:
  method: random
  count: {points}
  parameters:
    target.depth: {{distribution: uniform, min: 3.0, max: 5.0}}
"""
MEASURE = (
    "import re, sys\n"
    "from service.cli import main\n"
    "code = main(sys.argv[1:])\n"
    "status = open('/proc/self/status').read()\n"
    "print('peak-rss', re.search(r'VmHWM:\\s+(\\d+)', status)[1], file=sys.stderr)\n"
    "sys.exit(code)\n"
)
"""Runs the command line in a process and reports its own peak RSS [KiB] on stderr (Linux's
``VmHWM``: ``ru_maxrss`` would count the RSS of this script, its parent, at the fork)."""


def sweep_text(*, samples: int, points: int) -> str:
    """A sweep of `points` random target depths and ``samples // points`` realisations each."""
    return SWEEP.format(realisations=samples // points, points=points)


def build(folder: str, *, samples: int, points: int, shard: int) -> tuple[str, str]:
    """The sweep file and a complete synthetic store of it in `folder`."""
    sweep = os.path.join(folder, "resume.yaml")
    Path(sweep).write_text(sweep_text(samples=samples, points=points))
    plan = parse_sweep(Path(sweep).read_text(), max_memory=None)
    store = Store.at(os.path.join(folder, "resume.zarr"))
    create_store(plan, store, samples_per_shard=shard)
    group = store.group("r+")
    size = shard_samples(group)
    names = [name for name in rendered_order() if name in group]
    blank = [np.full(group[n].shape[1:], group[n].fill_value, group[n].dtype) for n in names]
    attrs = group.attrs.asdict()
    for kind in CHECKSUMS:
        if kind in group:
            group[kind][:] = [
                sample_checksum(blank, kind, sample_identity(attrs, sample))
                for sample in range(plan.samples)
            ]
    group["completed"][:] = 1
    statistics(store, realisations=plan.realisations)
    print(f"store: {plan.samples} samples, {len(plan.points)} points, {size} a shard")
    return sweep, store.url


def statistics(store: Store, *, realisations: int) -> None:
    """Statistics beside `store` that count every sample (as a complete run leaves them)."""
    create_statistics(store.dataset(dask=False), store, store.stats, int(store.completed().sum()))
    store.stats.group("r+")["samples"][:] = realisations


def measure(*args: str, code: Path = ROOT) -> tuple[float, float, int]:
    """Seconds, peak RSS [MiB] and exit code of ``oceanlidar ARGS`` in its own process.

    `code`: the checkout whose ``service`` runs (the current folder comes first).
    """
    started = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-c", MEASURE, *args], cwd=code, capture_output=True, text=True
    )
    seconds = time.perf_counter() - started
    peak = [line for line in done.stderr.splitlines() if line.startswith("peak-rss")]
    if not peak:
        sys.exit(f"oceanlidar {' '.join(args)} failed:\n{done.stderr[-2000:]}")
    return seconds, int(peak[-1].split()[1]) / 1024, done.returncode


def report(what: str, sweep: str, url: str, code: Path = ROOT) -> None:
    """Time a resume and ``info`` of the store at `url` (by the checkout `code`)."""
    for name, args in (
        ("run --resume", ("-q", "run", sweep, "--output", url, "--resume", "--workers", "1")),
        ("info", ("-q", "info", url)),
    ):
        seconds, peak, status = measure(*args, code=code)
        print(f"{what:24} {name:14} {seconds:8.1f} s {peak:8.0f} MiB  (exit {status})", flush=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--samples", type=int, default=200_000)
    parser.add_argument("--points", type=int, default=20_000)
    parser.add_argument("--shard", type=int, default=40)
    parser.add_argument("--missing", type=float, default=0.01)
    parser.add_argument(
        "--code", type=Path, default=ROOT, help="the checkout whose commands are timed"
    )
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        started = time.perf_counter()
        sweep, url = build(folder, samples=args.samples, points=args.points, shard=args.shard)
        print(f"built in {time.perf_counter() - started:.1f} s", flush=True)
        report("complete", sweep, url, args.code)
        store = Store.at(url)
        group = store.group()
        size, samples = shard_samples(group), group["completed"].shape[0]
        shards = -(-samples // size)
        lost = np.linspace(0, shards - 1, max(1, round(args.missing * shards))).astype(int)
        store.mark_incomplete(
            [s for shard in lost for s in range(shard * size, min(samples, (shard + 1) * size))]
        )
        report(f"{len(lost)} of {shards} shards lost", sweep, url, args.code)


if __name__ == "__main__":
    main()
