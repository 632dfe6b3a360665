"""How many samples of one scene a task renders at once: batches sized to the device's memory.

A shard's samples of one scene render in batches (`service.tasks.render_shard`) of
`batch_samples` samples: as many as fit a memory budget (`memory_budget`) at a sample's
estimated peak (`sample_memory`), at least one. The estimate is
`service.sweep.memory_estimate`, read from the scene's values without rendering: an upper
bound on a first sample's peak allocations (traced by ``tracemalloc``, every cache empty:
the scene's setup counted in), which ``tests/test_sweep.py`` holds within 8 times the
traced peak. A batch of N is counted N times that, the setup in every sample: an upper
bound whether the batch renders its samples in turn (each sample's arrays freed before the
next) or side by side on a leading sample axis. The budget is ``--batch-memory`` if given,
else `BUDGET_SHARE` of the memory a task has (`task_memory`): a GPU's memory shared by the
`service.cluster.GPU_TASKS` tasks its worker runs at once, a dask worker's memory limit
shared by its threads, or this machine's memory shared by the workers as dask's embedded
cluster shares it (`distributed.system.MEMORY_LIMIT`: the machine's, or its cgroup's).

A sample's bytes never depend on its batch (`workers.render.render_batch`), so the batch
size changes no store: it only bounds memory and sets how much of the work a GPU sees at
once.
"""

from __future__ import annotations

import importlib
import math
import os

from distributed import get_worker
from distributed.system import MEMORY_LIMIT

from service.cluster import GPU_TASKS
from service.errors import BadOptionError
from service.sweep import memory_estimate
from workers.backends.backend import Backend
from workers.settings.scene import Scene

__all__ = [
    "BUDGET_SHARE",
    "batch_samples",
    "given_memory",
    "memory_budget",
    "sample_memory",
    "task_memory",
]

BUDGET_SHARE = 0.5
"""Share of a task's memory (`task_memory`) its batches may take by default: the rest holds
the shard's rendered samples until they are written, zarr's encoding of them, and the
worker's own."""


def sample_memory(scene: Scene) -> int:
    """Estimated peak memory [bytes] of rendering one sample of `scene`, at least 1.

    `service.sweep.memory_estimate` of the scene's values (an upper bound, the scene's
    setup included).
    """
    return max(1, memory_estimate(scene.model_dump(mode="json")))


def task_memory(backend: Backend, *, workers: int | None = None) -> tuple[float, str]:
    """Memory [bytes] one task has where it renders on `backend`, and what it is, in words.

    Parameters
    ----------
    backend : Backend
        Where the task renders: a CUDA device's memory is shared by the `GPU_TASKS` tasks
        its worker runs at once; on the CPU, a dask worker's memory limit by its threads
        (read on the worker), elsewhere this machine's memory (dask's
        `distributed.system.MEMORY_LIMIT`, what the embedded cluster shares) by `workers`.
    workers : int or None, optional
        Worker processes sharing this machine off a dask worker (None: one per core).

    Returns
    -------
    tuple of (float, str)
        The bytes, and where they come from (``validate`` prints it).
    """
    if backend.device != "cpu":
        torch = importlib.import_module("torch")
        total = torch.cuda.get_device_properties(torch.device(backend.device)).total_memory
        return total / GPU_TASKS, f"{backend.device}'s memory shared by {GPU_TASKS} tasks"
    try:
        worker = get_worker()
    except ValueError:  # not on a dask worker
        worker = None
    limit = None if worker is None else worker.memory_manager.memory_limit
    if limit:
        threads = worker.state.nthreads
        return limit / threads, f"the dask worker's memory limit shared by {threads} thread(s)"
    workers = workers or os.cpu_count() or 1
    return MEMORY_LIMIT / workers, f"this machine's memory shared by {workers} worker(s)"


def given_memory(gib: float | None) -> float | None:
    """The bytes ``--batch-memory`` gives in GiB (``run``, ``validate``, ``serve``).

    None if not given.

    Raises
    ------
    BadOptionError
        If it is not a positive, finite number (NaN and infinity among them).
    """
    if gib is None:
        return None
    if not 0 < gib < math.inf:
        raise BadOptionError("--batch-memory must be a positive, finite number of GiB")
    return gib * 2**30


def memory_budget(backend: Backend, memory: float | None = None, **where) -> float:
    """Memory [bytes] a batch may take.

    `memory` if given (``--batch-memory``), else `BUDGET_SHARE` of `task_memory` (`where`
    its keywords).
    """
    if memory is not None:
        return memory
    return BUDGET_SHARE * task_memory(backend, **where)[0]


def batch_samples(scene: Scene, budget: float) -> int:
    """Samples of `scene` a batch holds within `budget` bytes (`sample_memory` each).

    At least one: a sample over the budget renders alone (``--max-memory`` bounds a sample).
    """
    return max(1, int(budget // sample_memory(scene)))
