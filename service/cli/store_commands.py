"""The store's commands: ``info``, ``stats``, ``detect``, ``preview`` and ``plot``.

Each takes the parsed arguments (`service.cli.parser`) and returns an exit code; bad input
is raised as a `service.errors.InputError`, a damaged store as
`service.integrity.DamagedStoreError`, both reported by `service.cli.main`.
"""

from __future__ import annotations

import logging
import os

from service import integrity, lock, storage, store
from service.errors import BadOptionError, InputError, UnusableOutputError
from service.inputs import shown
from service.sweep import load_sweep, parse_sweep

__all__ = ["cmd_detect", "cmd_info", "cmd_plot", "cmd_preview", "cmd_stats"]

log = logging.getLogger("oceanlidar")

EXIT_OK, EXIT_FAILURE = 0, 1
SHOWN_PROBLEMS = 20
"""Most samples listed one per line in a report; the rest are counted."""


def _print_problems(what: str, problems: list) -> None:
    """One line per damaged sample (at most `SHOWN_PROBLEMS`), then a count."""
    for sample, reason in problems[:SHOWN_PROBLEMS]:
        print(f"  sample {sample}: {what}: {reason}")
    if len(problems) > SHOWN_PROBLEMS:
        print(f"  ... and {len(problems) - SHOWN_PROBLEMS} more samples")


def _open(url: str, storage_options: dict | None):
    """The samples store at `url` (normalised), opened lazily.

    Raises
    ------
    UnusableOutputError
        If nothing, or not an oceanlidar samples store, is there.
    """
    if not storage.store_exists(url, storage_options):
        raise UnusableOutputError(f"{url}: no store there")
    attributes = storage.root_attributes(url, storage_options) or {}
    if attributes.get(storage.KIND) != "samples":
        raise UnusableOutputError(f"{url}: not an oceanlidar samples store")
    try:
        return store.open_store(url, storage_options=storage_options)
    except Exception as error:
        raise UnusableOutputError(f"{url}: not an oceanlidar store ({error})") from None


def _statistics(url: str, storage_options: dict | None) -> str | None:
    """The statistics store beside `url`, if one of this store is there."""
    stats = storage.stats_url(url)
    attributes = storage.root_attributes(stats, storage_options) or {}
    ours = attributes.get("samples_store") in (None, storage.store_name(url))
    if attributes.get(storage.KIND) != "statistics" or not ours:
        return None  # none, or another store's (copied here, or of "one" beside "one.zarr")
    return stats


def cmd_info(args) -> int:
    """What a store holds and how complete it is; ``--verify`` reads every sample back."""
    url = storage.normalise(args.store, args.storage_options)
    ds = _open(url, args.storage_options)
    done = int(integrity.completed_samples(url, storage_options=args.storage_options).sum())
    total = ds.sizes["sample"]
    swept = [f"{name} ({path})" for name, path in store.swept_parameters(ds).items()]
    print(f"{url}: {ds.attrs.get('title', '')}")
    print(f"  samples: {done}/{total} complete ({100 * done / max(total, 1):.1f} %)")
    print(f"  points: {ds.attrs.get('points')}  realisations: {ds.attrs.get('realisations')}")
    print("  dimensions: " + ", ".join(f"{k}={v}" for k, v in ds.sizes.items()))
    print("  variables: " + ", ".join(map(str, ds.data_vars)))
    print(f"  swept: {', '.join(map(str, swept)) or '(nothing)'}")
    print(f"  sweep sha256: {ds.attrs.get('sweep_sha256')}")
    print(f"  written by: oceanlidar {ds.attrs.get('oceanlidar_version')}")
    print(f"  statistics: {_statistics(url, args.storage_options) or '(none)'}")
    if not args.verify:
        return EXIT_OK
    problems = integrity.verify(url, args.storage_options)
    print(f"  verified: {done - len(problems)} of {done} complete samples read back intact")
    _print_problems("damaged or missing", problems)
    labels = _label_problems(url, ds, args.storage_options)
    if problems or "lost" in labels.values():
        print("  run the sweep again with --resume --verify to recompute them")
    return EXIT_FAILURE if problems or labels else EXIT_OK


