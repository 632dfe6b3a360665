"""What a detection study checks of a store before it scores anything.

`check_store`: the store holds a sweep's photoelectron counts and enough realisations;
`pair_points`: each point with a target paired with its target-free twin;
`written_pairs`: each pair's realisations written at both points; `sweep_plan`: the
store's sweep read again, to render the expected images a store without them lacks.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from service.errors import BadSweepError, InputError
from service.stats import twin_points
from service.store.location import Store
from service.sweep import parse_sweep

MIN_REALISATIONS = 8
"""Fewest realisations per point: half train the logistic detector, half test it."""


def pair_points(ds: xr.Dataset) -> tuple[list[tuple[int, int]], list[int]]:
    """Pair each point with a target with the target-free point of the same scene.

    The twins are `service.stats.twin_points`'s (also those the statistics read).

    Returns
    -------
    pairs : list of (int, int)
        (positive point, negative point) indices in the store.
    unpaired : list of int
        Points with a target and no target-free twin.

    Raises
    ------
    BadSweepError
        When no point has a target, or none is target-free (nothing to evaluate).
    """
    realisations = int(ds.attrs["realisations"])
    present = ds["target_present"].values[::realisations].astype(bool)
    if not present.any():
        raise BadSweepError("no parameter point has a target: there is nothing to detect")
    if present.all():
        raise BadSweepError(
            "no parameter point is target-free, so there are no negatives to evaluate "
            "detectors against; sweep target.shape: [sphere, none] (or disk) to pair them"
        )
    twins = twin_points(ds)
    positives = np.flatnonzero(present).tolist()
    pairs = [(point, int(twins[point])) for point in positives if twins[point] >= 0]
    unpaired = [point for point in positives if twins[point] < 0]
    if not pairs:
        raise BadSweepError(
            "no point with a target has a target-free twin (equal in every swept parameter "
            "outside target.): sweep target.shape: [sphere, none] on a grid to pair them"
        )
    return pairs, unpaired


def written_pairs(store: Store, pairs, realisations: int) -> list[np.ndarray]:
    """Each pair's realisations written at both points, before any is scored.

    Raises
    ------
    BadSweepError
        If a pair has fewer than `MIN_REALISATIONS` (nothing is scored then).
    """
    done = store.completed().reshape(-1, realisations)
    written = []
    for positive, negative in pairs:
        both = done[positive] & done[negative]
        if both.sum() < MIN_REALISATIONS:
            raise BadSweepError(
                f"points {positive} and {negative}: {both.sum()} realisations written at both, "
                f"fewer than {MIN_REALISATIONS}; complete the run with `oceanlidar run --resume`"
            )
        written.append(both)
    return written


def check_store(ds: xr.Dataset, url: str) -> None:
    """Refuse a store a study cannot read: no images, not counts, too few realisations."""
    for name in ("image", "completed", "target_present"):
        if name not in ds:
            raise BadSweepError(f"{url}: the store has no {name!r}: not a sweep's store")
    if ds["image"].dtype.kind != "u":
        raise BadSweepError(
            f"{url}: images are {ds['image'].attrs.get('long_name')!r}, not photoelectrons: "
            "detection needs shot noise with no gain (radiometry with photons, noise.gain 1)"
        )
    if int(ds.attrs["realisations"]) < MIN_REALISATIONS:
        raise BadSweepError(
            f"{url}: {ds.attrs['realisations']} realisations per point; detection needs at "
            f"least {MIN_REALISATIONS} (half train the logistic detector, half test it)"
        )


def sweep_plan(ds: xr.Dataset, url: str, *, why: str = "the store has no 'expected' images"):
    """The store's sweep, read again from its text, to render samples again.

    `why` says in an error what the renders are for.
    """
    try:
        plan = parse_sweep(ds.attrs["sweep"])
    except InputError as error:
        raise type(error)(
            f"{url}: {why}, and its sweep cannot be read again to render them: {error}"
        ) from None
    if plan.digest != ds.attrs.get("sweep_sha256"):
        raise BadSweepError(
            f"{url}: {why}, and its sweep reads differently now (another oceanlidar "
            "version?): they cannot be rendered"
        )
    return plan
