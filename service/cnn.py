"""The trained image detector of `detect --cnn`: one network per sweep, told each pair's point.

`point_conditions` describes each pair (`service.detect_checks.pair_points`) by its
positive point's swept values outside ``target.shape`` (the numbers the network is
conditioned on) and picks the pairs it trains on (``--train-on``). `add_cnn` trains a
`workers.detectors.cnn.DetectorNet` on the training realisations
(`workers.detectors.detection.held_out` False) of the training pairs' points, read from the
store (`service.dataset.SampleDataset`), and on ``samples`` fresh realisations a point
rendered by `service.stream.SweepStream` from the store's recorded sweep (realisations from the
sweep's count on: none the store holds), positives and negatives together, each with its
pair's conditions; it says first how long training will take, then each epoch's loss. It
scores the held-out realisations of every pair and appends the network's row (scores, AUC
and its interval, Pd) to each pair's results, as `workers.detectors.detection.score_metrics`
measures every detector. Imports torch: `service.detect` imports this module only when
asked.
"""

from __future__ import annotations

import dataclasses
import itertools
import time
from dataclasses import dataclass

import numpy as np
import torch
import xarray as xr
from torch.utils.data import DataLoader, Dataset

from service.dataset import SampleDataset
from service.errors import BadOptionError
from service.progress import Progress, phase
from service.store.location import Store
from service.store.template import swept_parameters
from service.stream import SweepStream
from workers.detectors.cnn import (
    CNN_DESCRIPTION,
    CnnSettings,
    default_device,
    score,
    train_detector,
)
from workers.detectors.detection import DETECTORS, score_metrics

__all__ = ["CNN", "Conditions", "PairSamples", "add_cnn", "point_conditions", "record_training"]

CNN = "cnn"
"""The trained network's name in the detection dataset's ``detector``."""

SEA_MARGINAL = "sea_marginal_observer"
"""The detector the network's AUC is compared with after training (its ceiling)."""

TRIAL_BATCHES = 3
"""Batches read and trained on (twice, timed the second time) to estimate training's time."""


@dataclass(frozen=True)
class Conditions:
    """What the network is told of each pair, and which pairs it trains on.

    Attributes
    ----------
    names : tuple of str
        The columns: a numeric parameter's path (its values standardised by their mean and
        standard deviation over the training pairs), ``PATH=VALUE`` for each value of a
        parameter that is not a number (1 for that value, else 0).
    values : ndarray of float32, shape (pairs, len(names))
        Each pair's columns (its positive point's values).
    training : ndarray of bool, shape (pairs,)
        The pairs trained on (every pair without ``--train-on``).
    trained_on : tuple of str
        The ``--train-on`` selections, ``PATH=VALUE``.
    """

    names: tuple[str, ...]
    values: np.ndarray
    training: np.ndarray
    trained_on: tuple[str, ...]


def _numeric(column: np.ndarray) -> bool:
    return np.issubdtype(column.dtype, np.number) and column.dtype != bool


def _values(column: np.ndarray) -> np.ndarray:
    """A parameter's values: float64 numbers, else their texts (an object array)."""
    if _numeric(column):
        return column.astype(np.float64)
    return np.array([str(value) for value in column.tolist()], dtype=object)


def _selected(column: np.ndarray, path: str, texts: list[str]) -> np.ndarray:
    """Which of a parameter's values (`column`, one a pair) ``--train-on`` picks."""
    numeric = _numeric(column)
    picked = np.zeros(column.size, dtype=bool)
    for text in texts:
        try:
            value = float(text) if numeric else text
        except ValueError:
            raise BadOptionError(f"--train-on {path}={text}: {path} takes numbers") from None
        match = column == value
        if not match.any():
            values = ", ".join(str(v) for v in dict.fromkeys(column.tolist()))
            raise BadOptionError(
                f"--train-on {path}={text}: no paired point has that value ({path}: {values})"
            )
        picked |= match
    return picked


