"""The trained image detector of `detect --cnn`: one network per sweep, from its store.

`add_cnn` trains a `workers.detectors.cnn.DetectorNet` through the training reader
(`service.dataset.SampleDataset` in a ``torch.utils.data.DataLoader``) on the training
realisations (`workers.detectors.detection.held_out` False) of every point `service.detect` pairs,
positives and negatives together, their swept parameters not given to it; it scores the
held-out realisations of the same points and appends the network's row (scores, AUC and
its interval, Pd) to each pair's results, as `workers.detectors.detection.score_metrics` measures
every detector. Imports torch: `service.detect` imports this module only when asked.
"""

from __future__ import annotations

import numpy as np
import torch
from torch.utils.data import DataLoader, Subset

from service.dataset import SampleDataset
from service.progress import phase
from service.store.location import Store
from workers.detectors.cnn import (
    CNN_DESCRIPTION,
    CnnSettings,
    default_device,
    score,
    train_detector,
)
from workers.detectors.detection import score_metrics

__all__ = ["BATCH_SIZE", "CNN", "add_cnn"]

CNN = "cnn"
"""The trained network's name in the detection dataset's ``detector``."""

BATCH_SIZE = 64
"""Samples a training and a scoring batch holds."""


def _loader(dataset: SampleDataset, samples: np.ndarray, *, shuffle: bool, seed: int):
    """A ``DataLoader`` over the store's `samples` (indices in the store, all written)."""
    items = np.searchsorted(dataset.sample_index, samples).tolist()
    return DataLoader(
        Subset(dataset, items),
        batch_size=BATCH_SIZE,
        shuffle=shuffle,
        generator=torch.Generator().manual_seed(seed) if shuffle else None,
    )


def add_cnn(
    results: list[dict],
    *,
    store: Store,
    pairs: list[tuple[int, int]],
    realisations: int,
    test: np.ndarray,
    pfa,
    settings: CnnSettings,
    device=None,
    stream=None,
) -> dict[str, str]:
    """Train the network on `store`, score it, and append its row to each pair's results.

    Parameters
    ----------
    results : list of dict
        `workers.detectors.detection.evaluate_pair`'s results, one per pair, changed in place: the
        network's scores (NaN on the training realisations and where a sample is not
        written at both points) and metrics appended after the other detectors'.
    store : Store, keyword-only
        The sweep's store.
    pairs : list of (int, int), keyword-only
        (positive point, negative point), as `service.detect.pair_points` gives them.
    realisations : int, keyword-only
        Realisations per point.
    test : ndarray of bool, shape (realisations,), keyword-only
        Held-out realisations (`workers.detectors.detection.held_out`); the others train.
    pfa : sequence of float, keyword-only
        False-alarm probabilities of the Pd.
    settings : CnnSettings, keyword-only
        The network's size, training and seed.
    device : torch.device or str, keyword-only
        Where to train and score (default: a GPU when there is one, else the CPU).
    stream : file, keyword-only
        Where to show the phases and their durations; None shows nothing.

    Returns
    -------
    dict
        The network's name and description, for the dataset's ``detector`` coordinate.
    """
    points = np.unique(np.asarray(pairs, dtype=np.int64))
    rows = (points[:, np.newaxis] * realisations + np.arange(realisations)).ravel()
    written = rows[store.completed(rows)]
    training = written[~test[written % realisations]]
    held = written[test[written % realisations]]
    dataset = SampleDataset(
        store.url,
        arrays=("image",),
        labels=("target_present",),
        storage_options=store.storage_options,
    )
    frames, gates = dataset[0]["image"].shape[:2]
    device = torch.device(device) if device is not None else default_device()
    with phase(f"training the CNN on {training.size} samples ({device})", stream=stream):
        model = train_detector(
            _loader(dataset, training, shuffle=True, seed=settings.seed),
            channels=frames * gates,
            settings=settings,
            device=device,
        )
    with phase(f"scoring the CNN on {held.size} held-out samples", stream=stream):
        scores = np.full((points.max() + 1) * realisations, np.nan)
        scores[held] = score(model, _loader(dataset, held, shuffle=False, seed=0))
    for result, (positive, negative) in zip(results, pairs, strict=True):
        s1 = scores[positive * realisations : (positive + 1) * realisations].copy()
        s0 = scores[negative * realisations : (negative + 1) * realisations].copy()
        s1[np.isnan(s0)] = s0[np.isnan(s1)] = np.nan  # realisations written at both only
        row = {"score_positive": s1, "score_negative": s0}
        row |= score_metrics(positives=s1, negatives=s0, pfa=pfa)
        for name, value in row.items():
            result[name] = np.concatenate([result[name], np.asarray(value)[np.newaxis]])
    return {CNN: CNN_DESCRIPTION}
