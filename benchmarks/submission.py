"""Submission to the job service: how long ``POST /v1/jobs`` takes to answer, and where.

Until issue #27 item 3 the service validated the whole sweep inside the POST; now it
answers after the quick checks (`service.admission.admit_header`) and validates the rest
in the background (`service.admission.admit_job`, the validator thread of
`service.jobs.Runner`). This prints, for one sweep file, the steps of the whole
validation (the YAML and schema, every point's scene, the size limits, the output), the
time `Runner.submit` takes to accept it (the POST's answer, HTTP aside) and the time until
the validator has queued it, medians over ``--rounds``. Nothing runs (no cluster).

Usage: ``python benchmarks/submission.py [SWEEP] [--rounds 3]`` (default
``configs/mldc-detection.yaml``, 2000 points).

2026-11-25, the shared 2-core machine, ``configs/mldc-detection.yaml``. Under load 2.8 (one
round, profiled): the old POST took 6.7–9.7 s, each point's scene 2.5–4.7 s (the footprint
check and the count type's scene set-up most), the size limits 2.0–3.0 s
(`Plan.total_bytes` sets each scene up again), the quick part 0.01 s, the output 0.001 s.
Under load 9, medians of 3 rounds: quick checks 0.020 s, every point's scene 6.4 s, size
limits 4.5 s, output 0.001 s; the new POST is answered in 0.030 s and the job is queued
13.6 s later (the whole validation again, in the background).
"""

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from service.admission import SERVICE, admit_header, check_output
from service.inputs import read_text
from service.jobs import Runner
from service.records import JobState
from service.store.location import Store
from service.sweep import parse_sweep
from service.table import JobTable


def steps(text: str, root: Store) -> dict[str, float]:
    """Seconds of each step of the whole validation (what the old POST did)."""
    times = {}
    start = time.perf_counter()
    _, url = admit_header(text, "new", data_root=root)
    times["quick checks (admit_header)"] = time.perf_counter() - start
    start = time.perf_counter()
    plan = parse_sweep(text, folder=root.url, max_memory=SERVICE.max_memory)
    times["every point's scene (parse_sweep)"] = time.perf_counter() - start
    start = time.perf_counter()
    plan.check_limits(remedy=SERVICE.too_big)
    times["size limits (check_limits)"] = time.perf_counter() - start
    start = time.perf_counter()
    check_output(plan, root.other(url), resume=False, overwrite=False, rules=SERVICE)
    times["output (check_output)"] = time.perf_counter() - start
    return times


def submission(text: str, folder: Path) -> tuple[float, float]:
    """Seconds until a runner accepts `text`, and until its validator has queued it."""
    (folder / "data").mkdir()
    table = JobTable(str(folder / "jobs.sqlite"))
    runner = Runner(
        table,
        None,
        data_root=Store(str(folder / "data")),
        max_running=0,  # nothing starts
        queue_limit=10,
        batch_size=None,
    )
    runner.start()
    try:
        start = time.perf_counter()
        job, _ = runner.submit(text, owner="bench")
        accepted = time.perf_counter() - start
        while table.get(job.id).state is JobState.VALIDATING:
            time.sleep(0.01)
        queued = time.perf_counter() - start
    finally:
        runner.stop()
    assert table.get(job.id).state is JobState.QUEUED, table.get(job.id).message
    return accepted, queued


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sweep", nargs="?", default="configs/mldc-detection.yaml")
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    text = read_text(args.sweep, place=args.sweep)
    rounds: dict[str, list[float]] = {}
    for _ in range(args.rounds):
        with tempfile.TemporaryDirectory() as folder:
            root = Store(folder)
            for name, seconds in steps(text, root).items():
                rounds.setdefault(name, []).append(seconds)
        with tempfile.TemporaryDirectory() as folder:
            accepted, queued = submission(text, Path(folder))
        rounds.setdefault("POST answered (Runner.submit)", []).append(accepted)
        rounds.setdefault("validated, queued (background)", []).append(queued)
    print(f"{args.sweep}, medians of {args.rounds} rounds:")
    for name, seconds in rounds.items():
        print(f"  {name:<36} {statistics.median(seconds):8.3f} s")


if __name__ == "__main__":
    main()