def point_conditions(ds, pairs: list[tuple[int, int]], *, train_on=()) -> Conditions:
    """Each pair's conditions (its positive point's swept values), and the pairs trained on.

    A column is fitted on the training pairs: a numeric one is standardised by their mean
    and standard deviation, a parameter that they all share is dropped (the network could
    not learn what it changes; so a parameter that ``--train-on`` fixes is not given to it,
    and the pairs at its other values are scored as if they were at the trained one: the
    network does not know the sea changed), and a value of another type gets a column per
    value they have (0 in every column for a value they lack).

    Parameters
    ----------
    ds : xarray.Dataset
        The samples store.
    pairs : list of (int, int)
        (positive point, negative point), as `service.detect_checks.pair_points` gives them.
    train_on : sequence of str, keyword-only
        ``PATH=VALUE``: train only on the pairs whose swept parameter PATH has VALUE (a
        number for a numeric parameter, else its text); several values of one path: any of
        them; several paths: all of them.

    Raises
    ------
    BadOptionError
        Naming ``--train-on`` and the selection: not ``PATH=VALUE``, a path the store does
        not sweep (or ``target.shape``, the label), a value no pair has.
    """
    realisations = int(ds.attrs["realisations"])
    first = np.array([p for p, _ in pairs], dtype=np.int64) * realisations
    columns = {
        path: _values(ds[name].values[first])
        for name, path in swept_parameters(ds).items()
        if path != "target.shape"
    }
    asked: dict[str, list[str]] = {}
    for selection in train_on:
        path, equals, text = selection.partition("=")
        if not equals or not path or not text:
            raise BadOptionError(f"--train-on {selection}: give PATH=VALUE")
        if path == "target.shape":
            raise BadOptionError(
                f"--train-on {selection}: target.shape is the label (with and without the "
                "target), which every pair trains on both of; pick by another parameter"
            )
        if path not in columns:
            raise BadOptionError(
                f"--train-on {selection}: {path} is not a swept parameter of the store "
                f"(it sweeps {', '.join(columns) or 'only target.shape'})"
            )
        asked.setdefault(path, []).append(text)
    training = np.ones(len(pairs), dtype=bool)
    for path, texts in asked.items():
        training &= _selected(columns[path], path, texts)
    if not training.any():
        raise BadOptionError(
            f"--train-on {' '.join(train_on)}: no pair has all these values at once"
        )
    names, values = [], []
    for path, column in columns.items():
        if _numeric(column):
            fitted = column[training]
            if fitted.std() > 0:
                names.append(path)
                values.append((column - fitted.mean()) / fitted.std())
            continue
        kinds = sorted(set(column[training].tolist()))
        if len(kinds) > 1:
            names += [f"{path}={kind}" for kind in kinds]
            values += [column == kind for kind in kinds]
    table = np.stack(values, axis=1) if values else np.empty((len(pairs), 0))
    return Conditions(
        names=tuple(names),
        values=table.astype(np.float32),
        training=training,
        trained_on=tuple(train_on),
    )


class PairSamples(Dataset):
    """Samples of the store (`rows` >= 0) or fresh ones (-1 - index), each with its conditions.

    Item i is sample `rows[i]` with the conditions of pair `pairs[i]`: ``image``,
    ``target_present`` and ``conditions``, a map-style dataset for a ``DataLoader``.

    Parameters
    ----------
    store : SampleDataset
        The store's samples (its written ones).
    fresh : dict
        Fresh samples' ``image`` and ``target_present``, stacked.
    conditions : ndarray, shape (pairs, k)
        Each pair's conditions (`Conditions.values`).
    rows, pairs : array_like of int
        Each item's sample (a store's index, or -1 - a fresh one's) and pair.
    """

    def __init__(self, store: SampleDataset, fresh: dict, conditions: np.ndarray, rows, pairs):
        self.store, self.fresh, self.conditions = store, fresh, conditions
        self.rows = np.asarray(rows, dtype=np.int64)
        self.pairs = np.asarray(pairs, dtype=np.int64)

    def __len__(self) -> int:
        return int(self.rows.size)

    def __getitem__(self, index: int) -> dict[str, np.ndarray]:
        return self.__getitems__([index])[0]

    def __getitems__(self, indices) -> list[dict[str, np.ndarray]]:
        rows, pairs = self.rows[indices], self.pairs[indices]
        stored = rows >= 0
        read = iter(
            self.store.__getitems__(np.searchsorted(self.store.sample_index, rows[stored]))
        )
        items = []
        for row, pair in zip(rows.tolist(), pairs.tolist(), strict=True):
            if row >= 0:
                item = next(read)
                item = {"image": item["image"], "target_present": item["target_present"]}
            else:
                item = {name: values[-1 - row] for name, values in self.fresh.items()}
            items.append(item | {"conditions": self.conditions[pair]})
        return items


