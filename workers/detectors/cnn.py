"""A small convolutional detector of a target in gated images, in PyTorch.

One network scores a sample's images, every frame's every gate a channel of one picture,
larger scores more target-like (the log-odds of a target). It learns from batches of
samples (dicts with ``image``, (frames, gates, y, x) photoelectron counts,
``target_present``, and ``conditions``, (k,) numbers describing the sample's sweep point
without giving its label away), as `service.dataset.SampleDataset` gives them through a
``torch.utils.data.DataLoader``: `train_detector`, then `score`. Both run on the device
asked for (`default_device`: a GPU when there is one), with a fixed seed and PyTorch's
deterministic algorithms: the same batches give the same model and the same scores, bit for
bit, on CPU. ``service.cnn`` trains one on a sweep's store; `service.detect` scores it.
"""

from __future__ import annotations

import contextlib
import math
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
    "Anscombe-transformed counts, and each pixel's place relative to the picture's centre), "
    "its feature maps and its score conditioned on the sample's swept parameters that do not "
    "give the label away (FiLM), read out by per-pixel weight maps (no global pooling: it may "
    "use where the target is), trained once per sweep on the training realisations of every "
    "point, evaluated on the held-out ones: knows neither sea nor target, only the labelled "
    "images and their points."
)
"""What the trained image detector assumes (the detection dataset's ``description``)."""

READOUTS = 4
"""Weight maps of the readout, mixed per sample by coefficients of its conditions."""

HIDDEN = 32
"""Units of the conditions' hidden layer."""


@dataclass(frozen=True)
class CnnSettings:
    """How the detector is built and trained.

    Attributes
    ----------
    width : int
        Feature maps of the first convolutions (the last have twice as many).
    epochs : int
        Passes over the training samples. On the detection study's 500 training
        realisations a point the held-out AUCs are best after 3 to 5 and fall after
        (``docs/detection.md``, "The trained network"): more passes memorise the samples.
    learning_rate : float
        Adam's step size [1].
    weight_decay : float
        Adam's L2 penalty on the weights [1].
    seed : int
        Seed of the weights' initialisation and of the batches' shuffling.
    batch_size : int
        Samples a training and a scoring batch holds (the loader's: the network takes what
        it is given).
    """

    width: int = 16
    epochs: int = 5
    learning_rate: float = 2e-3
    weight_decay: float = 1e-4
    seed: int = 0
    batch_size: int = 64


def _mlp(inputs: int, outputs: int) -> nn.Sequential:
    """Conditions -> `outputs` numbers, one hidden layer; 0 for every input at first."""
    out = nn.Linear(HIDDEN, outputs)
    nn.init.zeros_(out.weight)
    nn.init.zeros_(out.bias)
    return nn.Sequential(nn.Linear(inputs, HIDDEN), nn.ReLU(), out)


class DetectorNet(nn.Module):
    r"""Convolutions conditioned on the point, read out by weight maps over the picture.

    The counts are variance-stabilised, :math:`2\sqrt{x + 3/8}` (Anscombe), then each
    channel centred and scaled by its mean and standard deviation over the training samples
    (a batch normalisation without momentum: the running statistics are the average of
    every training batch's), and two channels added, each pixel's x and y relative to the
    picture's centre (in half-widths): the convolutions may tell the centre from the edge.
    Three 3 × 3 convolutions (one 2 × 2 maximum pooling between), each followed by a
    per-map scale and shift computed from the sample's conditions (FiLM, Perez et al. 2018;
    the identity at first), give feature maps; a 1 × 1 convolution reduces them to
    :data:`READOUTS` maps, each weighted pixel by pixel by a learnt map over the (pooled)
    picture and summed: as many numbers, mixed into the score by coefficients and a bias that
    are again functions of the conditions (learnt constants without conditions). No global
    pooling: the score may depend on where the target is, and on the point.

    Notes
    -----
    The weight maps act on the reduced maps, not on every feature map, and nothing reads the
    input linearly (a template, the matched filter's form, 3 × 32 × 32 weights a readout at
    32 px): on ``configs/detection-study.yaml`` (12 000 training samples) a readout of every
    feature map with such a template memorised the training samples within 3 epochs, and
    the reduced readout with the template did too, their held-out AUCs falling below the
    sea-marginal observer's by up to 0.10 (``docs/detection.md``, "The trained network").

    Parameters
    ----------
    channels : int
        Frames × gates of a sample.
    size : (int, int), keyword-only
        Pixels (y, x) of a picture.
    conditions : int, keyword-only
        Numbers describing a sample's sweep point (0: none given).
    width : int, keyword-only
        Feature maps of the first two convolutions.
    """

    def __init__(
        self, channels: int, *, size: tuple[int, int], conditions: int = 0, width: int = 16
    ) -> None:
        super().__init__()
        ny, nx = (int(n) for n in size)
        self.conditions = int(conditions)
        self.normalise = nn.BatchNorm2d(channels, momentum=None)
        y = (torch.arange(ny, dtype=torch.float32) - (ny - 1) / 2) / (ny / 2)
        x = (torch.arange(nx, dtype=torch.float32) - (nx - 1) / 2) / (nx / 2)
        self.register_buffer("place", torch.stack(torch.meshgrid(y, x, indexing="ij")))
        self.maps = (width, width, 2 * width)
        self.convolutions = nn.ModuleList(
            [
                nn.Conv2d(channels + 2, width, 3, padding=1),
                nn.Conv2d(width, width, 3, padding=1),
                nn.Conv2d(width, 2 * width, 3, padding=1),
            ]
        )
        self.pool = nn.MaxPool2d(2, ceil_mode=True)
        self.reduce = nn.Conv2d(2 * width, READOUTS, 1)
        self.readout = nn.Parameter(torch.zeros(READOUTS, math.ceil(ny / 2), math.ceil(nx / 2)))
        if self.conditions:
            self.film = _mlp(self.conditions, 2 * sum(self.maps))
            self.mix = _mlp(self.conditions, READOUTS + 1)
        mean = torch.full((READOUTS,), 1.0 / READOUTS)
        self.mix_constant = nn.Parameter(torch.cat([mean, torch.zeros(1)]))  # the readouts' mean

    def forward(self, image: torch.Tensor, conditions: torch.Tensor | None = None) -> torch.Tensor:
        """Scores (batch,) of images (batch, frames, gates, y, x) [photoelectrons].

        `conditions` (batch, k), float32: the samples' points, required when the network
        was built with k > 0 conditions, ignored otherwise.
        """
        x = self.normalise(2.0 * torch.sqrt(image.to(torch.float32).flatten(1, 2) + 0.375))
        batch = x.shape[0]
        if self.conditions:
            if conditions is None:
                raise ValueError(f"conditions: the network needs {self.conditions} a sample")
            c = conditions.to(x.device, torch.float32).reshape(batch, self.conditions)
            film = self.film(c).split([m for m in self.maps for _ in (0, 1)], dim=1)
            mix = self.mix_constant + self.mix(c)
        else:
            film = [None] * (2 * len(self.maps))
            mix = self.mix_constant.expand(batch, -1)
        maps = torch.cat([x, self.place.expand(batch, -1, -1, -1)], dim=1)
        for i, convolution in enumerate(self.convolutions):
            maps = convolution(maps)
            scale, shift = film[2 * i], film[2 * i + 1]
            if scale is not None:
                maps = maps * (1.0 + scale[:, :, None, None]) + shift[:, :, None, None]
            maps = torch.relu(maps)
            if i == 1:
                maps = self.pool(maps)
        readouts = (self.reduce(maps) * self.readout).sum(dim=(2, 3))
        return (readouts * mix[:, :READOUTS]).sum(dim=1) + mix[:, READOUTS]


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


