"""A small convolutional detector of a target in gated images, in PyTorch.

One network scores a sample's images, every frame's every gate a channel of one picture,
larger scores more target-like (the log-odds of a target). It learns from batches of
samples (dicts with ``image``, (frames, gates, y, x) photoelectron counts, and
``target_present``), as `service.dataset.SampleDataset` gives them through a
``torch.utils.data.DataLoader``: `train_detector`, then `score`. Both run on the device
asked for (`default_device`: a GPU when there is one), with a fixed seed and PyTorch's
deterministic algorithms: the same batches give the same model and the same scores, bit for
bit, on CPU. ``service.cnn`` trains one on a sweep's store; `service.detect` scores it.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

__all__ = [
    "CNN_DESCRIPTION",
    "CnnSettings",
    "DetectorNet",
    "default_device",
    "score",
    "train_detector",
]

CNN_DESCRIPTION = (
    "Small convolutional network over the gated images (every frame's gates as channels, "
    "Anscombe-transformed counts), trained once per sweep on the training realisations of "
    "every point (its swept parameters not given), evaluated on the held-out ones: knows "
    "neither sea nor target, only the labelled images."
)
"""What the trained image detector assumes (the detection dataset's ``description``)."""


@dataclass(frozen=True)
class CnnSettings:
    """How the detector is built and trained.

    Attributes
    ----------
    width : int
        Feature maps of the first convolutions (the last have twice as many).
    epochs : int
        Passes over the training samples.
    learning_rate : float
        Adam's step size [1].
    weight_decay : float
        Adam's L2 penalty on the weights [1].
    seed : int
        Seed of the weights' initialisation and of the batches' shuffling.
    """

    width: int = 16
    epochs: int = 20
    learning_rate: float = 2e-3
    weight_decay: float = 1e-4
    seed: int = 0


class DetectorNet(nn.Module):
    r"""Convolutions, then the largest and the mean response over the picture, then a score.

    The counts are variance-stabilised, :math:`2\sqrt{x + 3/8}` (Anscombe), then each
    channel centred and scaled by its mean and standard deviation over the training samples
    (a batch normalisation without momentum: the running statistics are the average of
    every training batch's). Three 3 × 3 convolutions (one 2 × 2 pooling between) and the
    maximum and mean of the last maps over the picture make the score translation
    invariant: a target anywhere in the footprint scores alike.

    Parameters
    ----------
    channels : int
        Frames × gates of a sample.
    width : int, keyword-only
        Feature maps of the first two convolutions.
    """

    def __init__(self, channels: int, *, width: int = 16) -> None:
        super().__init__()
        self.features = nn.Sequential(
            nn.BatchNorm2d(channels, momentum=None),
            nn.Conv2d(channels, width, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(width, width, 3, padding=1),
            nn.ReLU(),
            nn.MaxPool2d(2, ceil_mode=True),
            nn.Conv2d(width, 2 * width, 3, padding=1),
            nn.ReLU(),
        )
        self.head = nn.Linear(4 * width, 1)

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        """Scores (batch,) of images (batch, frames, gates, y, x) [photoelectrons]."""
        x = image.to(torch.float32).flatten(1, 2)
        maps = self.features(2.0 * torch.sqrt(x + 0.375))
        pooled = torch.cat([maps.amax(dim=(2, 3)), maps.mean(dim=(2, 3))], dim=1)
        return self.head(pooled).squeeze(1)


def default_device() -> torch.device:
    """A CUDA GPU when PyTorch sees one, else the CPU."""
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


@contextlib.contextmanager
def _deterministic(seed: int, device: torch.device):
    """A seeded global stream; on the CPU, deterministic algorithms on one thread.

    All restored on leaving. One thread: the same bytes whatever the machine's cores, and
    a network this small gains little from more (on 16 × 16 images two threads on a busy
    2-core machine ran ten times slower than one). On a GPU only the seed is fixed
    (cuBLAS's deterministic mode needs ``CUBLAS_WORKSPACE_CONFIG`` set before CUDA starts):
    scores repeat to rounding there, not to the bit.
    """
    cpu = device.type == "cpu"
    enabled, threads = torch.are_deterministic_algorithms_enabled(), torch.get_num_threads()
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        if cpu:
            torch.use_deterministic_algorithms(True)
            torch.set_num_threads(1)
        try:
            yield
        finally:
            torch.use_deterministic_algorithms(enabled)
            torch.set_num_threads(threads)


def train_detector(
    batches, *, channels: int, settings: CnnSettings = CnnSettings(), device=None
) -> DetectorNet:
    """Train a `DetectorNet` on labelled batches by binary cross-entropy.

    Parameters
    ----------
    batches : iterable
        Iterated once per epoch: dicts of ``image`` (batch, frames, gates, y, x)
        [photoelectrons] and ``target_present`` (batch,), arrays or tensors (a
        ``DataLoader``'s; shuffle it with a generator seeded by ``settings.seed`` for
        bytes that repeat).
    channels : int, keyword-only
        Frames × gates of a sample.
    settings : CnnSettings, keyword-only
        Architecture, optimiser and seed.
    device : torch.device or str, keyword-only
        Where to train (default `default_device`).

    Returns
    -------
    DetectorNet
        The trained network, in evaluation mode, on `device`.
    """
    device = torch.device(device) if device is not None else default_device()
    with _deterministic(settings.seed, device):
        model = DetectorNet(channels, width=settings.width).to(device)
        optimiser = torch.optim.Adam(
            model.parameters(), lr=settings.learning_rate, weight_decay=settings.weight_decay
        )
        loss = nn.BCEWithLogitsLoss()
        model.train()
        for _ in range(settings.epochs):
            for batch in batches:
                image = torch.as_tensor(batch["image"]).to(device)
                label = torch.as_tensor(batch["target_present"]).to(device, torch.float32)
                optimiser.zero_grad()
                loss(model(image), label).backward()
                optimiser.step()
    return model.eval()


def score(model: DetectorNet, batches) -> np.ndarray:
    """The scores (log-odds of a target) of every sample of `batches`, in order.

    Parameters
    ----------
    model : DetectorNet
        A trained network (`train_detector`).
    batches : iterable
        Dicts with ``image`` (batch, frames, gates, y, x) [photoelectrons].

    Returns
    -------
    ndarray of float64, shape (samples,)
    """
    device = next(model.parameters()).device
    with torch.no_grad(), _deterministic(0, device):
        scores = [model(torch.as_tensor(b["image"]).to(device)).cpu() for b in batches]
    return torch.cat(scores).to(torch.float64).numpy() if scores else np.empty(0)