def _render_fresh(plan, points, *, first, samples, backend, workers, stream):
    """`samples` fresh realisations (from `first` on) of each of `points`, rendered here.

    In this process, or in `workers` processes (a ``DataLoader``'s, started by a fork
    server: this process's threads are not forked) when it is 2 or more: the same samples
    in the same order either way (`service.stream.SweepStream`).

    Returns
    -------
    fresh : dict
        The images and labels stacked (``image``, ``target_present``).
    where : dict
        Each point's indices in them.
    """
    sweep = SweepStream(
        plan,
        points=points,
        realisations=samples,
        first=first,
        arrays=("image",),
        labels=("target_present",),
        backend=backend.name,
        device=backend.device,
        shuffle=False,
    )
    total = len(sweep)
    fresh, where = {}, {point: [] for point in points}
    progress = Progress(
        total, unit="fresh samples", stream=stream, first="rendering the first fresh sample"
    )
    try:
        processes = workers if workers > 1 else 0
        loader = DataLoader(
            sweep,
            batch_size=None,
            num_workers=processes,
            multiprocessing_context="forkserver" if processes else None,
        )
        for index, item in enumerate(loader):
            for name in ("image", "target_present"):
                value = np.asarray(item[name])
                if name not in fresh:
                    fresh[name] = np.empty((total, *value.shape), value.dtype)
                fresh[name][index] = value
            where[int(item["point"])].append(index)
            progress.update(1)
    finally:
        progress.close()
    return fresh, where


def _say(stream, text: str) -> None:
    """One line on `stream` (None: nowhere)."""
    if stream is not None:
        stream.write(text + "\n")
        stream.flush()


def _minutes(seconds: float) -> str:
    """A duration [s] as a person reads it: seconds under a minute, else minutes."""
    return f"{seconds / 60:.1f} min" if seconds >= 60 else f"{seconds:.1f} s"


def _estimate(items: PairSamples, *, settings, shape, conditions: int, device) -> float:
    """Seconds an epoch over `items` will take: a few batches read and trained, timed.

    The batches are read unshuffled (the training loader's shuffle stream is left as it
    is) and trained on twice: the second pass times a step without the first's start-up.
    """
    loader = DataLoader(items, batch_size=settings.batch_size)
    start = time.perf_counter()
    batches = list(itertools.islice(loader, TRIAL_BATCHES))
    read = time.perf_counter() - start
    ends = []
    train_detector(
        batches,
        channels=shape[0],
        size=shape[1],
        conditions=conditions,
        settings=dataclasses.replace(settings, epochs=2),
        device=device,
        on_epoch=lambda epoch, loss: ends.append(time.perf_counter()),
    )
    step = ends[1] - ends[0]
    return (read + step) / len(batches) * len(loader)


