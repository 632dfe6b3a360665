"""Statistics of a sweep, per parameter point and gate.

The statistics dataset sits beside the store (`service.store.location.Store.stats`). One
dask task per group of parameter points reads those points' samples and their
target-free twins' (never the whole store), checks each against its checksum
(`service.store.shards.read_verified`: a damaged or lost sample stops the statistics, the
previous ones kept), reduces them over realisations and frames with numpy, and writes its
points' whole chunks of the statistics store. Samples not yet written are ignored. The
noise-free signals come from the per-sample means the render task computed (``target_signal``,
``background_signal``, the target's effect against its target-free twin
``target_effect_relative``), so the store need not keep the noise-free images. After a
resumed run only the points it wrote (and those whose twins it wrote) are recomputed, in
place. Variables:

- ``image_mean``, ``image_std`` (point, gate, y, x): mean and standard deviation images;
- ``target_signal``, ``background_signal`` (point, gate): mean expected (noise-free)
  signal inside the target mask and in a ring of local background around it;
- ``target_contrast`` (point, gate): the mean over samples and frames of each one's
  ``target_effect_relative``, (T − T₀) / T₀ with T₀ the mean of the sample's target-free
  twin over the same mask (`workers.dataset.labels.target_effect`): what the target changes in the
  expected image, before noise; 0 where it changes nothing (a local (T − B) / B would
  also hold the beam's fall-off between the mask and its ring: +0.06 to +0.20 with no
  target in the gate);
- ``cnr`` (point, gate): contrast-to-noise ratio of the noisy images, the mean of each
  sample's and frame's (target − background) over the standard deviation of its background
  ring (shot noise and clutter); a local contrast, so it holds the beam's fall-off between
  mask and ring too;
- ``cnr_without_target`` (point, gate): for a point with a target, the same reading of
  its target-free twin point's noisy images (`twin_points`; realisation by realisation, on
  the same sea) over this point's masks and rings: the CNR that the beam's fall-off, the
  clutter and the noise alone give, to compare ``cnr`` with; NaN for a point without a
  target or without a twin;
- ``visible_fraction`` (point, gate): fraction of samples and frames in which the target
  shows in the gate (``target_visibility`` ``in_gate``: it brightens its mask by at least
  ``target.visibility_threshold``);
- ``samples`` (point): realisations written.

Its attributes ``samples_complete`` and ``samples_total`` say how many samples of the store
the statistics hold (``oceanlidar stats`` refuses an incomplete store without ``--partial``;
`completeness` reads them back for titles).
"""

from __future__ import annotations

import contextlib
import uuid
import warnings

import dask
import numpy as np
import xarray as xr

from service import package_version
from service.errors import UnusableOutputError
from service.progress import Progress, compute
from service.store.layout import CODECS, CONVENTIONS, lazy_array, one_per_chunk, per_shard
from service.store.location import KIND, Store
from service.store.shards import read_verified
from service.store.template import swept_parameters
from workers.dataset.labels import signal_means
from workers.dataset.variables import Visibility

__all__ = [
    "check_computable",
    "check_owner",
    "completeness",
    "create_statistics",
    "point_statistics",
    "statistics_completeness",
    "twin_points",
    "write_statistics",
]

POINTS_PER_TASK = 8

_PER_GATE = {
    "target_signal": "mean expected signal inside the target mask",
    "background_signal": "mean expected signal in the background ring around the mask",
    "target_contrast": "mean over samples and frames of (T - T0) / T0 of the expected images, "
    "T0 the target-free twin's over the same mask",
    "cnr": "mean over samples and frames of (T - B) / sd(B) of the noisy images",
    "cnr_without_target": "cnr of the target-free twin point's noisy images read over this "
    "point's masks, realisation by realisation",
    "visible_fraction": "fraction of samples and frames with the target in_gate",
}