def _inputs(batch, device: torch.device, conditions: int):
    """A batch's images and conditions (None without) as tensors on `device`."""
    image = torch.as_tensor(batch["image"]).to(device)
    if not conditions:
        return image, None
    return image, torch.as_tensor(batch["conditions"]).to(device, torch.float32)


def train_detector(
    batches,
    *,
    channels: int,
    size: tuple[int, int] | None = None,
    conditions: int = 0,
    settings: CnnSettings = CnnSettings(),
    device=None,
    on_epoch=None,
) -> DetectorNet:
    """Train a `DetectorNet` on labelled batches by binary cross-entropy.

    Parameters
    ----------
    batches : iterable
        Iterated once per epoch: dicts of ``image`` (batch, frames, gates, y, x)
        [photoelectrons], ``target_present`` (batch,), and ``conditions`` (batch, k) when
        k > 0, arrays or tensors (a ``DataLoader``'s; shuffle it with a generator seeded by
        ``settings.seed`` for bytes that repeat).
    channels : int, keyword-only
        Frames × gates of a sample.
    size : (int, int), keyword-only
        Pixels (y, x) of a picture (default: the first batch's, `batches` iterated once
        more for it: a shuffling loader's epochs then shuffle otherwise).
    conditions : int, keyword-only
        Numbers k describing a sample's point (0: none).
    settings : CnnSettings, keyword-only
        Architecture, optimiser and seed.
    device : torch.device or str, keyword-only
        Where to train (default `default_device`).
    on_epoch : callable, keyword-only
        Called as ``on_epoch(epoch, loss)`` after each epoch (from 0) with its mean
        training cross-entropy [nats]; None calls nothing.

    Returns
    -------
    DetectorNet
        The trained network, in evaluation mode, on `device`.
    """
    device = torch.device(device) if device is not None else default_device()
    if size is None:
        size = tuple(np.shape(next(iter(batches))["image"])[-2:])
    with _deterministic(settings.seed, device):
        model = DetectorNet(channels, size=size, conditions=conditions, width=settings.width).to(
            device
        )
        optimiser = torch.optim.Adam(
            model.parameters(), lr=settings.learning_rate, weight_decay=settings.weight_decay
        )
        loss = nn.BCEWithLogitsLoss(reduction="sum")
        model.train()
        for epoch in range(settings.epochs):
            total, samples = 0.0, 0
            for batch in batches:
                image, c = _inputs(batch, device, conditions)
                label = torch.as_tensor(batch["target_present"]).to(device, torch.float32)
                optimiser.zero_grad()
                value = loss(model(image, c), label)
                (value / label.numel()).backward()
                optimiser.step()
                total, samples = total + float(value.detach()), samples + label.numel()
            if on_epoch is not None:
                on_epoch(epoch, total / max(samples, 1))
    return model.eval()


def score(model: DetectorNet, batches) -> np.ndarray:
    """The scores (log-odds of a target) of every sample of `batches`, in order.

    Parameters
    ----------
    model : DetectorNet
        A trained network (`train_detector`).
    batches : iterable
        Dicts with ``image`` (batch, frames, gates, y, x) [photoelectrons], and
        ``conditions`` (batch, k) when the network takes k > 0.

    Returns
    -------
    ndarray of float64, shape (samples,)
    """
    device = next(model.parameters()).device
    with torch.no_grad(), _deterministic(0, device):
        scores = [model(*_inputs(b, device, model.conditions)).cpu() for b in batches]
    return torch.cat(scores).to(torch.float64).numpy() if scores else np.empty(0)
