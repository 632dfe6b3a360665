"""The detection study of a sweep: detectors' ROC, AUC and Pd per parameter point.

Pairs every parameter point with a target (a positive point) with the target-free point
of the same scene (`pair_points`), reads both points' samples realisation by realisation
(pairs never cross realisations: row i of both saw the same sea; a store without the
noise-free images has them rendered again from its sweep and seeds), scores them with the
detectors of `workers.detectors.detection` on the dask cluster in use (one task per pair) and
writes
a detection dataset beside the store (`detection_store`). Variables, per positive point:

- ``score_positive``, ``score_negative`` (point, detector, realisation): every score, NaN
  where a detector is not evaluated (the trained one's training realisations);
- ``auc``, ``auc_low``, ``auc_high`` (point, detector): area under the ROC and its 95 %
  bootstrap interval (realisations resampled, fixed seed); ``evaluated`` the pairs used;
- ``pd`` (point, detector, pfa): probability of detection at 10⁻¹ and 10⁻², NaN where the
  negatives are too few to measure that false-alarm rate, ``pd_available`` the flag;
- ``roc_pfa``, ``roc_pd`` (point, detector, vertex): the empirical ROC, NaN-padded;
- ``gate_auc``, ``gate_auc_low``, ``gate_auc_high`` (point, gate): each gate's matched
  filter alone;
- ``sea_auc_se``, ``auc_half_seas``, ``effective_seas``, ``seas`` (point): the
  sea-marginal observer's Monte Carlo error (`workers.detectors.detection.sea_auc_error`);
- ``negative_point`` (point): the store's target-free point paired with it, and
  ``held_out`` (realisation): the realisations the trained detector and the sea-marginal
  observer are evaluated on (the others train the one and are the other's seas);
- with the trained network (``--cnn``), ``cnn_trained`` (point): whether it trained on the
  pair (``--train-on``), and attributes ``cnn_conditions`` (the columns it was told of each
  pair), ``cnn_trained_on``, ``cnn_fresh_samples``, ``cnn_training_samples``, ``cnn_epochs``,
  ``cnn_batch_size``, ``cnn_seed``, ``cnn_device`` (`service.cnn`).
"""

from __future__ import annotations

import contextlib
import logging
import uuid
from typing import TYPE_CHECKING

import dask
import numpy as np
import xarray as xr

from service import package_version
from service.detect_checks import check_store, pair_points, sweep_plan, written_pairs
from service.devices import written_by
from service.errors import BadOptionError, BadSweepError, UnusableOutputError
from service.progress import Progress, compute, phase
from service.store.integrity import check_labels
from service.store.layout import CONVENTIONS
from service.store.location import Store
from service.store.shards import read_verified
from service.store.template import swept_parameters
from workers.backends.backend import Backend
from workers.detectors.detection import (
    DETECTORS,
    MIN_FALSE_ALARMS,
    evaluate_pair,
    held_out,
    roc_curve,
)
from workers.render import render_images, render_pair

if TYPE_CHECKING:
    from workers.detectors.cnn import CnnSettings

__all__ = ["PFA", "detection_store", "pair_points", "write_detection"]

log = logging.getLogger("oceanlidar")

PFA = (1e-1, 1e-2)
"""False-alarm probabilities at which the probability of detection is reported."""

DATASET_KIND = "detection"
"""``oceanlidar_dataset`` attribute of a detection dataset (what may be overwritten)."""


def detection_store(store: Store) -> Store:
    """Where the detection dataset of `store` lives by default (beside it)."""
    return store.sibling("detect")


def _rendered_expected(plan, rows, both, images, backend: Backend):
    """Render the pair's samples again for their noise-free images (renders are deterministic).

    `rows` maps the positive and the negative point to their samples, `both` picks the
    realisations read, `images` their stored noisy images by point, `backend` the one that
    wrote them (`service.devices.written_by`: another draws other noise). A positive sample whose
    point's target-free twin (`workers.settings.scene.Scene.without_target`) is the negative
    point's
    scene is rendered once with its twin (`workers.render.render_pair`: the negative
    sample's images, on the same sea, in the same pass); otherwise each sample is rendered
    on its own (`workers.render.render_images`: no twin). The noisy images rendered again
    must be the stored ones, or the store was written by another version of the physics and
    its expected images cannot be recovered.

    Returns
    -------
    dict
        The expected images by point, float64.
    """
    (positive, negative), rendered = rows, {point: [] for point in rows}
    where = {"backend": backend.name, "device": backend.device}
    for p, q in zip(rows[positive][both], rows[negative][both], strict=True):
        a, b = plan.sample(int(p)), plan.sample(int(q))
        pair = None
        if b.scene == a.scene.without_target():
            pair = render_pair(a.scene, seed=a.seed, twin_seed=b.seed, **where)
        if pair is None:
            pair = (
                *render_images(a.scene, seed=a.seed, **where),
                *render_images(b.scene, seed=b.seed, **where),
            )
        rendered[positive].append(pair[:2])
        rendered[negative].append(pair[2:])
    expected = {}
    for point, samples in rendered.items():
        if not np.array_equal(np.stack([noisy for _, noisy in samples]), images[point]):
            picked = rows[point][both]
            raise BadSweepError(
                f"samples {picked[0]}..{picked[-1]} rendered again differ from the stored "
                "ones (written by another oceanlidar version?): their expected images cannot "
                "be recovered"
            )
        expected[point] = np.stack([mean for mean, _ in samples]).astype(np.float64)
    return expected


