"""The dask client a run uses: an existing scheduler, or an embedded LocalCluster on loopback."""

from __future__ import annotations

import contextlib
import functools
import importlib.util
import logging
import os
import signal
import threading
import time
from pathlib import Path

import dask
from distributed import Client, LocalCluster, get_worker
from distributed.core import Status
from distributed.diagnostics.plugin import WorkerPlugin
from distributed.worker import thread_state

from service.errors import BadOptionError

__all__ = [
    "GPU_TASKS",
    "ClusterError",
    "connecting",
    "dask_client",
    "dask_setup",
    "embedded_cluster",
    "embedded_cuda_cluster",
    "hold",
]

CLOSE_TIMEOUT = 60.0
"""Longest wait for the embedded cluster's workers to exit, s."""

QUIET = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.admin.tick.interval": "1s",
}
"""dask settings of the embedded cluster without a dashboard: no statistical profiler in the
workers (it samples their stacks every 10 ms for the dashboard's profile page), the
resource monitor every 5 s (0.5 s) and the event loops' responsiveness tick every 1 s
(20 ms; a loop blocked beyond ``distributed.admin.tick.limit``, 3 s, is still reported).
Idle, a worker then burns 6 ms of CPU a second instead of 24, the scheduler and client
8 instead of 27 (``benchmarks/sweep.py``)."""

OWN_WORKERS = {"distributed.worker.preload": ["service.cluster"]}
"""dask settings of the embedded cluster's workers: each runs `dask_setup` as it starts."""

GPU_TASKS = 2
"""Shard tasks a GPU worker runs at once (its threads, and the ``GPU`` resource it
advertises: each task holds one, `service.run.GPU_RESOURCE`): while one renders its shard on
the GPU, the other checks, encodes and writes the shard it rendered on the host's cores,
so that the GPU is not idle while a shard is written (`service.tasks`)."""
CUDA_CLUSTER_HINT = (
    "pip install 'oceanlidar[gpu]' for dask-cuda, or give --scheduler a cluster of GPU workers"
)
"""What to do when ``--device cuda`` finds no dask-cuda for its local cluster."""

HOLD = "OCEANLIDAR_TEST_HOLD"
"""Tests only, the environment variable of `hold`: a folder (the interrupt tests)."""
HOLD_LIMIT = 120.0
"""Longest hold of a task by `hold`, s."""

log = logging.getLogger("oceanlidar")


def dask_setup(worker) -> None:
    """Start an embedded cluster's worker process (a dask preload, `OWN_WORKERS`).

    A Ctrl-C at the terminal reaches every process of the run, and so does a SIGTERM sent
    to its process group (a batch system's time limit, ``kill -- -PGID``, a container's
    whole cgroup): the run's own process (or ``serve``'s) stops the sweep and closes the
    cluster, so the workers ignore both. On a Ctrl-C each would print a traceback of its
    event loop's KeyboardInterrupt; on a SIGTERM each would die on the spot, its
    multiprocessing semaphores never released (the resource tracker's "leaked semaphore"
    warning at exit) and its connections cut mid-message (a traceback from the
    scheduler). A worker still exits when its nanny's process does, however it ends
    (``distributed``'s parent watch). A worker that is a thread of another process (not
    its main thread) leaves that process's handling alone.

    Such a worker process also closes without waiting for the tasks it is executing
    (`close_without_waiting`): when the run is interrupted, a sample mid-render is abandoned
    (not marked complete: ``--resume`` renders it again), and the worker exits within the
    few seconds its nanny gives it. Otherwise it waited for the task, and the nanny killed
    it once those seconds were up: killed, it left numcodecs' blosc lock (a named
    semaphore each worker creates as it first compresses) registered, and the resource
    tracker warned of a "leaked semaphore" as the run ended.
    """
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        worker.close = close_without_waiting(worker.close)


