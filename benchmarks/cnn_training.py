"""How fast `detect --cnn` is fed and trains: fresh samples from `SweepStream`, epochs per 1000.

Prints (1) the rate at which `service.stream.SweepStream` renders fresh samples (after the first
`WARM_UP`) of
``configs/detection-study.yaml`` (32 x 32 pixels, three gates; realisations from the
sweep's count on, as ``detect --samples`` renders them) in this process and through a
``DataLoader`` with ``--workers`` worker processes, and (2) the wall seconds of a training
epoch over 1000 samples of a study store on one CPU thread (the network
`workers.detectors.cnn.DetectorNet` with the study's conditions, ``batch_size`` 64):
read from the store each epoch, as `service.cnn.add_cnn` reads them, and held in memory
(the fresh samples' case). Usage: ``python benchmarks/cnn_training.py STORE [--renders 480]
[--workers 2]``, STORE a run of the study.

Figures, 2026-11-28, the 2-core machine shared by 8 sessions (load 2 to 2.5), the study's
store (1000 realisations), the network with the 1 x 1 reduction and per-pixel readout:
SweepStream 228.8 fresh samples/s in this process, 124.4 with 2 workers (480 renders after
96; over 1920: 200.8 and 167.3; timed after 1 render only, the first ~70 of a process
compiling, it showed 52-55); an epoch of 1000 samples 1.00-1.04 s read from the store,
0.83-0.95 s held in memory.
"""

import argparse
import itertools
import time
from pathlib import Path

import numpy as np
from torch.utils.data import DataLoader

from service.cnn import PairSamples, point_conditions
from service.dataset import SampleDataset
from service.detect import pair_points
from service.store.location import Store
from service.stream import SweepStream
from service.sweep import load_sweep
from workers.detectors.cnn import CnnSettings, train_detector

STUDY = Path(__file__).resolve().parent.parent / "configs" / "detection-study.yaml"
WARM_UP = 96
"""Samples rendered before the timing starts: the first ~70 of a process render 5x slower."""


def render_rate(plan, renders: int, workers: int) -> float:
    """Fresh samples rendered a second, after `WARM_UP` (`workers` 0: in this process)."""
    stream = SweepStream(
        plan,
        realisations=(renders + WARM_UP) // len(plan.points) + 2,
        first=plan.realisations,
        arrays=("image",),
        labels=("target_present",),
        shuffle=False,
    )
    items = iter(DataLoader(stream, batch_size=None, num_workers=workers))
    for _ in itertools.islice(items, WARM_UP):  # the kernels' compilation, the caches
        pass
    start = time.perf_counter()
    for _ in itertools.islice(items, renders):
        pass
    return renders / (time.perf_counter() - start)


def epoch_seconds(store: Store, *, in_memory: bool, samples: int = 1000) -> float:
    """Wall seconds of the second epoch over `samples` training items, one CPU thread."""
    ds = store.dataset()
    pairs, _ = pair_points(ds)
    conditions = point_conditions(ds, pairs)
    realisations = int(ds.attrs["realisations"])
    rows, of_pair = [], []
    for index, pair in enumerate(pairs):
        for point in pair:
            rows.append(point * realisations + np.arange(0, realisations, 2))
            of_pair.append(np.full(rows[-1].size, index))
    pick = np.random.default_rng(0).permutation(np.concatenate(rows).size)[:samples]
    dataset = SampleDataset(store.url, arrays=("image",), labels=("target_present",))
    items = PairSamples(
        dataset, {}, conditions.values, np.concatenate(rows)[pick], np.concatenate(of_pair)[pick]
    )
    batches = DataLoader(items, batch_size=64)
    if in_memory:
        batches = list(batches)
    image = dataset[0]["image"]
    ends = []
    train_detector(
        batches,
        channels=image.shape[0] * image.shape[1],
        size=image.shape[2:],
        conditions=len(conditions.names),
        settings=CnnSettings(epochs=2),
        device="cpu",
        on_epoch=lambda epoch, loss: ends.append(time.perf_counter()),
    )
    return ends[1] - ends[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("store", help="a store of configs/detection-study.yaml")
    parser.add_argument("--renders", type=int, default=480)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    plan = load_sweep(STUDY)
    for workers in (0, args.workers):
        rate = render_rate(plan, args.renders, workers)
        where = "this process" if not workers else f"{workers} DataLoader workers"
        print(f"SweepStream, 32 px, {where}: {rate:.1f} fresh samples/s")
    store = Store.at(args.store)
    for in_memory in (False, True):
        seconds = epoch_seconds(store, in_memory=in_memory)
        where = "held in memory" if in_memory else "read from the store"
        print(f"training, 1 CPU thread, 1000 samples {where}: {seconds:.2f} s an epoch")


if __name__ == "__main__":
    main()