def _evaluate(store: Store, positive, negative, both, test, plan, backend):
    """Read one pair's samples (the realisations `both` written at both points), score them.

    Each sample is checked as ``info --verify`` checks it (every chunk's CRC32C, its arrays
    against its checksum: `service.store.shards.read_verified`), so that a damaged, lost or
    foreign shard stops the study naming the sample. `plan`: the store's sweep, to render
    the expected images again when the store has none (None: read them), on `backend`,
    the one that wrote them.
    """
    source = store.group()
    realisations = both.size
    rows = {p: np.arange(realisations) + p * realisations for p in (positive, negative)}
    images, expected = {}, {}
    for p in (positive, negative):
        read = read_verified(source, rows[p][both].tolist())
        image = read["image"]
        if not np.array_equal(image, np.round(image)):
            raise BadSweepError(
                f"point {p}: images are not whole photoelectron counts (an ICCD excess-noise "
                "stage?): the ideal observer needs Poisson counts"
            )
        images[p] = image
        if plan is None:
            expected[p] = read["expected"].astype(np.float64)
    if plan is not None:
        expected = _rendered_expected(plan, rows, both, images, backend)
    metrics = evaluate_pair(
        positive_image=images[positive].astype(np.float64),
        positive_expected=expected[positive],
        negative_image=images[negative].astype(np.float64),
        negative_expected=expected[negative],
        test=test[both],
        pfa=PFA,
    )
    for name in ("score_positive", "score_negative"):
        full = np.full((len(DETECTORS), realisations), np.nan)
        full[:, both] = metrics[name]
        metrics[name] = full
    return metrics


