"""How fast `detect --cnn` is fed and trains: fresh samples from `SweepStream`, epochs per 1000.

Prints (1) the rate at which `service.stream.SweepStream` renders fresh samples of
``configs/detection-study.yaml`` (32 x 32 pixels, three gates; realisations from the
sweep's count on, as ``detect --samples`` renders them) in this process and through a
``DataLoader`` with ``--workers`` worker processes, and (2) the wall seconds of a training
epoch over 1000 samples of a study store on one CPU thread (the network
`workers.detectors.cnn.DetectorNet` with the study's conditions, ``batch_size`` 64):
read from the store each epoch, as `service.cnn.add_cnn` reads them, and held in memory
(the fresh samples' case). Usage: ``python benchmarks/cnn_training.py STORE [--renders 60]
[--workers 2]``, STORE a run of the study.

Figures, 2026-11-28, the 2-core machine shared by 8 sessions (load 2 to 3), the network
of net's 15a3bf2 (the study's store 1000 realisations): SweepStream 54.9 fresh samples/s in
this process, 109.2 with 2 workers (51.7 and 119.0 in an earlier run); an epoch of 1000
samples 1.00 s read from the store, 0.83 s held in memory (0.91 and 0.85 with net's first
network).
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


def render_rate(plan, renders: int, workers: int) -> float:
    """Fresh samples rendered a second, after the first (`workers` 0: in this process)."""
    stream = SweepStream(
        plan,
        realisations=renders // len(plan.points) + 2,
        first=plan.realisations,
        arrays=("image",),
        labels=("target_present",),
        shuffle=False,
    )
    items = iter(DataLoader(stream, batch_size=None, num_workers=workers))
    next(items)
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
    parser.add_argument("--renders", type=int, default=60)
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
