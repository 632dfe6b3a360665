"""Run a sweep on dask (on the client of `service.cluster`), then write its statistics.

One task per shard of the store (`service.store`): it renders the shard's missing samples
and writes the whole shard (`service.tasks.render_shard`). A shard is written by one
task at a time, never two: each shard has one task in the first pass; the samples of
shards whose task failed are then rendered one per task with a single task in flight, and
a shard whose task was given up as stuck (it may still be running) is never given to
another task. Submission is bounded: at most a few tasks per worker thread are in flight,
so the client's memory stays flat whatever the sweep's size. Results never depend on
worker count, order or retries: every sample's random streams are keyed by its position
(`service.sweep.Plan.sample`) and a retried task rewrites the same bytes.

Two kinds of failure: a runtime failure (a worker lost, a storage hiccup) is retried; a
sample whose scene cannot be rendered (`workers.settings.section.SceneError`, an error in the
input)
or whose values are invalid would fail alike on every retry, so its task reports it and
goes on: it is never retried.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import functools
import hashlib
import threading
import time

import numpy as np
from distributed import Client, wait

from service.admission import check_output
from service.cluster import ClusterError, connecting, dask_client
from service.devices import NUMPY, check_on_worker
from service.errors import BadOptionError
from service.progress import Progress, phase
from service.records import RunResult
from service.stats import write_statistics
from service.store import integrity
from service.store.layout import shard_samples
from service.store.location import Store
from service.store.template import create_store
from service.sweep import Plan
from service.tasks import render_shard, task_batches
from workers.backends.backend import Backend

__all__ = [
    "Cancel",
    "RunCancelledError",
    "execute",
    "render_shard",
    "run_plan",
    "task_batches",
]

IN_FLIGHT_PER_THREAD = 2
WINDOW_REFRESH = 5.0
"""Seconds between looks at the cluster's threads, to resize the in-flight window."""
RETRIES = 2
TASK_TIMEOUT = 600.0
"""Seconds after its submission that a task may take before it is given up as stuck."""
TICK = 1.0
"""Seconds between looks at the tasks in flight (timeouts, window)."""
LASTING_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM})
"""Storage failures that stop a run: every further write would fail alike."""
PROBE_TIMEOUT = 120
"""Seconds a worker has to confirm it sees the store, before anything is rendered."""
GPU_RESOURCE = {"GPU": 1}
"""What a task rendering on a CUDA device asks of its worker: one of the two task slots
its GPU worker advertises (``--resources GPU=2``, `service.cluster.GPU_TASKS`)."""


class RunCancelledError(Exception):
    """A run stopped because its `cancel` event was set (`run_plan`)."""


class Cancel(threading.Event):
    """A run's cancel event that the run closes once its samples are written (`execute`).

    From then on the run writes its statistics and ends as it is: a cancel is refused
    rather than accepted and ignored.
    """

    def __init__(self):
        super().__init__()
        self._guard = threading.Lock()
        self._closed = False

    def cancel(self) -> bool:
        """Set the event unless the run has closed it; whether it is set."""
        with self._guard:
            if not self._closed:
                self.set()
            return not self._closed

    def close(self) -> bool:
        """Refuse further cancels, unless one came first; whether it is closed."""
        with self._guard:
            self._closed = not self.is_set()
            return self._closed