def contrast_to_noise(image, mask):
    """(T − B) / sd(B) of each noisy image: its mask's mean T against its ring's B.

    Parameters
    ----------
    image : ndarray, shape (samples, frames, gates, y, x)
        Noisy images.
    mask : ndarray of bool, shape (samples, frames, y, x)
        The regions read (`workers.dataset.labels.signal_means`: the mask and its ring).

    Returns
    -------
    ndarray, shape (samples, frames, gates)
        NaN where the mask is empty or the ring uniform.
    """
    inside, ring = signal_means(image, mask)
    square = signal_means(image.astype(np.float64) ** 2, mask)[1]
    spread = np.sqrt(np.maximum(square - ring**2, 0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # NaN where nothing is read
        return (inside - ring) / np.where(spread > 0, spread, np.nan)


def point_statistics(image, target, background, mask, relative, visibility):
    """The statistics of one parameter point from its written samples.

    Parameters
    ----------
    image : ndarray, shape (samples, frames, gates, y, x)
        Noisy images.
    target, background : ndarray, shape (samples, frames, gates)
        Mean noise-free signal inside the target mask and in the ring around it
        (`workers.dataset.labels.signal_means`), NaN where the region is empty.
    mask : ndarray of bool, shape (samples, frames, y, x)
        Pixels whose ray meets the target.
    relative : ndarray, shape (samples, frames, gates)
        The relative change the target makes over its mask against the sample's
        target-free twin (``target_effect_relative``), NaN where the mask is empty.
    visibility : ndarray, shape (samples, frames, gates)
        What the target shows in each gate (``target_visibility``; 1: ``in_gate``).

    Returns
    -------
    dict of ndarray
        ``image_mean``, ``image_std`` (gates, y, x) and the (gates,) entries of
        `_PER_GATE` but ``cnr_without_target`` (`twin_cnr`), float32; NaN where undefined
        (no target, fewer than two samples).
    """
    n = image.shape[0] * image.shape[1]
    flat = image.reshape(n, *image.shape[2:]).astype(np.float64)
    stats = {
        "image_mean": flat.mean(axis=0) if n else np.full(image.shape[2:], np.nan),
        "image_std": flat.std(axis=0, ddof=1) if n > 1 else np.full(image.shape[2:], np.nan),
    }
    target = target.astype(np.float64)
    background = background.astype(np.float64)
    with warnings.catch_warnings():
        # no target, or no background ring: those entries are NaN by design
        warnings.simplefilter("ignore", RuntimeWarning)
        per_gate = {
            "target_signal": np.nanmean(target, axis=(0, 1)),
            "background_signal": np.nanmean(background, axis=(0, 1)),
            "target_contrast": np.nanmean(relative.astype(np.float64), axis=(0, 1)),
            "cnr": np.nanmean(contrast_to_noise(image, mask), axis=(0, 1)),
            "visible_fraction": (visibility == Visibility.in_gate).mean(axis=(0, 1)),
        }
    stats.update(per_gate)
    return {name: np.asarray(value, dtype=np.float32) for name, value in stats.items()}


def completeness(done: int, total: int) -> str:
    """``"96 of 2400 samples (4 %)"``: how complete a store, or its statistics, is.

    The percentage is rounded, but never to 0 % with a sample written nor to 100 % with one
    missing.
    """
    percent = 100 * done / total if total else 0.0
    shown = f"{percent:.0f}"
    if 0 < percent < 1:
        shown = "< 1"
    elif 99 < percent < 100:
        shown = "> 99"
    return f"{done} of {total} samples ({shown} %)"


def statistics_completeness(stats: xr.Dataset) -> str:
    """How complete the statistics dataset `stats` is (`completeness`), from its record.

    Statistics written before their attributes recorded it say how many samples they hold.
    """
    done = int(stats["samples"].sum())
    total = stats.attrs.get("samples_total")
    return completeness(done, int(total)) if total else f"{done} samples"


def twin_cnr(twin, mask) -> np.ndarray:
    """``cnr_without_target``: the mean `contrast_to_noise` of a twin's images over `mask`.

    Parameters
    ----------
    twin : ndarray, shape (pairs, frames, gates, y, x)
        Noisy images of a point's target-free twin, realisation by realisation.
    mask : ndarray of bool, shape (pairs, frames, y, x)
        The point's masks in the same realisations.

    Returns
    -------
    ndarray of float32, shape (gates,)
        NaN where nothing is read (no pair, an empty mask).
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # no pair: NaN by design
        return np.nanmean(contrast_to_noise(twin, mask), axis=(0, 1)).astype(np.float32)


def twin_points(ds: xr.Dataset) -> np.ndarray:
    """Each point's target-free twin: the point of the same scene without a target.

    A point without a target matches a point with one when every swept parameter outside
    ``target.`` is equal (without a target, the target's parameters change nothing); of
    several matches, one equal in every parameter but ``target.shape`` is preferred, then
    the first. Their samples of one realisation share the sea.

    Parameters
    ----------
    ds : xarray.Dataset
        A samples store (its ``target_present`` label and swept coordinates).

    Returns
    -------
    ndarray of int, shape (points,)
        The twin of each point with a target; -1 for a point without a target or twin.
    """
    realisations = int(ds.attrs["realisations"])
    present = ds["target_present"].values[::realisations].astype(bool)
    first = np.arange(present.size) * realisations
    values = {path: ds[name].values[first].tolist() for name, path in swept_parameters(ds).items()}
    scene_keys = [path for path in values if not path.startswith("target.")]
    near_keys = [path for path in values if path != "target.shape"]

    def key(point: int, paths: list[str]) -> tuple:
        return tuple(values[path][point] for path in paths)

    matches, exact = {}, {}  # the first target-free point of each scene, and of each near key
    for point in np.flatnonzero(~present).tolist():
        matches.setdefault(key(point, scene_keys), point)
        exact.setdefault(key(point, near_keys), point)
    twins = np.full(present.size, -1)
    for point in np.flatnonzero(present).tolist():
        twins[point] = exact.get(key(point, near_keys), matches.get(key(point, scene_keys), -1))
    return twins


def _template(ds: xr.Dataset, source: Store, done: int) -> xr.Dataset:
    points = int(ds.attrs["points"])
    realisations = int(ds.attrs["realisations"])
    gates, ny, nx = ds.sizes["gate"], ds.sizes["y"], ds.sizes["x"]
    units = ds["image"].attrs.get("units", "1")
    signal_units = ds["target_signal"].attrs.get("units", "1")
    data_vars = {
        "image_mean": (
            ("point", "gate", "y", "x"),
            lazy_array((points, gates, ny, nx), np.nan, np.float32),
            {"long_name": "mean image over realisations and frames", "units": units},
        ),
        "image_std": (
            ("point", "gate", "y", "x"),
            lazy_array((points, gates, ny, nx), np.nan, np.float32),
            {"long_name": "standard deviation image over realisations and frames", "units": units},
        ),
        "samples": (
            ("point",),
            lazy_array((points,), 0, np.int32),
            {"long_name": "realisations written", "units": "1"},
        ),
    }
    for name, long_name in _PER_GATE.items():
        data_vars[name] = (
            ("point", "gate"),
            lazy_array((points, gates), np.nan, np.float32),
            {"long_name": long_name, "units": signal_units if "signal" in name else "1"},
        )
    first = np.arange(points) * realisations
    coords = {
        "point": (
            "point",
            np.arange(points),
            {"long_name": "parameter point index", "units": "1"},
        ),
        "gate": ds["gate"],
        "gate_top": ds["gate_top"].load(),
        "gate_bottom": ds["gate_bottom"].load(),
    }
    for name, coord in ds.coords.items():
        if coord.dims == ("sample",) and name not in ("point", "realisation"):
            coords[name] = ("point", coord.values[first], dict(coord.attrs))
    stats = xr.Dataset(data_vars, coords=coords)
    stats.attrs.update(
        title=ds.attrs.get("title", "") + " statistics",
        Conventions=CONVENTIONS,
        source=f"oceanlidar {package_version()}",
        history=f"oceanlidar {package_version()} statistics of {source.name}",
        sweep_sha256=ds.attrs.get("sweep_sha256", ""),
        samples_store=source.name,
        samples_complete=done,
        samples_total=points * realisations,
        oceanlidar_version=package_version(),
        **{KIND: "statistics"},
    )
    return stats


def _reduce_points(source: Store, target: Store, points, done, twins, twin_done) -> dict:
    """Read the samples of `points` (and their twins'), reduce them, write their chunks.

    `done` holds the completion flags of those points' samples (points, realisations);
    `twins` each point's target-free twin (`twin_points`, -1 for none) and `twin_done`
    the twin's flags (all False for none). Returns the samples each point's statistics
    were computed from (``point: count``, the points with any), which `_reduce_all`
    records once every task has written.
    """
    samples, sink = source.group(), target.group("r+")
    realisations = done.shape[1]
    starts = np.asarray(points)[:, np.newaxis] * realisations
    picks = (starts + np.arange(realisations))[done]
    if picks.size == 0:
        return {}
    # all the points' samples at once (consecutive points are one slice of the store),
    # every rendered array, to check each sample against its checksum
    read = read_verified(samples, picks.tolist())
    owner = np.repeat(np.arange(len(points)), done.sum(axis=1))
    counts = {}
    for index, point in enumerate(points):
        mine = owner == index
        if not mine.any():
            continue
        stats = point_statistics(
            image=read["image"][mine],
            target=read["target_signal"][mine],
            background=read["background_signal"][mine],
            mask=read["target_mask"][mine].astype(bool),
            relative=read["target_effect_relative"][mine],
            visibility=read["target_visibility"][mine],
        )
        twin, shape = twins[index], read["image"].shape[1:]
        both = done[index] & twin_done[index]
        paired = both[done[index]]  # the point's samples read whose twin sample is written
        twin_image = np.zeros((0, *shape), read["image"].dtype)
        if both.any():
            twin_image = read_verified(
                samples, (twin * realisations + np.flatnonzero(both)).tolist()
            )["image"]
        mask = read["target_mask"][mine][paired].astype(bool)
        stats["cnr_without_target"] = twin_cnr(twin_image, mask)
        for name, value in stats.items():
            sink[name][point] = value
        counts[point] = int(mine.sum())
    return counts


def write_statistics(
    store: Store,
    *,
    points: np.ndarray | None = None,
    stream=None,
    completed: np.ndarray | None = None,
) -> Store:
    """(Re)compute the statistics of `store` and write them beside it (`Store.stats`).

    With `points` (after a resumed run: the points whose samples it wrote), only those
    points (and any whose statistics count other samples than the store holds) are
    recomputed, in place, if sound statistics of this sweep are there (else everything
    is). Otherwise new statistics are written to a fresh store beside the old
    ones and moved into place only when complete: a failure leaves the previous statistics
    as they were. The caller holds the sample store's writer lock (`Store.lock`). Runs on
    the dask client in use (the sweep's cluster), or on local threads. `stream` shows the
    points done (`service.progress.Progress`); None shows nothing. `completed`: the
    store's completion flags, if the caller has read them (`Store.completed_after`).

    Returns
    -------
    Store
        Where the statistics were written.

    Raises
    ------
    UnusableOutputError
        If the statistics path holds something other than oceanlidar statistics, or the
        statistics of another store (`check_owner`), or the store predates the target's
        effect.
    DamagedStoreError
        Naming a sample marked complete that cannot be read back as its checksum says.
    """
    ds = check_computable(store)
    target = store.stats
    done = store.completed() if completed is None else completed
    recorded = None if points is None else _recorded(ds.attrs, store)
    if recorded is not None:
        # the run's points, and any whose statistics count other samples than are written
        stale = recorded != done.reshape(recorded.size, -1).sum(axis=1)
        update = np.union1d(np.asarray(points, dtype=int), np.flatnonzero(stale))
        if update.size:
            twins = twin_points(ds)  # a point's cnr_without_target reads its twin's samples
            update = np.union1d(update, np.flatnonzero(np.isin(twins, update) & (twins >= 0)))
            _reduce_all(ds, store, target, update.tolist(), stream=stream, completed=done)
        if update.size or (target.attributes() or {}).get("samples_complete") != done.sum():
            # also after an update stopped between its counts and this record
            target.update_attributes(samples_complete=int(done.sum()))
        return target
    old = target.removable("statistics")
    partial = target.partial(uuid.uuid4().hex[:12])
    try:
        _compute(ds, store, partial, int(done.sum()), stream=stream)
    except BaseException:
        with contextlib.suppress(UnusableOutputError, OSError):  # best effort: not in place
            partial.remove(partial.removable("statistics"))
        raise
    target.remove(old)
    partial.move_to(target)
    return target


def check_computable(store: Store) -> xr.Dataset:
    """The samples store `store`, opened, if statistics can be written beside it.

    Raises
    ------
    UnusableOutputError
        As `check_owner` does, or if the store predates the target's effect.
    """
    check_owner(store)
    ds = store.dataset()
    if "target_effect_relative" not in ds:
        raise UnusableOutputError(
            f"{store.url} has no target_effect_relative (written before it was stored, issue "
            "#24): its statistics cannot be computed; run the sweep again with --overwrite"
        )
    return ds


def check_owner(store: Store) -> None:
    """Refuse to write statistics beside `store` over those of another samples store.

    Two outputs share one statistics path (``run`` and ``run.zarr`` in one folder:
    `service.store.location.Store.stats`). Statistics record the name of the store they were
    computed from (attribute ``samples_store``, its last path component, beside
    ``sweep_sha256``), so that a store and its statistics copied or moved together stay
    a pair; those of another store that is still beside them are never replaced.

    Parameters
    ----------
    store : Store
        The samples store, normalised (`service.store.location.Store.at`).

    Raises
    ------
    UnusableOutputError
        If the statistics path holds the statistics of another samples store there.
    """
    target = store.stats
    attributes = target.attributes() or {}
    owner, name = attributes.get("samples_store"), store.name
    if attributes.get(KIND) != "statistics" or owner in (None, name):
        return
    other = store.other(store.url.rstrip("/")[: -len(name)] + str(owner))
    if other.kind() == "samples":
        remedy = (
            "write this sweep to another output"
            if other.stats == target  # "one" and "one.zarr" share statistics
            else f"delete {target.url}, a copy: {other.url}'s are {other.stats.url}"
        )
        raise UnusableOutputError(
            f"{target.url} holds the statistics of another store, {other.url}, which the "
            f"statistics of {store.url} would replace; {remedy}"
        )


def _recorded(source: dict, store: Store):
    """Samples per point that the statistics beside `store` were computed from.

    None unless they are statistics of the store at `store` whose attributes are `source`
    (by its name and its sweep's hash), of this version, with every variable and a
    readable ``samples`` array (their images are not read; ``samples`` is one chunk, read
    at once, in statistics written since issue #26 item 8, one chunk a point before).
    """
    attributes = store.stats.attributes() or {}
    if (
        attributes.get(KIND) != "statistics"
        or attributes.get("samples_store") != store.name
        or attributes.get("sweep_sha256") != source.get("sweep_sha256")
        or attributes.get("oceanlidar_version") != package_version()
    ):
        return None
    try:
        group = store.stats.group()
        if not {"image_mean", "image_std", "samples", *_PER_GATE} <= set(group.array_keys()):
            return None
        counts = group["samples"][:]
    except Exception:
        return None
    return counts if counts.shape == (int(source["points"]),) else None


def create_statistics(ds: xr.Dataset, source: Store, target: Store, done: int) -> None:
    """Write the template of the statistics of `ds` (the store `source`) at `target`.

    `done` is the number of its samples written. Nothing computed: every statistic at its
    fill value, ``samples`` 0. One chunk a point (the tasks write their points' chunks),
    but ``samples`` one chunk, written once by `_reduce_all` and read at once (`_recorded`).
    """
    template = _template(ds, source, done)
    encoding = {
        **{name: {"compressors": CODECS} for name in template.coords},
        **{name: one_per_chunk(template[name].shape[1:]) for name in template},
        "samples": per_shard((), template.sizes["point"]),
    }
    target.write(template, mode="w-", compute=False, encoding=encoding)


def _compute(ds: xr.Dataset, source: Store, target: Store, done: int, *, stream=None) -> None:
    """Write the statistics of `ds` (the store `source`, `done` samples written) at `target`.

    `stream` shows the points done; None shows nothing.
    """
    create_statistics(ds, source, target, done)
    _reduce_all(ds, source, target, list(range(int(ds.attrs["points"]))), stream=stream)


def _reduce_all(
    ds: xr.Dataset,
    source: Store,
    target: Store,
    points: list[int],
    *,
    stream=None,
    completed: np.ndarray | None = None,
):
    """Compute the statistics of `points` into the statistics store at `target`.

    Each task writes its points' statistics; then the samples each point counts
    (``samples``, one chunk) are written, once, here: an interrupted update leaves the old
    counts, which the next resumed run finds stale (`write_statistics`). `stream` shows
    the points done; None shows nothing. `completed`: the source's completion flags, if
    already read.
    """
    if not points:  # a resume that wrote nothing, its statistics sound: nothing to read
        return
    flags = source.completed() if completed is None else completed
    flags = flags.reshape(-1, int(ds.attrs["realisations"]))
    twins = twin_points(ds)
    starts = range(0, len(points), POINTS_PER_TASK)
    tasks = [
        dask.delayed(_reduce_points)(
            source,
            target,
            group,
            flags[group],
            twins[group],
            flags[np.maximum(twins[group], 0)] & (twins[group] >= 0)[:, np.newaxis],
        )
        for group in (points[start : start + POINTS_PER_TASK] for start in starts)
    ]
    groups = [len(points[start : start + POINTS_PER_TASK]) for start in starts]
    progress = Progress(len(points), unit="points", stream=stream)
    try:
        results = compute(tasks, counts=groups, progress=progress)
    finally:
        progress.close()
    counts = {point: n for done in results for point, n in done.items()}
    if counts:
        samples = target.group("r+")["samples"]
        samples.set_orthogonal_selection((list(counts),), list(counts.values()))