def _label_problems(url: str, ds, storage_options: dict | None) -> dict:
    """Print and return `service.integrity.wrong_labels` of the store, if its sweep loads."""
    try:
        plan = parse_sweep(ds.attrs["sweep"], max_memory=None)
    except InputError as error:  # e.g. a measurement file the sweep names is not here
        print(f"  labels and coordinates: not checked (its sweep does not load here: {error})")
        return {}
    if plan.digest != ds.attrs.get("sweep_sha256"):  # a measurement file changed since
        print("  labels and coordinates: not checked (its sweep reads other files here)")
        return {}
    labels = integrity.wrong_labels(url, plan, storage_options)
    lost = ", ".join(name for name, kind in labels.items() if kind == "lost") or "none"
    print(f"  labels and coordinates lost or unreadable: {lost}")
    if differing := [name for name, kind in labels.items() if kind == "differs"]:
        print(
            f"  labels and coordinates not as this installation computes them: "
            f"{', '.join(differing)} (another numpy or scipy version?)"
        )
    return labels


def cmd_stats(args) -> int:
    """(Re)compute a store's statistics, holding its writer lock."""
    from service.stats import write_statistics

    url = storage.normalise(args.store, args.storage_options)
    _open(url, args.storage_options)
    with lock.writer_lock(url, args.storage_options):
        print(write_statistics(url, storage_options=args.storage_options))
    return EXIT_OK


def cmd_detect(args) -> int:
    """The detection study of a store (`service.detect`)."""
    from service.detect import write_detection

    url = storage.normalise(args.store, args.storage_options)
    _open(url, args.storage_options)
    target, unpaired = write_detection(
        url, output=args.output, storage_options=args.storage_options
    )
    if unpaired:
        log.warning("points with no target-free twin, left out: %s", unpaired)
    print(target)
    return EXIT_OK


def _stored_sample(url: str, sample: int, storage_options: dict | None):
    """Sample `sample` of a store, loaded, and its title; refused if not written."""
    ds = _open(url, storage_options)
    total = ds.sizes["sample"]
    if not 0 <= sample < total:
        raise BadOptionError(f"--sample {sample}: the store has samples 0..{total - 1}")
    if not integrity.completed_samples(url, storage_options=storage_options)[sample]:
        raise BadOptionError(f"--sample {sample}: not written yet in {url} (resume its run)")
    one = ds.isel(sample=sample).load()
    values = ", ".join(
        f"{path}={shown(one[name].values.item())}"
        for name, path in store.swept_parameters(ds).items()
    )
    where = f"point {int(one['point'])}" + (f": {values}" if values else "")
    name = ds.attrs.get("title", url)
    return one, f"{name}, sample {sample} ({where}; realisation {int(one['realisation'])})"


def cmd_preview(args) -> int:
    """Draw a sample: rendered now from a sweep file, or read from a store."""
    from service.plots import render_preview, save_preview

    if os.path.isfile(args.source):
        plan = load_sweep(args.source)
        address = plan.sample(args.sample)
        ds = render_preview(plan, args.sample)
        title = f"{plan.sweep.name}, {address.describe()}"
        measurements = address.scene.surface.conditioning.points
    else:
        url = storage.normalise(args.source, args.storage_options)
        ds, title = _stored_sample(url, args.sample, args.storage_options)
        measurements = None
    frames = save_preview(
        ds,
        args.output,
        frame=args.frame,
        shared_scale=args.shared_scale,
        title=title,
        measurements=measurements,
    )
    log.info("%s: %d frame(s)", args.output, frames)
    return EXIT_OK


def cmd_plot(args) -> int:
    """Plot a store's statistics, or a detection dataset."""
    from service.detect import DATASET_KIND
    from service.plots import plot_detection, plot_statistics

    url = storage.normalise(args.store, args.storage_options)
    attributes = storage.root_attributes(url, args.storage_options) or {}
    if attributes.get(storage.KIND) == DATASET_KIND:
        detection = store.open_store(url, storage_options=args.storage_options)
        plot_detection(detection, args.output)
        log.info("%s", args.output)
        return EXIT_OK
    _open(url, args.storage_options)
    stats_path = _statistics(url, args.storage_options)
    if stats_path is None:
        raise UnusableOutputError(f"{url}: no statistics yet; run `oceanlidar stats` first")
    stats = store.open_store(stats_path, storage_options=args.storage_options)
    try:
        stats = stats.load()  # small: per point and gate
    except Exception as error:
        raise integrity.DamagedStoreError(
            f"{stats_path}: a chunk cannot be read ({type(error).__name__}); run "
            f"`oceanlidar stats {url}` to write the statistics again"
        ) from None
    plot_statistics(stats, args.output)
    log.info("%s", args.output)
    return EXIT_OK
