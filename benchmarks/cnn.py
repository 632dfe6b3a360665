"""The trained network on the detection study: its AUC per pair beside the ceilings', its time.

Reads a rendered study (``configs/detection-study.yaml``: ``oceanlidar run``, then
``oceanlidar detect``, README "Detection study") read-only: trains
`workers.detectors.cnn.DetectorNet` on the training (even) realisations of every point,
told each sample's point (its swept values but ``target.shape``: numbers standardised over
the points, names one-hot), and optionally on ``--fresh`` more realisations a point
rendered by `service.stream.SweepStream` past the store's; scores the held-out (odd)
realisations, and prints per pair the sea-marginal observer's, the matched filter's and the
network's AUCs with their 95 % intervals, the network's held-out cross-entropy, and the
seconds of rendering, training (one CPU thread, `workers.detectors.cnn`) and scoring.
Usage: ``python benchmarks/cnn.py STORE DETECTION [--epochs 5] [--fresh 0]
[--no-conditions] [--device cpu]``.

Figures, 2026-11-28, the 2-core machine shared by several sessions, CPU, one thread, 500
training realisations a point (12 000 samples) unless said; "gap" is the network's AUC
minus the sea-marginal observer's over the 12 pairs (mean, worst):

- the defaults (5 epochs): reading the store 35-39 s, training 56 s (1080 samples/s),
  scoring 12 000 samples 6 s, held-out cross-entropy 0.357; gap -0.004, -0.018 (9 m,
  10 m/s, coastal: 0.608 [0.573, 0.641] against 0.626 [0.591, 0.660], the paired gap
  [-0.049, +0.012]); the same bytes on a second run;
- not told the point (``--no-conditions``): -0.036, -0.091, 11 paired intervals of 12
  below 0;
- the old network (global maximum and mean pooling, no conditions; 20 epochs, 154 s):
  -0.119, -0.217 (6 m, 3 m/s, coastal: 0.626 against 0.842);
- a linear template over the input as well: -0.012, -0.040 after 1 epoch, then
  memorising (-0.040, -0.103 after 4);
- ``--fresh 1500 --epochs 3`` (2000 a point: 36 000 samples rendered in 150 s, 240 /s;
  48 000 trained on in 127 s): -0.001, -0.009, every paired interval holding 0; 5000 a
  point (4500 fresh, 2 epochs, 182 s; measured outside this script): -0.002, -0.015;

the rest in ``docs/detection.md``, "The trained network".
"""

import argparse
import time

import numpy as np
import torch
import xarray as xr
from torch.utils.data import DataLoader, Dataset

from service.stream import SweepStream
from service.sweep import parse_sweep
from workers.detectors.cnn import CnnSettings, score, train_detector
from workers.detectors.detection import auc, bootstrap_auc, held_out

SHAPE = "target_shape"
"""The swept value that gives the label away: never a condition."""

REFERENCES = ("sea_marginal_observer", "matched_filter")
"""The detection dataset's detectors printed beside the network."""


class Samples(Dataset):
    """In-memory samples as `service.dataset.SampleDataset` gives them, with conditions."""

    def __init__(self, image, present, conditions):
        self.image, self.present, self.conditions = image, present, conditions

    def __len__(self):
        return len(self.present)

    def __getitem__(self, i):
        return {
            "image": self.image[i],
            "target_present": self.present[i],
            "conditions": self.conditions[i],
        }


def point_conditions(ds: xr.Dataset) -> np.ndarray:
    """(points, k) float32: each point's swept values but the target's shape.

    Numbers standardised over the points, names one-hot (sorted); a value that does not
    vary adds nothing.
    """
    realisations = int(ds.attrs["realisations"])
    columns = []
    for name, coordinate in sorted(ds.coords.items()):
        if coordinate.dims != ("sample",) or name in ("point", "realisation", SHAPE):
            continue
        values = coordinate.values[::realisations]
        if np.issubdtype(values.dtype, np.number):
            if values.std() > 0:
                columns.append((values - values.mean()) / values.std())
        elif len(names := sorted(set(values.tolist()))) > 1:
            columns += [np.array([v == n for v in values], float) for n in names]
    return np.column_stack(columns).astype(np.float32)


def fresh_samples(ds, *, realisations, count):
    """`count` realisations a point past the store's, rendered; (image, present, point)."""
    plan = parse_sweep(ds.attrs["sweep"])
    stream = SweepStream(
        plan, first=realisations, realisations=count, arrays=("image",), labels=("target_present",)
    )
    start = time.perf_counter()
    items = list(stream)
    seconds = time.perf_counter() - start
    print(f"rendered {len(items)} fresh samples in {seconds:.0f} s: {len(items) / seconds:.0f} /s")
    return tuple(np.stack([it[k] for it in items]) for k in ("image", "target_present", "point"))