def add_cnn(
    results: list[dict],
    *,
    store: Store,
    pairs: list[tuple[int, int]],
    realisations: int,
    test: np.ndarray,
    pfa,
    settings: CnnSettings,
    conditions: Conditions,
    plan=None,
    backend=None,
    samples: int = 0,
    workers: int = 0,
    device=None,
    stream=None,
) -> tuple[dict[str, str], dict]:
    """Train the network, score it, and append its row to each pair's results.

    Parameters
    ----------
    results : list of dict
        `workers.detectors.detection.evaluate_pair`'s results, one per pair, changed in place: the
        network's scores (NaN on the training realisations and where a sample is not
        written at both points) and metrics appended after the other detectors'.
    store : Store, keyword-only
        The sweep's store.
    pairs : list of (int, int), keyword-only
        (positive point, negative point), as `service.detect_checks.pair_points` gives them.
    realisations : int, keyword-only
        Realisations per point.
    test : ndarray of bool, shape (realisations,), keyword-only
        Held-out realisations (`workers.detectors.detection.held_out`); the others train.
    pfa : sequence of float, keyword-only
        False-alarm probabilities of the Pd.
    settings : CnnSettings, keyword-only
        The network's size, training, batch size and seed.
    conditions : Conditions, keyword-only
        Each pair's conditions and the pairs trained on (`point_conditions`).
    plan : service.sweep.Plan, keyword-only
        The store's sweep (`service.detect_checks.sweep_plan`), to render fresh samples;
        needed when `samples` > 0.
    backend : workers.backends.backend.Backend, keyword-only
        Where the fresh samples render: the store's (`service.devices.written_by`).
    samples : int, keyword-only
        Fresh realisations rendered a training point, besides the store's.
    workers : int, keyword-only
        Processes that render them (2 or more; else this process renders them).
    device : torch.device or str, keyword-only
        Where to train and score (default: a GPU when there is one, else the CPU).
    stream : file, keyword-only
        Where to show the estimate, the rendering's and the epochs' progress and the
        network's gap to the sea-marginal observer; None shows nothing.

    Returns
    -------
    detectors : dict
        The network's name and description, for the dataset's ``detector`` coordinate.
    trained : dict
        ``training_samples`` (the items of an epoch) and ``device`` (where it trained).
    """
    device = torch.device(device) if device is not None else default_device()
    dataset = SampleDataset(
        store.url,
        arrays=("image",),
        labels=("target_present",),
        storage_options=store.storage_options,
    )
    done = store.completed()
    trained = [pair for pair, on in zip(pairs, conditions.training, strict=True) if on]
    points = sorted({point for pair in trained for point in pair})
    fresh, where = {}, {}
    if samples:
        fresh, where = _render_fresh(
            plan,
            points,
            first=realisations,
            samples=samples,
            backend=backend,
            workers=workers,
            stream=stream,
        )
    rows, items_pairs = [], []
    train = np.flatnonzero(~test)
    for index, (positive, negative) in enumerate(pairs):
        if not conditions.training[index]:
            continue
        for point in (positive, negative):
            stored = point * realisations + train
            stored = stored[done[stored]]
            extra = -1 - np.asarray(where.get(point, []), dtype=np.int64)
            rows.append(np.concatenate([stored, extra]))
            items_pairs.append(np.full(rows[-1].size, index))
    training = PairSamples(
        dataset, fresh, conditions.values, np.concatenate(rows), np.concatenate(items_pairs)
    )
    first = dataset[0]["image"]
    shape = (first.shape[0] * first.shape[1], tuple(first.shape[2:]))
    k = len(conditions.names)
    epoch_time = _estimate(training, settings=settings, shape=shape, conditions=k, device=device)
    _say(
        stream,
        f"training: about {_minutes(epoch_time * settings.epochs)} ({settings.epochs} epochs "
        f"of {len(training)} samples on {device})",
    )
    start = time.monotonic()

    def on_epoch(epoch: int, loss: float) -> None:
        elapsed = time.monotonic() - start
        left = elapsed / (epoch + 1) * (settings.epochs - epoch - 1)
        _say(
            stream,
            f"epoch {epoch + 1}/{settings.epochs}: loss {loss:.4f} nats, "
            f"{elapsed:.1f} s elapsed, about {_minutes(left)} left",
        )

    model = train_detector(
        DataLoader(
            training,
            batch_size=settings.batch_size,
            shuffle=True,
            generator=torch.Generator().manual_seed(settings.seed),
        ),
        channels=shape[0],
        size=shape[1],
        conditions=k,
        settings=settings,
        device=device,
        on_epoch=on_epoch,
    )
    held = np.flatnonzero(test)
    scored, scored_pairs = [], []
    for index, (positive, negative) in enumerate(pairs):
        both = held[done[positive * realisations + held] & done[negative * realisations + held]]
        scored += [positive * realisations + both, negative * realisations + both]
        scored_pairs += [np.full(2 * both.size, index)]
    items = PairSamples(
        dataset, {}, conditions.values, np.concatenate(scored), np.concatenate(scored_pairs)
    )
    with phase(f"scoring the CNN on {len(items)} held-out samples", stream=stream):
        scores = iter(score(model, DataLoader(items, batch_size=settings.batch_size)))
    gaps, ceiling = [], list(DETECTORS).index(SEA_MARGINAL)
    for result, (positive, negative) in zip(results, pairs, strict=True):
        both = held[done[positive * realisations + held] & done[negative * realisations + held]]
        s1, s0 = np.full(realisations, np.nan), np.full(realisations, np.nan)
        s1[both] = list(itertools.islice(scores, both.size))
        s0[both] = list(itertools.islice(scores, both.size))
        row = {"score_positive": s1, "score_negative": s0}
        row |= score_metrics(positives=s1, negatives=s0, pfa=pfa)
        for name, value in row.items():
            result[name] = np.concatenate([result[name], np.asarray(value)[np.newaxis]])
        gaps.append(result["auc"][ceiling] - result["auc"][-1])
    if not np.isnan(gaps).all():
        worst = int(np.nanargmax(gaps))
        _say(
            stream,
            f"cnn against the sea-marginal observer: AUC gap mean {np.nanmean(gaps):.3f}, "
            f"worst {gaps[worst]:.3f} (point {pairs[worst][0]}; per point in the dataset)",
        )
    return {CNN: CNN_DESCRIPTION}, {"training_samples": len(training), "device": str(device)}


def record_training(detection: xr.Dataset, settings, conditions, training: dict) -> None:
    """What the network was told, trained on and how: the detection dataset's record."""
    detection["cnn_trained"] = (
        "point",
        conditions.training.astype(np.uint8),
        {"long_name": "the network trained on this pair's training realisations", "units": "1"},
    )
    detection.attrs.update(
        cnn_conditions=list(conditions.names),
        cnn_trained_on=list(conditions.trained_on) or "every pair",
        cnn_fresh_samples=int(training["samples"]),
        cnn_training_samples=int(training["training_samples"]),
        cnn_device=training["device"],
        cnn_epochs=int(settings.epochs),
        cnn_batch_size=int(settings.batch_size),
        cnn_seed=int(settings.seed),
    )
