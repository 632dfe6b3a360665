"""The sweep's commands: ``run``, ``validate`` (with an estimated run time) and ``schema``.

Each takes the parsed arguments (`service.cli.parser`) and returns an exit code; bad input
is raised as a `service.errors.InputError` and reported by `service.cli.main`. A sweep is
admitted as the job service admits one (`service.admission`). Messages go through
the ``oceanlidar`` logger (``-q`` keeps the errors only), what a command prints as its
result goes to stdout.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import sys
import threading
import time
from pathlib import Path

import dask
import yaml
from dask.utils import format_bytes, format_time

from service.admission import Rules, admit
from service.batching import (
    BUDGET_SHARE,
    batch_samples,
    given_memory,
    sample_memory,
    task_memory,
)
from service.devices import NUMPY, check_renderers, choose
from service.errors import BadFileError, BadOptionError, BadSweepError
from service.inputs import DEFAULT_MAX_MEMORY, read_text, shown
from service.schema import sweep_json_schema
from service.store.integrity import invalid_values
from service.store.layout import shard_size
from service.store.location import Store
from service.sweep import Plan
from service.tasks import render_samples
from workers.backends.backend import Backend
from workers.backends.caches import clear_all
from workers.sea.cascades import describe
from workers.settings.section import SceneError
from workers.setup.seasetup import scene_sea

__all__ = [
    "batch_lines",
    "cmd_run",
    "cmd_schema",
    "cmd_validate",
    "memory_limit",
    "report_samples",
    "run_time",
    "sigterm_raises",
]

log = logging.getLogger("oceanlidar")

EXIT_OK, EXIT_FAILURE = 0, 1
SHOWN_SEAS = 3
"""Most distinct seas whose resolved shares `validate` prints."""
TIMED_BATCH = 8
"""Most samples of `validate`'s timed batch on torch (`_timed_render`)."""
SHOWN_PROBLEMS = 20
"""Most samples named under one reason in a report; the rest are counted."""
CLUSTER_START = 4.0
"""Seconds an embedded cluster takes before its workers can render: the scheduler and the
worker processes started, each importing the renderer (numpy, scipy, numba) for its first
task. ``benchmarks/cluster_start.py``: medians 3.4 s with 1 worker, 4.1 s with 2, on the
shared 2-core machine under load (2026-11-25); `validate`'s estimate counts it once."""


def memory_limit(args) -> float:
    """The most memory [bytes] one sample may need, by ``--max-memory`` (GiB).

    Raises
    ------
    BadOptionError
        If ``--max-memory`` is not a positive number.
    """
    if args.max_memory is not None and not args.max_memory > 0:
        raise BadOptionError("--max-memory must be a positive number of GiB")
    return DEFAULT_MAX_MEMORY if args.max_memory is None else args.max_memory * 2**30


def batch_lines(plan: Plan, backend: Backend, *, memory: float | None, workers: int) -> list[str]:
    """The batches a run's tasks render, for people: the sweep's largest scene's.

    A task renders its shard's samples of one scene in batches of
    `service.batching.batch_samples` (`service.tasks.render_shard`), at most the shard's
    samples of a point (its realisations, as a rule). The budget is `memory`
    (``--batch-memory``), else `BUDGET_SHARE` of `service.batching.task_memory` on `backend`
    with `workers` sharing this machine (a ``--scheduler``'s workers may have other memory:
    they size their batches themselves).
    """
    point = max(range(len(plan.scenes)), key=lambda p: sample_memory(plan.scenes[p]))
    scene = plan.scenes[point]
    if memory is None:
        task, source = task_memory(backend, workers=workers)
        budget, source = BUDGET_SHARE * task, f"{BUDGET_SHARE:.0%} of {source}"
    else:
        budget, source = memory, "--batch-memory"
    per_sample, most = sample_memory(scene), min(shard_size(plan), plan.realisations)
    batch = min(batch_samples(scene, budget), most)
    largest = ", the largest" if len(plan.scenes) > 1 else ""
    capped = f"; a shard holds {most} of a point" if batch == most else ""
    return [
        f"  batches: up to {batch} samples of a scene at once on {backend.device}, about "
        f"{format_bytes(batch * per_sample)} a batch ({format_bytes(per_sample)} a sample "
        f"at point {point}{largest}{capped})",
        f"  batch memory: {format_bytes(budget)} ({source})",
    ]