def main(store, detection, *, epochs, fresh, conditioned, device):
    ds = xr.open_zarr(store)
    det = xr.open_zarr(detection).load()
    realisations = int(ds.attrs["realisations"])
    point = ds["point"].values
    present = ds["target_present"].values
    start = time.perf_counter()
    image = ds["image"].values
    print(f"read {len(point)} samples in {time.perf_counter() - start:.0f} s")
    conditions = point_conditions(ds)
    test = held_out(realisations)[ds["realisation"].values]
    train_image, train_present, train_point = image[~test], present[~test], point[~test]
    if fresh:
        more = fresh_samples(ds, realisations=realisations, count=fresh)
        train_image, train_present, train_point = (
            np.concatenate([a, b])
            for a, b in zip((train_image, train_present, train_point), more, strict=True)
        )
    k = conditions.shape[1] if conditioned else 0
    settings = CnnSettings(epochs=epochs)
    loader = DataLoader(
        Samples(train_image, train_present, conditions[train_point]),
        batch_size=settings.batch_size,
        shuffle=True,
        generator=torch.Generator().manual_seed(settings.seed),
    )
    start = time.perf_counter()
    model = train_detector(
        loader,
        channels=image.shape[1] * image.shape[2],
        size=image.shape[-2:],
        conditions=k,
        settings=settings,
        device=device,
        on_epoch=lambda e, loss: print(f"epoch {e}: training loss {loss:.4f}", flush=True),
    )
    seconds = time.perf_counter() - start
    print(
        f"trained on {len(train_present)} samples, {epochs} epochs, in {seconds:.0f} s "
        f"({epochs * len(train_present) / seconds:.0f} samples/s)"
    )
    start = time.perf_counter()
    held = Samples(image[test], present[test], conditions[point[test]])
    scores = np.full(len(point), np.nan)
    scores[test] = score(model, DataLoader(held, batch_size=256))
    print(f"scored {test.sum()} samples in {time.perf_counter() - start:.1f} s")
    loss = np.where(
        present[test] == 1, np.logaddexp(0, -scores[test]), np.logaddexp(0, scores[test])
    )
    print(f"held-out cross-entropy {loss.mean():.4f} (ln 2 = {np.log(2):.4f})")
    print_table(det, scores, test, realisations)


def paired_gap(ours, theirs, *, resamples=2000, seed=0):
    """95 % percentile interval of AUC(ours) - AUC(theirs), realisation pairs resampled.

    `ours` and `theirs` are (positive, negative) scores of the same realisations: both
    detectors' are resampled together, so the images' error common to both cancels.
    """
    picks = np.random.default_rng(seed).integers(0, len(ours[0]), size=(resamples, len(ours[0])))
    gaps = [
        auc(positives=ours[0][p], negatives=ours[1][p])
        - auc(positives=theirs[0][p], negatives=theirs[1][p])
        for p in picks
    ]
    return tuple(np.quantile(gaps, [0.025, 0.975]))


def print_table(det, scores, test, realisations):
    """Per pair: sea-marginal, matched filter and network AUCs [95 % intervals], the gap."""
    held = test[:realisations]
    marginal = det.sel(detector="sea_marginal_observer")
    print("depth wind water | sea-marginal | matched filter | network | network - sea-marginal")
    gaps = []
    for i, positive in enumerate(det["point"].values):
        negative = int(det["negative_point"][i])
        s1 = scores[positive * realisations : (positive + 1) * realisations][held]
        s0 = scores[negative * realisations : (negative + 1) * realisations][held]
        ours = auc(positives=s1, negatives=s0)
        low, high = bootstrap_auc(positives=s1, negatives=s0)
        cells = [
            f"{float(det['auc'][i, d]):.3f} [{float(det['auc_low'][i, d]):.3f}, "
            f"{float(det['auc_high'][i, d]):.3f}]"
            for d in map(det.get_index("detector").get_loc, REFERENCES)
        ]
        gaps.append(ours - float(marginal["auc"][i]))
        theirs = (marginal[n].values[i][held] for n in ("score_positive", "score_negative"))
        gap_low, gap_high = paired_gap((s1, s0), tuple(theirs))
        where = " ".join(
            str(det[c].values[i]) for c in ("target_depth", "surface_wind_speed", "water_preset")
        )
        print(
            where,
            "|",
            " | ".join(cells),
            f"| {ours:.3f} [{low:.3f}, {high:.3f}]",
            f"| {gaps[-1]:+.3f} [{gap_low:+.3f}, {gap_high:+.3f}]",
        )
    print(f"network - sea-marginal: mean {np.mean(gaps):+.4f}, worst {np.min(gaps):+.4f}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("store", help="the rendered study (read only)")
    parser.add_argument("detection", help="its detection dataset (oceanlidar detect)")
    parser.add_argument("--epochs", type=int, default=5)
    parser.add_argument("--fresh", type=int, default=0, help="fresh realisations a point")
    parser.add_argument("--no-conditions", action="store_true", help="the point not given")
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args()
    main(
        args.store,
        args.detection,
        epochs=args.epochs,
        fresh=args.fresh,
        conditioned=not args.no_conditions,
        device=args.device,
    )