def run_plan(
    plan: Plan,
    store: Store,
    *,
    client: Client,
    resume: bool = False,
    task_timeout: float = TASK_TIMEOUT,
    progress_stream=None,
    cancel=None,
    on_progress=None,
    completed: np.ndarray | None = None,
    backend: Backend = NUMPY,
    batch_memory: float | None = None,
) -> RunResult:
    """Render every missing sample of `plan` into `store`.

    The store must exist (`service.store.template.create_store`); one task per shard. With
    `resume`, samples already marked complete are skipped. Shards whose task fails (after
    dask's retries, or because a worker died under it) have their samples run again one
    per task, one task in flight, so a sample that kills its worker is reported alone and
    the samples that merely shared its worker complete. A task without a result
    `task_timeout` seconds after its submission (a frozen worker) is given up and reported
    in ``stuck``; its shard is given to no other task. A storage failure that no retry
    cures (a full disk, a read-only or forbidden store) stops the run at once, with one
    message in ``stopped``.

    Setting `cancel` (a `threading.Event`) cancels the tasks in flight, waits for those
    already executing to end (at most `task_timeout`), and ends the run as interrupted,
    resumable. `on_progress(done, rate)` is called as samples complete
    (samples, samples/s). `progress_stream` shows the progress (`service.progress.Progress`:
    a line until the first shard is written, then the bar); None shows nothing.
    `completed`: with `resume`, the store's completion flags if already read. The
    samples render on `backend`; on a CUDA device each task asks for one unit of its
    worker's ``GPU`` resource (`GPU_RESOURCE`). A task renders its samples of a scene in
    batches of at most `batch_memory` bytes (None: a share of its device's memory,
    `service.batching.memory_budget`).
    """
    size = shard_samples(store.group())
    if resume:
        todo = np.flatnonzero(~(store.completed() if completed is None else completed))
    else:
        todo = range(plan.samples)  # lazy: the client holds no per-sample list
    result = RunResult(
        total=plan.samples, task_timeout=task_timeout, skipped=plan.samples - len(todo)
    )
    if resume:
        result.points = np.unique(todo // plan.realisations)
    progress = Progress(
        plan.samples,
        unit="samples",
        already=result.skipped,
        stream=progress_stream,
        callback=on_progress,
        first="rendering the first shard",
    )
    threads = sum(client.nthreads().values()) or 1
    # task keys name the store and the sweep: concurrent runs never share a task
    run_id = f"{_store_key(store)}-{plan.digest[:16]}"
    started = time.monotonic()
    window = max(2, IN_FLIGHT_PER_THREAD * threads)
    failed: list = []
    submit = functools.partial(
        _submit_bounded,
        client,
        store,
        task_timeout=task_timeout,
        result=result,
        progress=progress,
        failed=failed,
        cancel=cancel,
        backend=backend,
        memory=batch_memory,
    )

    def alone(samples):
        """One sample per task, never of a shard whose task was given up (still running?)."""
        for start, jobs in task_batches(plan, samples, 1):
            if any(first // size == start // size for first, _ in result.stuck):
                result.stuck.append((start, 1))
                continue
            yield start, jobs

    try:
        submit(task_batches(plan, todo, size), window, f"{run_id}-shard")
        singles = sorted(sample for samples, _ in failed for sample in samples)
        failed.clear()
        if result.stopped is None:
            submit(alone(singles), 1, f"{run_id}-alone")
    except KeyboardInterrupt:
        result.interrupted = True
    except RunCancelledError:
        result.interrupted = True
        # a task cannot be stopped mid-sample: let those executing end before the lock goes
        _wait_executing(client, f"oceanlidar-{run_id}", task_timeout)
    finally:
        progress.close()
        result.seconds = time.monotonic() - started
    result.failed = [(samples[0], len(samples), error) for samples, error in failed]
    return result


def unwritten(flags: np.ndarray) -> list[tuple[int, str]]:
    """The samples whose completion `flags` are not set (`Store.completed_after`).

    Checked after a run that reports every sample written, before its statistics: such a
    run leaves its store complete, and a fault of the runner that skipped a sample (a
    resume that left one out) is then a failure naming it, never statistics over an
    incomplete store.

    Returns
    -------
    list of tuple
        ``(sample, reason)``, by sample index.
    """
    return [
        (int(sample), "not marked complete after the run (no task reported it failed)")
        for sample in np.flatnonzero(~flags)
    ]


def _store_key(store: Store) -> str:
    """The part of the task keys that names `store`."""
    return hashlib.sha256(store.url.encode()).hexdigest()[:16]


def _wait_executing(client: Client, prefix: str, timeout: float) -> bool:
    """Wait at most `timeout` s for the tasks named ``prefix...`` to end; whether some run.

    A worker that leaves meanwhile runs none.
    """
    deadline = time.monotonic() + timeout
    while any(client.run(_executing, prefix, on_error="ignore").values()):
        if time.monotonic() > deadline:
            return True
        time.sleep(TICK / 5)
    return False


def _executing(prefix: str, dask_worker=None) -> int:
    """Tasks named ``prefix...`` executing on this worker, cancelled ones included."""
    return sum(str(task.key).startswith(prefix) for task in dask_worker.state.executing)


def _lasting_storage_error(error: BaseException | None) -> bool:
    """A failure to write that retrying cannot cure."""
    return isinstance(error, OSError) and error.errno in LASTING_ERRNOS


def _submit_bounded(
    client,
    store,
    batches,
    window,
    tag,
    *,
    task_timeout,
    result,
    progress,
    failed,
    cancel=None,
    backend=NUMPY,
    memory=None,
):
    """Submit `batches` keeping at most `window` tasks in flight; record what happened."""
    running: dict = {}  # future -> (samples, submitted at)

    def submit_next() -> bool:
        try:
            start, jobs = next(batches)
        except StopIteration:
            return False
        future = client.submit(
            render_shard,
            store,
            jobs,
            backend,
            memory,
            key=f"oceanlidar-{tag}-{start}-{len(jobs)}",
            retries=RETRIES,
            pure=False,
            resources=_resources(backend),
        )
        running[future] = ([job[0] for job in jobs], time.monotonic())
        result.max_in_flight = max(result.max_in_flight, len(running))
        return True

    def fill(limit: int) -> None:
        while result.stopped is None and len(running) < limit and submit_next():
            pass

    checked = time.monotonic()
    try:
        fill(window)
        while running:
            try:
                with client.as_current():  # `wait` asks for the current client
                    done = wait(list(running), timeout=TICK, return_when="FIRST_COMPLETED").done
            except TimeoutError:
                done = set()
            if cancel is not None and cancel.is_set():
                raise RunCancelledError
            for future in done:
                samples, _ = running.pop(future)
                if future.status == "finished":
                    unwritten = future.result()
                    result.written += len(samples) - len(unwritten)
                    for sample, reason, refused in unwritten:
                        (result.refused if refused else result.rejected).append((sample, reason))
                    progress.update(len(samples))
                elif _lasting_storage_error(error := future.exception()):
                    result.stopped = f"{store.url}: {error.strerror} (errno {error.errno})"
                else:
                    failed.append((samples, repr(error)))
                future.release()
            now = time.monotonic()
            for future, (samples, submitted) in list(running.items()):
                if result.stopped is not None or now - submitted > task_timeout:
                    running.pop(future)
                    future.cancel()
                    if result.stopped is None:
                        result.stuck.append((samples[0], samples[-1] - samples[0] + 1))
            if window > 1 and now - checked > WINDOW_REFRESH:
                # workers join and leave: keep a few tasks per thread present now
                checked = now
                window = max(2, IN_FLIGHT_PER_THREAD * sum(client.nthreads().values()))
            fill(window)
    except (KeyboardInterrupt, RunCancelledError):
        for future in running:
            future.cancel()
        raise


def _resources(backend: Backend) -> dict | None:
    """The worker resources a task rendering on `backend` holds while it runs."""
    return GPU_RESOURCE if backend.device != "cpu" else None


def _see_and_check(store: Store, token: str, backend: Backend) -> None:
    """On a worker: it sees `store` and its lock `token`, and it renders on `backend`."""
    store.check_workers_see(token)
    check_on_worker(backend)


def _probe(client: Client, store: Store, token: str, backend: Backend = NUMPY) -> None:
    """Wait for a worker to confirm that it sees `store` and its writer lock `token`.

    The worker (one with a GPU for a CUDA `backend`) checks that it can render on
    `backend` too (`service.devices.check_on_worker`).

    Raises
    ------
    BadOptionError
        If it cannot (torch missing there, no CUDA device), naming the flag.
    ClusterError
        If no worker answers within `PROBE_TIMEOUT`.
    """
    probe = client.submit(
        _see_and_check, store, token, backend, pure=False, resources=_resources(backend)
    )
    try:
        probe.result(timeout=PROBE_TIMEOUT)
    except TimeoutError:
        gpu = " with a GPU resource" if _resources(backend) else ""
        raise ClusterError(
            f"no worker{gpu} answered within {PROBE_TIMEOUT} s (are any connected?)"
        ) from None
    except ValueError as error:  # workers.backends.backend.get_backend's, on the worker
        raise BadOptionError(f"--{error} (on the cluster's worker)") from None


def execute(
    plan: Plan,
    store: Store,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    security=None,
    dashboard: bool = False,
    verbose: bool = False,
    resume: bool = False,
    verify: bool = False,
    overwrite: bool = False,
    batch_size: int | None = None,
    task_timeout: float = TASK_TIMEOUT,
    progress_stream=None,
    client: Client | None = None,
    cancel=None,
    on_progress=None,
    claim: str | None = None,
    owner: str | None = None,
    backend: Backend = NUMPY,
    batch_memory: float | None = None,
) -> RunResult:
    """Create (or reopen) the store, run the missing samples and write the statistics.

    `store` is normalised (`service.store.location.Store.at`). `batch_size` is the samples
    per shard (and task) of a new store (by default `service.store.layout.shard_size`'s
    choice); a resumed store keeps its own. With `resume` and `verify`, every completed
    sample is read back first (`service.store.integrity.verify`) and the
    damaged ones are rendered again with the missing ones. A run that reports nothing
    failed must leave every sample marked complete: those it did not are reported in
    ``unwritten`` (`unwritten`) and no statistics are written. After a resumed run, only
    the statistics of the points it wrote are recomputed (`service.stats.write_statistics`).
    `dashboard` and `verbose` go to `service.cluster.dask_client`.

    Everything is checked before anything is deleted or written, once before taking the
    store's writer lock (so a refused run leaves no trace) and again holding it (another
    run may have changed the output meanwhile). Then tasks of an earlier run into the
    same store still executing (a service killed mid-job, on a cluster that outlived it)
    are waited for, at most `task_timeout` (`ClusterError` if they last longer).

    `client` runs the samples on a cluster already connected (`workers`, `scheduler` and
    `security` are then unused); `cancel` (a `Cancel`) and `on_progress` are passed to
    `run_plan`, and `cancel` is closed before the statistics (a cancel that came first ends
    the run interrupted, its samples written, its statistics not);
    `claim` to `service.store.lock.writer_lock`; `owner` (the job service's submitter) is
    recorded in a new store (`service.store.template.create_store`). The samples render
    on `backend` (`service.devices.choose`), which a new store records and a resumed one
    must have recorded (`service.devices.check_same`); a CUDA backend without `client` or
    `scheduler` starts dask-cuda's local cluster, one worker a GPU. `batch_memory`
    (``--batch-memory``, bytes) goes to `run_plan`.
    """
    options = {"resume": resume, "overwrite": overwrite, "backend": backend}
    # a GPU worker sees its own GPU alone, as ``cuda`` (``cuda:N`` picks the embedded one)
    rendering = dataclasses.replace(backend, device=backend.device.partition(":")[0])
    with store.errors():
        check_output(plan, store, **options)
    with store.lock(claim=claim) as token:
        with store.errors():
            resuming, old_files, old_stats = check_output(plan, store, **options)
        # connect before touching storage: an unreachable cluster leaves everything as it was
        connect = functools.partial(
            dask_client,
            workers=workers,
            scheduler=scheduler,
            security=security,
            dashboard=dashboard,
            verbose=verbose,
            device=backend.device,
        )
        said = functools.partial(phase, stream=progress_stream)
        with contextlib.ExitStack() as connected:
            if client is None:
                with said(connecting(workers=workers, scheduler=scheduler, device=backend.device)):
                    client = connected.enter_context(connect())
            with said("waiting for the workers to start and see the store"):
                _probe(client, store, token, rendering)
                # an earlier run into this store (a service killed mid-job, on a cluster
                # that outlived it) may have tasks still executing: none may write past here
                if _wait_executing(client, f"oceanlidar-{_store_key(store)}", task_timeout):
                    raise ClusterError(
                        f"tasks of an earlier run into {store.url} are still executing on "
                        f"the cluster after {task_timeout:.0f} s; try again once they end"
                    )
            with store.errors():
                if old_files or old_stats:
                    with said("deleting the store it replaces"):
                        store.stats.remove(old_stats)
                        store.remove(old_files)
                if not resuming:
                    with said("writing the store template"):
                        create_store(
                            plan, store, samples_per_shard=batch_size, owner=owner, backend=backend
                        )
            checked = resuming and verify
            relabelled, damaged = [], []
            if checked:
                with said("reading the stored samples back against their checksums"):
                    relabelled = integrity.repair_labels(store, plan)
                    damaged = integrity.rebuild_records(store)
                    damaged += integrity.verify(store)
            store.mark_incomplete([sample for sample, _ in damaged])
            with store.errors():
                before = store.completed() if resuming else None
            result = run_plan(
                plan,
                store,
                client=client,
                resume=resuming,
                task_timeout=task_timeout,
                progress_stream=progress_stream,
                cancel=cancel,
                on_progress=on_progress,
                completed=before,
                backend=rendering,
                batch_memory=batch_memory,
            )
            result.damaged, result.relabelled = damaged, relabelled
            if result.ok:
                with store.errors():
                    done = store.completed() if before is None else store.completed_after(before)
                result.unwritten = unwritten(done)
            if result.ok and (cancel is None or cancel.close()):
                with said("writing the statistics"):
                    write_statistics(store, points=result.points, completed=done)
            elif result.ok:
                result.interrupted = True
        if result.interrupted:  # tasks in flight at the interrupt may have written since
            with store.errors():
                done = store.completed()
            result.written = max(result.written, int(done.sum()) - result.skipped)
    return result
