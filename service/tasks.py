"""A run's task: one shard's samples rendered in batches, checked and written whole.

`task_batches` groups the samples a run renders by the shard that holds them; `render_shard`
(on a dask worker) renders each scene's samples of its shard on the run's backend
(`render_samples`) in batches sized to the memory its device gives a task
(`service.batching.batch_samples`), checks every sample's values and writes the shard
(`service.store.shards.write_shard`). On a GPU worker two such tasks run at once
(`service.cluster.GPU_TASKS`): while one renders on the GPU, the other checks, encodes and
writes the shard it rendered on the host's cores. The bytes stay the same: a sample's
values depend on its scene and seed only, never on the samples that share its batch nor
on the work beside it on the device, and each shard is written by its one task.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator

import numpy as np

from service.batching import batch_samples, memory_budget
from service.cluster import hold
from service.devices import NUMPY
from service.store import integrity, shards
from service.store.location import Store
from service.sweep import Plan
from service.tuning import tune_allocator
from workers.backends.backend import Backend
from workers.render import render_batch
from workers.settings.scene import Scene
from workers.settings.section import SceneError

__all__ = ["render_samples", "render_shard", "task_batches"]


def render_samples(scene: Scene, seeds: list, *, backend: Backend) -> dict[str, np.ndarray]:
    """The rendered arrays of `scene` for each of `seeds`, stacked on a leading axis.

    Parameters
    ----------
    scene : Scene
        One scene, shared by the samples.
    seeds : list of SampleSeed
        The samples' seeds, in order.
    backend : Backend
        Where they render.

    Returns
    -------
    dict of str to numpy.ndarray
        `workers.render.render_arrays`'s values per seed, stacked (host numpy).

    Raises
    ------
    SceneError
        If the scene cannot be rendered (on this backend).
    """
    return render_batch(scene, seeds, backend=backend.name, device=backend.device)


def render_shard(store: Store, jobs, backend: Backend = NUMPY, memory: float | None = None):
    """Render samples of one shard and write the whole shard (runs on a dask worker).

    Parameters
    ----------
    store : Store
        The store.
    jobs : list of tuple
        ``(sample, scene, seed)`` per sample, all in one shard: its index, its
        `workers.settings.scene.Scene` (hashable, sent as it is) and
        `workers.settings.seeds.SampleSeed`.
        Consecutive samples of one scene render in batches of at most
        `service.batching.batch_samples` (the same bytes whatever the batches).
    backend : Backend, optional
        Where they render (`service.devices.choose`).
    memory : float or None, optional
        Bytes a batch may take (``--batch-memory``); None: `service.batching.memory_budget`'s
        share of what this worker's device gives a task.

    Returns
    -------
    list of tuple
        ``(sample, reason, refused)`` for every sample not written: ``refused`` True for a
        scene that cannot be rendered (`workers.settings.section.SceneError`), False for values
        rejected by `service.store.integrity.invalid_values`. Those are neither written nor
        marked complete; the valid samples around them are.
    """
    tune_allocator()
    group = store.group("r+")
    budget = memory_budget(backend, memory)
    rejected, valid = [], {}
    for scene, same in itertools.groupby(jobs, key=lambda job: job[1]):
        run, size = list(same), batch_samples(scene, budget)
        for start in range(0, len(run), size):
            rejected += _render_checked(scene, run[start : start + size], backend, valid)
    if valid:
        shards.write_shard(group, valid)
    hold(jobs[0][0])  # tests only
    return rejected


def _render_checked(scene: Scene, run: list, backend: Backend, valid: dict) -> list:
    """Render the jobs `run` of `scene` in one batch; add the valid samples to `valid`.

    Returns
    -------
    list of tuple
        The samples not valid, as `render_shard` returns them.
    """
    try:
        batch = render_samples(scene, [seed for _, _, seed in run], backend=backend)
    except SceneError as error:
        return [(sample, str(error), True) for sample, _, _ in run]
    rejected = []
    for index, (sample, _, _) in enumerate(run):
        rendered = {name: values[index] for name, values in batch.items()}
        reason = integrity.invalid_values(rendered, scene)
        if reason is None:
            valid[sample] = rendered
        else:
            rejected.append((sample, reason, False))
    return rejected


def task_batches(plan: Plan, todo, samples_per_shard: int) -> Iterator[tuple[int, list]]:
    """The samples of `todo` (ascending) grouped by the shard that holds them.

    Yields
    ------
    tuple
        ``(first sample, jobs)`` as `render_shard` takes the jobs.
    """
    run: list = []
    for sample in todo:
        sample = int(sample)
        if run and sample // samples_per_shard != run[0][0] // samples_per_shard:
            yield run[0][0], run
            run = []
        address = plan.sample(sample)
        run.append((sample, address.scene, address.seed))
    if run:
        yield run[0][0], run
