"""Training without disk: a sweep's samples rendered on the fly, as a PyTorch stream.

`SweepStream` is an ``IterableDataset`` that renders the samples of a sweep as they are
asked for (`workers.render.render_arrays`), with the seeds and labels its store would hold
(`workers.settings.seeds.SampleSeed` keyed by the sweep's seed, the point and the realisation; the
values in the store's types, `service.store.template.store_variables`), so that a training
loop reads exactly what ``oceanlidar run`` would write, or draws fresh realisations forever:
realisations beyond the sweep's count continue the same seed scheme. README, "Training
without disk".
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
from torch.utils.data import IterableDataset, get_worker_info

from service.dataset import image_type
from service.devices import check_renderers, named
from service.inputs import position
from service.store.template import store_variables
from service.sweep import Plan, load_sweep
from workers.backends.backend import get_backend
from workers.render import render_arrays
from workers.settings.seeds import SampleSeed

__all__ = ["SweepStream"]

PRESENCE = "target_present"
"""The one label a sample's scene fixes that a stream item holds (the rest are rendered)."""

ORDER_STREAM = 4
"""First spawn key of the points' order (`SweepStream.order`), apart from the samples'
streams (`workers.settings.seeds`) and the sweep's draws (`service.sweep`: 2, 3)."""