def load(args) -> Plan:
    """The plan of ``args.sweep`` admitted under the limits the flags set (`admit`).

    With ``--resume``, of the store at ``--output`` (or the sweep's ``output``).
    """
    rules = Rules(limits=not args.no_limits, max_memory=memory_limit(args))
    text = read_text(args.sweep, place=args.sweep)
    resume = None
    if getattr(args, "resume", False):  # `validate` has no --resume

        def resume(output: str) -> Store:
            return Store.at(args.output or output, args.storage_options)

    return admit(text, folder=Path(args.sweep).parent, rules=rules, resume=resume)


def plan_lines(
    plan: Plan, batch: int | None = None, url: str | None = None, *, resume: bool = False
) -> list[str]:
    """The plan for people: points, samples, tasks, storage, what is swept, where to.

    With `resume`, the tasks are those of a new store: a resumed store keeps its shards.
    """
    batch = shard_size(plan, batch)
    tasks = -(-plan.samples // batch)
    kept = " for a new store; a resumed one keeps its own" if resume else ""
    return [
        f"sweep {plan.sweep.name!r}: {len(plan.points)} parameter points x "
        f"{plan.realisations} realisations = {plan.samples} samples",
        f"  tasks: {tasks} (shards of {batch} samples{kept})",
        f"  storage: about {format_bytes(plan.total_bytes())} uncompressed "
        f"({format_bytes(plan.sample_bytes())} per sample)",
        f"  swept: {', '.join(plan.swept) or '(nothing)'}",
        f"  output: {url or plan.sweep.output}",
    ]


def run_time(
    *, samples: int, scenes: int, setup: float, per_sample: float, workers: int, start: float
):
    """Estimated seconds of a run: its start once, every scene's setup, every sample.

    Parameters
    ----------
    samples, scenes : int
        Samples to render, and distinct scenes among the points (each set up once per
        worker that meets it; counted once, an underestimate when workers share scenes).
    setup, per_sample : float
        Seconds of one scene's setup (its frames' geometry, kriging system) and of one
        sample once set up.
    workers : int
        Worker processes rendering in parallel (the setups and samples are shared out).
    start : float
        Seconds paid once before any sample, by every worker at the same time: the
        cluster's start (`CLUSTER_START`) and the compilation of the renderer's kernels
        (numba; loaded from its cache once compiled).
    """
    return start + (scenes * setup + samples * per_sample) / max(workers, 1)


def _timed_render(
    plan: Plan, point: int = 0, backend: Backend = NUMPY
) -> tuple[float, float, float]:
    """Seconds of the renderer's compilation, a scene's setup and one sample, on `backend`.

    The first frame of `point`'s first samples is rendered three times: first as a fresh
    worker renders it (its kernels compiled, or loaded from numba's cache, the scene set
    up), then set up, then with every cache of the renderer emptied (set up again, the
    kernels still compiled). The setup and the sample are scaled by the number of frames
    (each frame has its own geometry and its own light), the compilation is not. On torch
    each render is a batch of the point's first samples (at most `TIMED_BATCH`, as a task
    renders a shard's samples of a scene: `service.tasks.render_samples`) and a sample's
    time is the batch's share; on numpy, where a batch is its samples one by one, one.
    """
    batch = 1 if backend.name == "numpy" else min(TIMED_BATCH, plan.realisations)
    samples = [plan.sample(point * plan.realisations + i) for i in range(batch)]
    sequence = samples[0].scene.sequence
    first_frame = samples[0].scene.model_copy(
        update={"sequence": sequence.model_copy(update={"frames": 1})}
    )
    seeds = [sample.seed for sample in samples]
    timings = []
    for cleared in (False, False, True):
        if cleared:
            clear_all()
        started = time.perf_counter()
        try:
            rendered = render_samples(first_frame, seeds, backend=backend)
        except SceneError as error:
            raise BadSweepError(f"{samples[0].describe()}: {error}") from None
        timings.append(time.perf_counter() - started)
        # what `run` would refuse to write (every sample of the scene alike, as a rule)
        reason = invalid_values({k: v[0] for k, v in rendered.items()}, first_frame)
        if reason is not None:
            raise BadSweepError(f"{samples[0].describe()}: renders invalid values: {reason}")
    first, set_up, again = timings
    frames = sequence.frames
    return max(first - again, 0.0), frames * max(again - set_up, 0.0), frames * set_up / batch


def _estimate_workers(args, backend: Backend) -> tuple[int, str]:
    """The workers a run's estimate counts, and their name: ``--workers``, cores or GPUs."""
    if backend.device == "cpu":
        return args.workers or os.cpu_count() or 1, "worker(s)"
    import torch  # checked by `choose`

    gpus = 1 if ":" in backend.device else torch.cuda.device_count()
    return args.workers or gpus, f"GPU worker(s) ({backend.name} on {backend.device})"


def _sea_lines(plan: Plan) -> list[str]:
    """What the sea's cascades resolve of the spectrum, per distinct sea of the plan."""
    seas: dict = {}
    for point, scene in enumerate(plan.scenes):
        if (sea := scene_sea(scene)) is not None:
            seas.setdefault(sea, []).append(point)
    lines = [
        f"  sea at point {points[0]}{f' (+{len(points) - 1} more)' if len(points) > 1 else ''}:"
        f" {describe(sea)}"
        for sea, points in list(seas.items())[:SHOWN_SEAS]
    ]
    if len(seas) > SHOWN_SEAS:
        lines.append(f"  ... and {len(seas) - SHOWN_SEAS} more seas")
    return lines


def cmd_validate(args) -> int:
    """Check a sweep; print its plan, its seas' resolved shares, its batches, a run time."""
    memory = given_memory(args.batch_memory)
    plan = load(args)
    print("\n".join(plan_lines(plan) + _sea_lines(plan)))
    backend = choose(args.backend, args.device)
    check_renderers(plan, backend)
    workers, kind = _estimate_workers(args, backend)
    print("\n".join(batch_lines(plan, backend, memory=memory, workers=workers)))
    if args.show_scene:
        print("# the scene of point 0, every default filled in (units: `oceanlidar schema`)")
        print(yaml.safe_dump(plan.scenes[0].model_dump(mode="json"), sort_keys=False), end="")
    if args.no_estimate:
        return EXIT_OK
    # one render per renderer (transport.method): Monte Carlo takes far longer a sample
    points: dict[str, list[int]] = {}
    for point, scene in enumerate(plan.scenes):
        points.setdefault(scene.transport.method, []).append(point)
    timed = {method: _timed_render(plan, where[0], backend) for method, where in points.items()}
    compiled = sum(compile_time for compile_time, _, _ in timed.values())  # kernels apart
    setup, per_sample = (
        sum(timed[method][i] * len(where) for method, where in points.items()) / len(plan.scenes)
        for i in (1, 2)
    )
    seconds = run_time(
        samples=plan.samples,
        scenes=len(set(plan.scenes)),
        setup=setup,
        per_sample=per_sample,
        workers=workers,
        start=CLUSTER_START + compiled,
    )
    renders = " and ".join(
        f"{format_time(sample)}{f' with {method}' if len(timed) > 1 else ''}"
        for method, (_, _, sample) in timed.items()
    )
    print(
        f"  run time: about {format_time(seconds)} on {workers} {kind} (the cluster "
        f"starts in about {format_time(CLUSTER_START)}, the renderer compiles in "
        f"{format_time(compiled)}, a scene's setup takes {format_time(setup)}, a sample "
        f"renders in {renders})"
    )
    return EXIT_OK


def cmd_schema(args) -> int:
    """Print the JSON Schema of sweep files."""
    print(json.dumps(sweep_json_schema(), indent=2, ensure_ascii=False))
    return EXIT_OK


def security(args):
    """A `distributed.Security` from the TLS flags (all three, encryption required)."""
    given = [args.tls_ca_file, args.tls_cert, args.tls_key]
    if not any(given):
        if (args.scheduler or "").startswith("tls://") and not dask.config.get(
            "distributed.comm.tls.ca-file", None
        ):
            raise BadOptionError(
                f"--scheduler {shown(args.scheduler)}: a tls:// scheduler needs "
                "--tls-ca-file, --tls-cert and --tls-key (or dask's TLS configuration)"
            )
        return None
    if not all(given):
        raise BadOptionError("--tls-ca-file, --tls-cert and --tls-key go together")
    for path in given:
        if not os.path.isfile(path):
            raise BadFileError(f"{path}: no such file")
    from distributed import Security

    return Security(
        tls_ca_file=args.tls_ca_file,
        tls_client_cert=args.tls_cert,
        tls_client_key=args.tls_key,
        require_encryption=True,
    )


def report_samples(plan: Plan, what: str, problems: list) -> None:
    """Log ``(sample, reason)`` problems by reason, each with its samples' parameters."""
    by_reason: dict[str, list[int]] = {}
    for sample, reason in problems:
        by_reason.setdefault(reason, []).append(sample)
    for reason, samples in by_reason.items():
        count = f"{len(samples)} sample" + ("s" if len(samples) > 1 else "")
        log.error("%s %s: %s", count, what, reason)
        for sample in samples[:SHOWN_PROBLEMS]:
            log.error("  %s", plan.sample(sample).describe())
        if len(samples) > SHOWN_PROBLEMS:
            log.error("  ... and %d more", len(samples) - SHOWN_PROBLEMS)


def _check_run_flags(args) -> None:
    if args.workers is not None and args.workers < 1:
        raise BadOptionError("--workers must be at least 1")
    if args.batch is not None and args.batch < 1:
        raise BadOptionError("--batch must be at least 1")
    given_memory(args.batch_memory)
    if not args.task_timeout > 0:
        raise BadOptionError("--task-timeout must be a positive number of seconds")
    if args.verify and not args.resume:
        raise BadOptionError("--verify goes with --resume (a new store has nothing to verify)")


@contextlib.contextmanager
def sigterm_raises(stop: type[BaseException]):
    """SIGTERM (``docker stop``, ``kill``, a batch system's time limit) raises `stop`.

    The system's default ends the process on the spot, nothing cleaned up: the writer's
    lock left behind, the embedded cluster's workers killed (their semaphores leaked, the
    resource tracker's warning). Raised, `stop` unwinds the command: `run` takes
    ``KeyboardInterrupt`` and stops as interrupted (lock released, cluster closed, the
    summary and the ``--resume`` hint printed); ``serve`` takes ``SystemExit`` and exits
    0 once its jobs are stopped resumably and its cluster closed (uvicorn, which stops
    serving on SIGTERM first, raises the signal again with this handler). Only from the
    main thread, where signals are handled.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum, frame):
        raise stop

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:  # None: a handler not set from Python, the system's default
        signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)


def cmd_run(args) -> int:
    """Run a sweep into its store; report what failed, by sample and parameters."""
    from service.cluster import ClusterError
    from service.run import execute

    _check_run_flags(args)
    # the embedded cluster renders here: checked now; a scheduler's workers, by its probe
    backend = choose(args.backend, args.device, here=args.scheduler is None)
    plan = load(args)
    check_renderers(plan, backend)
    url = args.output or plan.sweep.output
    for line in plan_lines(plan, args.batch, url, resume=args.resume):
        log.info(line)
    store = Store.at(url, args.storage_options)
    if args.resume:
        with store.errors():
            if not store.occupied():  # README: --resume completes an interrupted run
                log.info("nothing at %s to resume: starting a new run", url)
    try:
        with sigterm_raises(KeyboardInterrupt):
            result = execute(
                plan,
                store,
                workers=args.workers,
                scheduler=args.scheduler,
                security=security(args),
                dashboard=args.dashboard,
                verbose=args.verbose > 0,
                resume=args.resume,
                verify=args.verify,
                overwrite=args.overwrite,
                batch_size=args.batch,
                task_timeout=args.task_timeout,
                progress_stream=None if args.quiet else sys.stderr,
                backend=backend,
                batch_memory=given_memory(args.batch_memory),
            )
    except ClusterError as error:
        log.error("oceanlidar run: error: %s", error)
        return EXIT_FAILURE
    report_samples(plan, "damaged or missing, recomputed", result.damaged)
    if result.relabelled:
        log.error(
            "damaged or missing, written again from the sweep: %s", ", ".join(result.relabelled)
        )
    rate = result.written / result.seconds if result.seconds > 0 else 0.0
    log.info(
        "%s: wrote %d samples in %s (%.2f samples/s)%s",
        url,
        result.written,
        format_time(result.seconds),
        rate,
        f", {result.skipped} already complete" if result.skipped else "",
    )
    if result.interrupted:
        log.error("interrupted: run again with --resume to complete %s", url)
        return EXIT_FAILURE
    for what, problems in result.problems().items():
        report_samples(plan, what, problems)
    if result.stopped:
        log.error("stopped: %s; run again with --resume", result.stopped)
    if not result.ok:
        log.error("statistics not written: some samples failed")
        return EXIT_FAILURE
    log.info("statistics: %s", Store(url).stats.url)  # beside the output as it was named
    return EXIT_OK