def close_without_waiting(close):
    """`close`, a worker's ``close`` method, that never waits for its executing tasks.

    Its nanny asks a worker process to close waiting for its executor's threads
    (``executor_wait=True``, which no setting changes) and kills it a few seconds later
    (`dask_setup`). The tasks themselves are cancelled by the run's client first; a task
    that is still executing is in compiled code no cancel stops, and its process exits
    without it.
    """

    @functools.wraps(close)
    async def closing(*args, **kwargs):
        return await close(*args, **{**kwargs, "executor_wait": False})

    return closing


def hold(start: int) -> None:
    """Tests only: hold a run at a known point, for an interrupt there (not a clock race).

    With `HOLD` set to a folder, a task that has written its shard (`start`, its first
    sample) says so by a file ``shard-START`` there; then, once as many shards as the
    folder's file ``hold`` says are written, it waits until the run lets it go (its client
    gone, interrupted: the task is cancelled, or its worker closes), at most `HOLD_LIMIT`.
    With a file ``busy`` there too, it waits `HOLD_LIMIT` whatever happens, as a sample
    mid-render in compiled code does (no cancel stops it).
    """
    folder = os.environ.get(HOLD)
    if not folder:
        return
    folder = Path(folder)
    (folder / f"shard-{start}").touch()
    if len(list(folder.glob("shard-*"))) < int((folder / "hold").read_text()):
        return
    worker = get_worker()
    task = worker.state.tasks[thread_state.key]
    deadline = time.monotonic() + HOLD_LIMIT
    busy = (folder / "busy").exists()
    # a worker closing with its cluster (the run interrupted) may not cancel it first
    while (
        busy or (task.state == "executing" and worker.status == Status.running)
    ) and time.monotonic() < deadline:
        time.sleep(0.05)


class ClusterError(RuntimeError):
    """The dask cluster cannot be reached or used."""


class WarningsToLogging(WorkerPlugin):
    """Route a worker's Python warnings to its logging, kept off the console unless verbose.

    The embedded cluster's workers write to the console the run was started from; a
    warning a worker raises would print there raw, once per process.
    """

    name = "oceanlidar-warnings"

    def __init__(self, verbose: bool):
        self.verbose = verbose

    def setup(self, worker):
        """Capture the worker's warnings (logged at WARNING, printed only if verbose)."""
        logging.captureWarnings(True)
        captured = logging.getLogger("py.warnings")
        captured.handlers = [logging.StreamHandler()] if self.verbose else [logging.NullHandler()]
        captured.setLevel(logging.WARNING if self.verbose else logging.ERROR)


def embedded_cluster(
    *, workers: int | None, dashboard: bool = False, verbose: bool = False
) -> LocalCluster:
    """The embedded LocalCluster of `dask_client`: `workers` processes of one thread each.

    Started on 127.0.0.1 with `QUIET` unless `dashboard`, every worker running `dask_setup`
    (`OWN_WORKERS`); `verbose` lets the workers' logs through.
    """
    quiet = {} if dashboard else QUIET
    with dask.config.set({**quiet, **OWN_WORKERS}):
        return LocalCluster(
            n_workers=workers or os.cpu_count() or 1,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address="127.0.0.1:0",
            scheduler_kwargs={"dashboard": dashboard},
            silence_logs=logging.WARNING if verbose else logging.CRITICAL,
            config={**quiet, **OWN_WORKERS},
        )