def _dataset(ds, pairs, results, realisations, test, detectors) -> xr.Dataset:
    names = list(detectors)
    stacked = {name: np.stack([r[name] for r in results]) for name in results[0]}
    rocs = [
        [
            roc_curve(positives=s1[~np.isnan(s1)], negatives=s0[~np.isnan(s0)])
            for s1, s0 in zip(r["score_positive"], r["score_negative"], strict=True)
        ]
        for r in results
    ]
    vertices = max(len(pfa) for point in rocs for pfa, _ in point)
    roc = np.full((2, len(pairs), len(names), vertices), np.nan)
    for i, point in enumerate(rocs):
        for d, (pfa, pd) in enumerate(point):
            roc[0, i, d, : len(pfa)] = pfa
            roc[1, i, d, : len(pd)] = pd
    one = {"units": "1"}
    dims = ("point", "detector")
    data_vars = {
        "negative_point": (
            "point",
            np.array([q for _, q in pairs], dtype=np.int64),
            {"long_name": "target-free parameter point paired with this one", **one},
        ),
        "score_positive": (
            (*dims, "realisation"),
            stacked["score_positive"],
            {"long_name": "detector score of the sample with the target", **one},
        ),
        "score_negative": (
            (*dims, "realisation"),
            stacked["score_negative"],
            {"long_name": "detector score of the target-free sample, same sea", **one},
        ),
        "auc": (dims, stacked["auc"], {"long_name": "area under the ROC curve", **one}),
        "auc_low": (dims, stacked["auc_low"], {"long_name": "AUC 95 % interval, low", **one}),
        "auc_high": (dims, stacked["auc_high"], {"long_name": "AUC 95 % interval, high", **one}),
        "evaluated": (
            dims,
            stacked["evaluated"],
            {"long_name": "realisation pairs the detector was evaluated on", **one},
        ),
        "pd": (
            (*dims, "pfa"),
            stacked["pd"],
            {
                "long_name": "probability of detection at the false-alarm probability",
                "comment": f"NaN (pd_available 0) with fewer than {MIN_FALSE_ALARMS}/pfa "
                "negatives: never extrapolated",
                **one,
            },
        ),
        "pd_available": (
            (*dims, "pfa"),
            (~np.isnan(stacked["pd"])).astype(np.uint8),
            {"long_name": "enough negatives to measure pd at this pfa", **one},
        ),
        "roc_pfa": (
            (*dims, "vertex"),
            roc[0],
            {"long_name": "ROC false-alarm probability (NaN-padded)", **one},
        ),
        "roc_pd": (
            (*dims, "vertex"),
            roc[1],
            {"long_name": "ROC probability of detection (NaN-padded)", **one},
        ),
        "gate_auc": (
            ("point", "gate"),
            stacked["gate_auc"],
            {"long_name": "AUC of the gate's matched filter alone", **one},
        ),
        "gate_auc_low": (
            ("point", "gate"),
            stacked["gate_auc_low"],
            {"long_name": "gate AUC 95 % interval, low", **one},
        ),
        "gate_auc_high": (
            ("point", "gate"),
            stacked["gate_auc_high"],
            {"long_name": "gate AUC 95 % interval, high", **one},
        ),
        "sea_auc_se": (
            "point",
            stacked["sea_auc_se"],
            {
                "long_name": "Monte Carlo error of the sea-marginal observer's AUC",
                "comment": "standard deviation over a bootstrap of its seas, the images fixed; "
                "adds in quadrature to the auc interval's error",
                **one,
            },
        ),
        "auc_half_seas": (
            "point",
            stacked["auc_half_seas"],
            {"long_name": "sea-marginal observer's AUC with half its seas (mean of two)", **one},
        ),
        "effective_seas": (
            "point",
            stacked["effective_seas"],
            {"long_name": "median effective number of seas weighting an image", **one},
        ),
        "seas": (
            "point",
            stacked["seas"].astype(np.int64),
            {"long_name": "seas in the sea-marginal observer's Monte Carlo sample", **one},
        ),
        "held_out": (
            "realisation",
            test.astype(np.uint8),
            {
                "long_name": "realisation evaluates (1) or trains (0) the trained detectors",
                "comment": "the training realisations' seas are the sea-marginal observer's",
                **one,
            },
        ),
    }
    positives = [p for p, _ in pairs]
    coords = {
        "point": ("point", np.array(positives), {"long_name": "parameter point index", **one}),
        "detector": ("detector", np.array(names, dtype=object), {"long_name": "detector"}),
        "description": (
            "detector",
            np.array([detectors[n] for n in names], dtype=object),
            {"long_name": "what the detector assumes"},
        ),
        "pfa": ("pfa", np.array(PFA), {"long_name": "false-alarm probability", **one}),
        "realisation": (
            "realisation",
            np.arange(realisations),
            {"long_name": "Monte Carlo realisation index", **one},
        ),
        "gate_top": ds["gate_top"].load(),
        "gate_bottom": ds["gate_bottom"].load(),
    }
    for name in swept_parameters(ds):
        coord = ds[name]
        coords[name] = (
            "point",
            coord.values[np.array(positives) * realisations],
            dict(coord.attrs),
        )
    detection = xr.Dataset(data_vars, coords=coords)
    detection.attrs.update(
        title=ds.attrs.get("title", "") + " detection study",
        Conventions=CONVENTIONS,
        source=f"oceanlidar {package_version()}",
        history=f"oceanlidar {package_version()} detection study of {ds.attrs.get('title', '')}",
        oceanlidar_dataset=DATASET_KIND,
        sweep_sha256=ds.attrs.get("sweep_sha256", ""),
        oceanlidar_version=package_version(),
        bootstrap="95 % percentile interval, 2000 resamples of realisation pairs, seed 0",
        **{f"detector_{name}": text for name, text in detectors.items()},
    )
    return detection