class SweepStream(IterableDataset):
    """A sweep's samples rendered as they are read: an ``IterableDataset`` for training.

    Items come realisation by realisation (realisation ``first``'s points, then
    ``first + 1``'s, ...), each realisation's points in a seeded shuffled order (`order`;
    point order with ``shuffle=False``). Given to a ``torch.utils.data.DataLoader`` with
    worker processes, worker k of n renders the items k, k + n, k + 2n, ... of that
    sequence: each item once, whatever the workers, and a worker's batches mix the points
    (in point order, 2 workers of a grid whose last parameter alternates, ``target.shape``,
    would each render one of its values only). A ``DataLoader`` without ``batch_size``
    gives the sequence itself, whatever its workers.

    Parameters
    ----------
    sweep : Plan or path-like
        The sweep (`service.sweep.load_sweep` reads a file).
    points : sequence of int, optional
        The parameter points drawn (default: all).
    realisations : int or None, optional
        Realisations drawn per point; None: without end (a loop stops when it will).
    first : int, optional
        The first realisation drawn. From the sweep's ``realisations`` on, the samples are
        none that its store holds: fresh seas and noise, keyed alike.
    arrays, labels : sequence of str, optional
        What an item holds besides ``point``, ``realisation`` and ``sample``: rendered
        arrays (``image``, ``expected``, ``target_mask``, ``target_visibility``,
        ``target_signal``, ...) and ``target_present``, as `service.dataset.SampleDataset`
        names them (the two lists are one pool here: nothing is read from disk).
    image_dtype : numpy dtype, optional
        The type ``image`` is returned in; default the store's (the sweep's widest). One
        that cannot hold the sweep's counts is refused (`service.dataset.image_type`).

    Raises
    ------
    TypeError
        For points, realisations or first that are not integers (``0.7``, ``2.5``, ``True``).
    ValueError
        For points outside the sweep, fewer than one realisation, a negative first, an
        image type that would wrap the counts, a backend or device that cannot render here
        (naming ``backend`` or ``device``: `workers.backends.backend.get_backend`), or a
        Monte Carlo point on torch.
    backend, device : str, optional
        The array backend and device to render on (`workers.render.render_arrays`), as
        ``--backend`` and ``--device`` name them (`service.devices.named`: default numpy on
        the CPU, torch on a CUDA device), checked as the stream is made. A store's bytes
        are those of the backend that wrote it: its ``render_backend``, ``render_device``.
    shuffle : bool, optional
        Shuffle each realisation's points (`order`; default), or keep point order.

    Notes
    -----
    An item is a dict of numpy arrays: ``point``, ``realisation``, ``sample`` (its index in
    the sweep's store, -1 beyond the sweep's realisations) and the names asked for, each in
    the store's type (the image in `image_dtype`), byte for byte the store's sample.
    """

    def __init__(
        self,
        sweep,
        *,
        points=None,
        realisations: int | None = None,
        first: int = 0,
        arrays=("image", "target_mask"),
        labels=(PRESENCE, "target_visibility"),
        image_dtype=None,
        backend: str | None = None,
        device: str | None = None,
        shuffle: bool = True,
    ) -> None:
        super().__init__()
        self.plan = sweep if isinstance(sweep, Plan) else load_sweep(Path(sweep))
        count = len(self.plan.points)
        self.points = (
            tuple(range(count))
            if points is None
            else tuple(position(p, "points' entries") for p in points)
        )
        if not self.points or not all(0 <= p < count for p in self.points):
            raise ValueError(f"points {points!r}: the sweep has points 0..{count - 1}")
        if realisations is not None:
            realisations = position(realisations, "realisations")
            if realisations < 1:
                raise ValueError(f"realisations must be at least 1 (or None), got {realisations}")
        if (first := position(first, "first")) < 0:
            raise ValueError(f"first must be a realisation (>= 0), got {first}")
        self.realisations, self.first = realisations, first
        table = store_variables(self.plan)
        self.names = (*arrays, *labels)
        unknown = [n for n in self.names if n != PRESENCE and table.get(n) is None]
        if unknown:
            raise KeyError(f"a sweep's samples hold no {', '.join(unknown)}")
        self.dtypes = {name: table[name].dtype for name in self.names}
        if image_dtype is not None:
            image = table["image"]
            largest = image.attrs.get("valid_max")
            self.dtypes["image"] = image_type(image_dtype, stored=image.dtype, largest=largest)
        chosen = get_backend(*named(backend, device))
        check_renderers(self.plan, chosen, points=self.points)
        self.options = {"backend": chosen.name, "device": chosen.device}
        self.shuffle, self.epoch = bool(shuffle), 0

    def __len__(self) -> int:
        if self.realisations is None:
            raise TypeError("an endless SweepStream (realisations=None) has no length")
        return len(self.points) * self.realisations

    def set_epoch(self, epoch: int) -> None:
        """Shuffle the points anew for `epoch` (>= 0), as a sampler's ``set_epoch`` does.

        Call it before each epoch's loop: the ``DataLoader``'s workers take the stream as
        it is when the loop starts.
        """
        if not isinstance(epoch, int | np.integer) or isinstance(epoch, bool) or epoch < 0:
            raise ValueError(f"epoch must be an integer >= 0, got {epoch!r}")
        self.epoch = int(epoch)

    def order(self, realisation: int) -> tuple[int, ...]:
        """The points of `realisation` in the order the stream gives them.

        A permutation of `points` drawn from the sweep's seed, the epoch (`set_epoch`) and
        the realisation (``SeedSequence(seed, spawn_key=(ORDER_STREAM, epoch,
        realisation))``): the same whatever the workers, ``first`` or the items read
        before. `points` in their order with ``shuffle=False``.
        """
        if not self.shuffle:
            return self.points
        key = (ORDER_STREAM, self.epoch, int(realisation))
        rng = np.random.default_rng(np.random.SeedSequence(self.plan.sweep.seed, spawn_key=key))
        return tuple(self.points[i] for i in rng.permutation(len(self.points)))

    def __iter__(self):
        worker = get_worker_info()
        start, step = (0, 1) if worker is None else (worker.id, worker.num_workers)
        end = None if self.realisations is None else len(self)
        realisation, order = None, ()
        for item in itertools.islice(itertools.count(), start, end, step):
            offset, position = divmod(item, len(self.points))
            if self.first + offset != realisation:
                realisation = self.first + offset
                order = self.order(realisation)
            yield self.item(point=order[position], realisation=realisation)

    def item(self, *, point: int, realisation: int) -> dict[str, np.ndarray]:
        """The sample of `point` and `realisation`, rendered (any realisation, >= 0)."""
        scene = self.plan.scenes[point]
        seed = SampleSeed(root=self.plan.sweep.seed, point=point, realisation=realisation)
        rendered = render_arrays(scene, seed=seed, **self.options)
        rendered[PRESENCE] = np.asarray(scene.target.shape != "none")
        stored = realisation < self.plan.realisations
        return {
            "point": np.int64(point),
            "realisation": np.int64(realisation),
            "sample": np.int64(point * self.plan.realisations + realisation if stored else -1),
            **{name: rendered[name].astype(self.dtypes[name]) for name in self.names},
        }