def embedded_cuda_cluster(
    *, workers: int | None, device: str, dashboard: bool = False, verbose: bool = False
):
    """dask-cuda's LocalCUDACluster on 127.0.0.1: one worker process a GPU.

    Each worker sees its own GPU alone (as ``cuda``, its ``CUDA_VISIBLE_DEVICES``), runs
    `GPU_TASKS` threads and advertises as many units of the ``GPU`` resource; dask-cuda is
    imported only here. Otherwise as `embedded_cluster`.

    Parameters
    ----------
    workers : int or None
        GPUs used (None: every GPU of the machine, or the one `device` names).
    device : str
        ``cuda``, or ``cuda:N`` for GPU N alone.

    Raises
    ------
    BadOptionError
        If dask-cuda is not installed, naming ``--device`` and the remedy.
    """
    if importlib.util.find_spec("dask_cuda") is None:
        raise BadOptionError(
            f"--device {device}: the local CUDA cluster needs dask-cuda, which is not "
            f"installed ({CUDA_CLUSTER_HINT})"
        )
    from dask_cuda import LocalCUDACluster

    quiet = {} if dashboard else QUIET
    with dask.config.set({**quiet, **OWN_WORKERS}):  # LocalCUDACluster sets `config` itself
        return LocalCUDACluster(
            CUDA_VISIBLE_DEVICES=device.partition(":")[2] or None,
            n_workers=workers,
            threads_per_worker=GPU_TASKS,
            resources={"GPU": GPU_TASKS},
            host="127.0.0.1",
            dashboard_address="127.0.0.1:0",
            scheduler_kwargs={"dashboard": dashboard},
            silence_logs=logging.WARNING if verbose else logging.CRITICAL,
        )


def connecting(*, workers: int | None, scheduler: str | None, device: str) -> str:
    """What `dask_client` does to get a run its cluster, in words (a set-up phase's line)."""
    if scheduler is not None:
        return f"connecting to the scheduler at {scheduler}"
    if device != "cpu":
        return "starting the local CUDA cluster (one worker a GPU)"
    count = workers or os.cpu_count() or 1
    return f"starting the local cluster ({count} worker{'s' if count > 1 else ''})"


@contextlib.contextmanager
def dask_client(
    *,
    workers: int | None,
    scheduler: str | None,
    security=None,
    dashboard: bool = False,
    verbose: bool = False,
    device: str = "cpu",
):
    """A client for an existing scheduler, or for an embedded LocalCluster on 127.0.0.1.

    A CUDA `device` (``cuda``, ``cuda:N``) embeds dask-cuda's cluster instead, one worker a
    GPU (`embedded_cuda_cluster`).

    `security` (a `distributed.Security`) defaults to dask's configuration, where TLS
    files and ``require-encryption`` can be set (``DASK_DISTRIBUTED__COMM__...``). With
    `dashboard`, the embedded scheduler serves dask's dashboard on a free loopback port
    (bokeh needed) and its link is logged; either way its HTTP server takes a free port,
    never a busy default. Without `dashboard`, the embedded cluster runs with `QUIET`: the
    scheduler reads it when it starts, the nannies keep it for every worker process they
    start, restarts included (a nanny's copy of the ambient configuration shares its
    nested dicts, which leaving ``dask.config.set`` restores). `verbose` lets the embedded
    workers' logs and warnings through.
    """
    if dashboard and importlib.util.find_spec("bokeh") is None:
        raise BadOptionError("--dashboard needs bokeh: pip install 'oceanlidar[dashboard]'")
    if scheduler is not None:
        try:
            client = Client(scheduler, security=security, timeout="30s")
        except (OSError, TimeoutError, ValueError) as error:
            raise ClusterError(
                f"cannot connect to the scheduler at {scheduler}: {error}"
            ) from None
        with client:
            if dashboard:
                log.info("dashboard: %s", client.dashboard_link)
            yield client
        return
    if device == "cpu":
        cluster = embedded_cluster(workers=workers, dashboard=dashboard, verbose=verbose)
    else:
        cluster = embedded_cuda_cluster(
            workers=workers, device=device, dashboard=dashboard, verbose=verbose
        )
    try:
        with Client(cluster) as client:
            client.register_plugin(WarningsToLogging(verbose))
            if dashboard:
                log.info("dashboard: %s", client.dashboard_link)
            yield client
    finally:
        # A worker slow to exit (a loaded machine) must not turn a finished run into a
        # traceback: what it wrote is complete, and its process is killed at exit anyway.
        try:
            cluster.close(timeout=CLOSE_TIMEOUT)
        except TimeoutError:
            log.warning("the embedded dask cluster did not shut down within %g s", CLOSE_TIMEOUT)