def write_detection(
    store: Store,
    *,
    output: Store | None = None,
    stream=None,
    cnn: CnnSettings | None = None,
    samples: int = 0,
    render_workers: int = 0,
    device: str | None = None,
    train_on=(),
) -> tuple[Store, list[int]]:
    """Run the detection study of `store` and write its dataset.

    Runs one task per positive point on the dask client in use, or on local threads,
    holding the store's writer lock (`service.store.location.Store.lock`): no run writes
    its samples meanwhile, and a second study of it is refused. Every sample read is
    checked as ``info --verify`` checks it, and the labels and coordinates too
    (`service.store.integrity.check_labels`).

    Parameters
    ----------
    store : Store
        The sweep's store.
    output : Store, optional
        Where to write (default `detection_store`); an earlier detection dataset there is
        replaced, anything else is refused.
    stream : file, optional
        Where to show the points scored (`service.progress.Progress`) and the set-up
        phases; None shows nothing.
    cnn : workers.detectors.cnn.CnnSettings, optional
        Train the convolutional detector too with these settings (`service.cnn.add_cnn`;
        needs torch).
    samples : int, optional
        With `cnn`: fresh realisations rendered a training point from the store's sweep
        (`service.stream.SweepStream`, from the sweep's realisations on), trained on
        besides the store's training realisations.
    render_workers : int, optional
        With `samples`: processes that render them (2 or more; else this process).
    device : str, optional
        With `cnn`: where to train and score (``cpu``, ``cuda``, ``cuda:N``; default a GPU
        when there is one).
    train_on : sequence of str, optional
        With `cnn`: ``PATH=VALUE`` selections of the pairs trained on
        (`service.cnn.point_conditions`); every pair is scored.

    Returns
    -------
    target : Store
        Where the dataset was written.
    unpaired : list of int
        Points with a target left out for want of a target-free twin.

    Raises
    ------
    InputError
        A store that cannot be evaluated, or an output that is not a detection dataset;
        `service.errors.LockedError` while another run, ``stats`` or ``detect`` holds
        the store.
    DamagedStoreError
        Naming a sample, or a file of the store, that cannot be read back as written
        (nothing is written then).
    """
    url = store.url
    target = output or detection_store(store)
    if target.url.rstrip("/") in (url.rstrip("/"), store.stats.url):
        raise BadOptionError(
            f"--output {target.url}: that is the sweep's own store or its statistics"
        )
    with store.lock():  # no run writes the samples meanwhile, no other detect the dataset
        training = {
            "samples": samples,
            "render_workers": render_workers,
            "device": device,
            "train_on": tuple(train_on),
        }
        return _write_detection(store, target, stream=stream, cnn=cnn, training=training)


def _write_detection(
    store: Store, target: Store, *, stream, cnn, training
) -> tuple[Store, list[int]]:
    """`write_detection` of `store` to `target`, holding the store's writer lock."""
    url = store.url
    ds = store.dataset()
    check_store(ds, url)
    pairs, unpaired = pair_points(ds)
    if cnn is not None:  # the options checked before any work: imports torch
        from service.cnn import add_cnn, point_conditions, record_training

        conditions = point_conditions(ds, pairs, train_on=training["train_on"])
        fresh = training["samples"] > 0
        why = f"--samples {training['samples']} asks for fresh samples"
        fresh_plan = sweep_plan(ds, url, why=why) if fresh else None
        fresh_backend = written_by(ds.attrs, url) if fresh else None
    # an earlier detection dataset is replaced, anything else refused, before any work
    old = target.removable(DATASET_KIND)
    realisations = int(ds.attrs["realisations"])
    written = written_pairs(store, pairs, realisations)
    if reason := check_labels(store):
        log.warning("%s: labels and coordinates not checked (%s)", url, reason)
    test = held_out(realisations)
    plan = None if "expected" in ds else sweep_plan(ds, url)
    backend = None if plan is None else written_by(ds.attrs, url)
    tasks = [
        dask.delayed(_evaluate)(store, p, q, both, test, plan, backend)
        for (p, q), both in zip(pairs, written, strict=True)
    ]
    how = "reading" if plan is None else "rendering again"
    progress = Progress(
        len(pairs),
        unit="points",
        stream=stream,
        first=f"scoring the first point ({how} the expected images of its samples)",
    )
    try:
        results = compute(tasks, counts=[1] * len(tasks), progress=progress)
    finally:
        progress.close()
    detectors = dict(DETECTORS)
    if cnn is not None:  # one network across the points
        network, trained = add_cnn(
            results,
            store=store,
            pairs=pairs,
            realisations=realisations,
            test=test,
            pfa=PFA,
            settings=cnn,
            conditions=conditions,
            plan=fresh_plan,
            backend=fresh_backend,
            samples=training["samples"],
            workers=training["render_workers"],
            device=training["device"],
            stream=stream,
        )
        detectors |= network
        training |= trained
    with phase("writing the detection dataset", stream=stream):
        detection = _dataset(ds, pairs, results, realisations, test, detectors)
        if cnn is not None:
            record_training(detection, cnn, conditions, training)
        detection.attrs["expected_images"] = (
            "read from the store" if plan is None else "rendered again"
        )
        partial = target.partial(uuid.uuid4().hex[:12])
        try:
            partial.write(detection, mode="w-")
        except BaseException:
            with contextlib.suppress(UnusableOutputError, OSError):  # best effort
                partial.remove(partial.removable(DATASET_KIND))
            raise
        target.remove(old)
        partial.move_to(target)
    return target, unpaired
