"""The store's commands: ``info``, ``stats``, ``detect``, ``preview``, ``plot`` and ``check``.

``preview`` and ``check`` render from a sweep file too; ``check`` never opens a store.

Each takes the parsed arguments (`service.cli.parser`) and returns an exit code; bad input
is raised as a `service.errors.InputError`, a damaged store as
`service.errors.DamagedStoreError`, both reported by `service.cli.main`. Each builds the
store's `service.store.location.Store` once from its arguments (`_store`).
"""

from __future__ import annotations

import contextlib
import functools
import logging
import os
import sys

import numpy as np

from service.devices import BACKEND_ATTR, DEVICE_ATTR, check_renderers, choose, stored
from service.errors import BadOptionError, DamagedStoreError, InputError, UnusableOutputError
from service.inputs import shown
from service.store import integrity
from service.store.location import KIND, Store
from service.store.shards import CHECKSUMS, checks_identity
from service.store.template import swept_parameters
from service.sweep import load_sweep

__all__ = ["cmd_check", "cmd_detect", "cmd_info", "cmd_plot", "cmd_preview", "cmd_stats"]

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


def _progress(args):
    """Where a command shows its progress: stderr, or nowhere with ``--quiet``."""
    return None if args.quiet else sys.stderr


def _store(args, url: str) -> Store:
    """The store the command names (normalised), with its ``--storage-options``."""
    return Store.at(url, args.storage_options)


def _open(store: Store):
    """The samples store, opened lazily without dask (no graph that grows with its samples).

    Raises
    ------
    UnusableOutputError
        If nothing, or not an oceanlidar samples store, is there.
    """
    url = store.url
    if not store.exists():
        raise UnusableOutputError(f"{url}: no store there")
    if store.kind() != "samples":
        raise UnusableOutputError(f"{url}: not an oceanlidar samples store")
    try:
        return store.dataset(dask=False)
    except InputError:  # a store, refused as it is (gates numbered from 0)
        raise
    except Exception as error:
        raise UnusableOutputError(f"{url}: not an oceanlidar store ({error})") from None


def _statistics(store: Store) -> Store | None:
    """The statistics store beside `store`, if one of this store is there."""
    attributes = store.stats.attributes() or {}
    ours = attributes.get("samples_store") in (None, store.name)
    if attributes.get(KIND) != "statistics" or not ours:
        return None  # none, or another store's (copied here, or of "one" beside "one.zarr")
    return store.stats


def cmd_info(args) -> int:
    """What a store holds and how complete it is; ``--verify`` reads every sample back."""
    store = _store(args, args.store)
    url = store.url
    ds = _open(store)
    done = int(store.completed().sum())
    total = ds.sizes["sample"]
    swept = [f"{name} ({path})" for name, path in swept_parameters(ds).items()]
    print(f"{url}: {ds.attrs.get('title', '')}")
    print(f"  samples: {done}/{total} complete ({100 * done / max(total, 1):.1f} %)")
    print(f"  points: {ds.attrs.get('points')}  realisations: {ds.attrs.get('realisations')}")
    print("  dimensions: " + ", ".join(f"{k}={v}" for k, v in ds.sizes.items()))
    print("  variables: " + ", ".join(map(str, ds.data_vars)))
    print(f"  swept: {', '.join(map(str, swept)) or '(nothing)'}")
    print(f"  sweep sha256: {ds.attrs.get('sweep_sha256')}")
    print(f"  written by: oceanlidar {ds.attrs.get('oceanlidar_version')}")
    rendered = stored(ds.attrs)
    print(f"  rendered on: backend {rendered[BACKEND_ATTR]}, device {rendered[DEVICE_ATTR]}")
    stats = _statistics(store)
    print(f"  statistics: {stats.url if stats else '(none)'}")
    if not args.verify:
        return EXIT_OK
    group = store.group()
    for name in ("completed", *CHECKSUMS):  # every record readable, or named (exit 1)
        if name in group:
            store.records(name, group=group)
    problems = integrity.verify(store)
    print(f"  verified: {done - len(problems)} of {done} complete samples read back intact")
    if not checks_identity(store.group()):
        print(
            "  its checksums (written before issue #37) do not cover which sample they "
            "are: a shard's files swapped with another's, or copied from another store, "
            "pass them; write the sweep again for that check"
        )
    _print_problems("damaged or missing", problems)
    unflagged = integrity.unflagged(store)
    reason = "its checksum is stored but its completion flag lost (or a run stopped writing it)"
    _print_problems("not counted complete", [(sample, reason) for sample in unflagged])
    labels = _label_problems(store)
    if problems or unflagged or "lost" in labels.values():
        print("  run the sweep again with --resume --verify to recompute them")
    return EXIT_FAILURE if problems or unflagged or labels else EXIT_OK


def _label_problems(store: Store) -> dict:
    """Print and return `service.store.integrity.wrong_labels` of the store, if its sweep loads."""
    plan, reason = integrity.stored_plan(store)
    if plan is None:  # e.g. a measurement file the sweep names is not here, or changed
        print(f"  labels and coordinates: not checked ({reason})")
        return {}
    labels = integrity.wrong_labels(store, plan)
    lost = ", ".join(name for name, kind in labels.items() if kind == "lost") or "none"
    print(f"  labels and coordinates lost or unreadable: {lost}")
    if differing := [name for name, kind in labels.items() if kind == "differs"]:
        print(
            f"  labels and coordinates not as this installation computes them: "
            f"{', '.join(differing)} (another numpy or scipy version?)"
        )
    return labels


def cmd_stats(args) -> int:
    """(Re)compute a store's statistics, holding its writer lock.

    The labels and coordinates are compared with the store's sweep first
    (`service.store.integrity.check_labels`, as ``info --verify`` compares them), and every
    sample read is checked against its checksum (`service.stats.write_statistics`).

    An incomplete store is refused (exit 2) unless ``--partial`` asks for the statistics of
    the samples written; those record how complete they are and say it.
    """
    from service.stats import check_computable, completeness, write_statistics

    store = _store(args, args.store)
    total = _open(store).sizes["sample"]
    with store.lock():
        check_computable(store)  # what cannot be computed at all is said first
        if reason := integrity.check_labels(store):  # a sample's checksum does not cover them
            log.warning("%s: labels and coordinates not checked (%s)", store.url, reason)
        done = int(store.completed().sum())
        if done < total and not args.partial:
            raise BadOptionError(
                f"{store.url}: {completeness(done, total)} are complete; statistics of an "
                "incomplete store are refused: complete it (`oceanlidar run SWEEP --resume`) "
                "or give --partial for the statistics of the samples written"
            )
        print(write_statistics(store, stream=_progress(args)).url)
    if done < total:
        print(f"  partial: the statistics of {completeness(done, total)}")
    return EXIT_OK


def cmd_detect(args) -> int:
    """The detection study of a store (`service.detect`); ``--workers``: on processes."""
    from service.cluster import dask_client
    from service.detect import write_detection
    from service.progress import phase

    if args.workers is not None and args.workers < 1:
        raise BadOptionError("--workers must be at least 1")
    cnn, device = _cnn_settings(args)
    store = _store(args, args.store)
    _open(store)
    output = store.other(args.output) if args.output else None
    stream = _progress(args)
    with contextlib.ExitStack() as cluster:
        if args.workers is not None:
            plural = "s" if args.workers > 1 else ""
            with phase(
                f"starting the local cluster ({args.workers} worker{plural})", stream=stream
            ):
                cluster.enter_context(
                    dask_client(workers=args.workers, scheduler=None, verbose=args.verbose > 0)
                )
        target, unpaired = write_detection(
            store,
            output=output,
            stream=stream,
            cnn=cnn,
            samples=args.samples or 0,
            render_workers=args.workers or 0,
            device=device,
            train_on=args.train_on or (),
        )
    if unpaired:
        log.warning("points with no target-free twin, left out: %s", unpaired)
    print(target.url)
    return EXIT_OK


TRAINING_OPTIONS = ("epochs", "samples", "batch_size", "device", "seed", "train_on")
"""``detect``'s options of the trained network, refused without ``--cnn``."""


def _cnn_settings(args):
    """The trained network's settings and device from ``--cnn`` and its options.

    Returns (None, None) without ``--cnn``. Raises `BadOptionError` naming the option: one
    given without ``--cnn``, torch missing, a ``--device`` that is not here.
    """
    given = [name for name in TRAINING_OPTIONS if getattr(args, name) is not None]
    if not args.cnn:
        if given:
            flag = "--" + given[0].replace("_", "-")
            raise BadOptionError(f"{flag} sets the trained network's training: it needs --cnn")
        return None, None
    try:
        from workers.detectors.cnn import CnnSettings
    except ImportError:
        raise BadOptionError(
            "--cnn trains a network with PyTorch, which is not installed: "
            "pip install 'oceanlidar[train]'"
        ) from None
    if args.device is not None:
        choose("torch", args.device)  # a device that is not here: BadOptionError
    chosen = {
        name: getattr(args, name)
        for name in ("epochs", "batch_size", "seed")
        if getattr(args, name) is not None
    }
    return CnnSettings(**chosen), args.device


def _stored_sample(store: Store, sample: int):
    """Sample `sample` of a store, loaded, and its title; refused if not written."""
    ds = _open(store)
    total = ds.sizes["sample"]
    if not 0 <= sample < total:
        raise BadOptionError(f"--sample {sample}: the store has samples 0..{total - 1}")
    if not store.completed()[sample]:
        raise BadOptionError(f"--sample {sample}: not written yet in {store.url} (resume its run)")
    one = ds.isel(sample=sample).load()
    values = {path: one[name].values.item() for name, path in swept_parameters(ds).items()}
    name = ds.attrs.get("title", store.url)
    point, realisation = int(one["point"]), int(one["realisation"])
    return one, _sample_title(name, sample, point, values, realisation)


def _sample_of(args, *, points, realisations) -> int:
    """The sample ``--sample`` names, or ``--point`` and ``--realisation`` (default 0).

    `points` and `realisations` are every sample's, in sample order.

    Raises
    ------
    BadOptionError
        If no sample is that point's realisation.
    """
    if args.point is None:
        return 0 if args.sample is None else args.sample
    realisation = 0 if args.realisation is None else args.realisation
    found = np.flatnonzero((points == args.point) & (realisations == realisation))
    if not len(found):
        raise BadOptionError(
            f"--point {args.point} --realisation {realisation}: the sweep has points "
            f"0..{int(points.max())} of realisations 0..{int(realisations.max())}"
        )
    return int(found[0])


def _sample_title(name: str, sample: int, point: int, values: dict, realisation: int) -> str:
    """A preview's title: the sweep, the sample, its point's swept values (rounded)."""
    from service.plots import rounded

    shown_values = ", ".join(f"{path}={rounded(value)}" for path, value in values.items())
    where = f"point {point}" + (f": {shown_values}" if shown_values else "")
    return f"{name}, sample {sample} ({where}; realisation {realisation})"


def _check_picture(path: str, formats: tuple[str, ...], flag: str = "--output") -> None:
    """Refuse a picture (its `flag`) that cannot be written, before any work is done.

    Raises
    ------
    BadOptionError
        If its folder is missing or not writable, it is a folder itself, or its extension
        is none of `formats`.
    """
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise BadOptionError(f"{flag} {shown(path)}: no folder {shown(folder)}")
    if os.path.isdir(path) or not os.access(folder, os.W_OK):
        what = "a folder" if os.path.isdir(path) else f"{shown(folder)} is not writable"
        raise BadOptionError(f"{flag} {shown(path)}: {what}")
    extension = os.path.splitext(path)[1].lower()
    if extension not in formats:
        what = f"a {extension} picture" if extension else "a picture without extension"
        raise BadOptionError(
            f"{flag} {shown(path)}: cannot write {what} (write {', '.join(formats)})"
        )


@contextlib.contextmanager
def _saving(path: str, flag: str = "--output"):
    """Report a picture that cannot be written (`_check_picture` passed) as bad input."""
    try:
        yield
    except OSError as error:
        reason = error.strerror or type(error).__name__
        raise BadOptionError(f"{flag} {shown(path)}: {reason}") from None


def cmd_preview(args) -> int:
    """Draw a sample: rendered now from a sweep file, or read from a store."""
    from service.cli.run_commands import memory_limit
    from service.plots import PREVIEW_FORMATS, render_preview, save_preview

    _check_picture(args.output, PREVIEW_FORMATS)
    if args.realisation is not None and args.point is None:
        raise BadOptionError("--realisation needs --point: the sample of that point")
    if os.path.isfile(args.source):
        backend = choose(args.backend, args.device)
        plan = load_sweep(args.source, max_memory=None if args.no_limits else memory_limit(args))
        sample = _sample_of(
            args,
            points=np.arange(len(plan.points)).repeat(plan.realisations),
            realisations=np.tile(np.arange(plan.realisations), len(plan.points)),
        )
        address = plan.sample(sample)
        check_renderers(plan, backend, points=[address.point])
        ds = render_preview(plan, sample, backend)
        title = _sample_title(
            plan.sweep.name, sample, address.point, address.values, address.realisation
        )
        measurements = address.scene.surface.conditioning.points
    else:
        if args.backend is not None or args.device is not None:
            flag = "--backend" if args.backend is not None else "--device"
            raise BadOptionError(
                f"{flag}: preview reads a store's sample as it was rendered; give it with a "
                "sweep file, whose sample preview renders"
            )
        store = _store(args, args.source)
        ds = _open(store)
        sample = _sample_of(args, points=ds["point"].values, realisations=ds["realisation"].values)
        ds, title = _stored_sample(store, sample)
        measurements = None
    with _saving(args.output):
        frames = save_preview(
            ds,
            args.output,
            frame=args.frame,
            shared_scale=args.shared_scale,
            full_range=args.full_range,
            title=title,
            measurements=measurements,
            dpi=args.dpi,
        )
    log.info("%s: %d frame(s)", args.output, frames)
    return EXIT_OK


def cmd_check(args) -> int:
    """Hold the fast renderer to photon transport on a few points of a sweep (exit 1: not)."""
    from service.charts import plot_check
    from service.check import check_points, report_lines, spanning_points, transport_settings
    from service.cli.run_commands import memory_limit
    from service.plots import PLOT_FORMATS

    if args.points < 1:
        raise BadOptionError(f"--points {args.points}: check at least 1 point")
    if args.plot is not None:
        _check_picture(args.plot, PLOT_FORMATS, "--plot")
    plan = load_sweep(args.sweep, max_memory=None if args.no_limits else memory_limit(args))
    transport_settings(plan, photons=args.photons)
    points = spanning_points(plan, args.points)
    log.info(
        "checking %d of %d points (%s), realisation 0's sea, frame 0",
        len(points),
        len(plan.points),
        ", ".join(map(str, points)),
    )
    checks = check_points(
        plan, points, photons=args.photons, progress=lambda c: print("\n".join(report_lines(c)))
    )
    failing = [check.point for check in checks if not check.holds]
    print(
        f"{len(checks) - len(failing)} of {len(checks)} points hold"
        + (f"; outside the bars: point(s) {', '.join(map(str, failing))}" if failing else "")
    )
    if args.plot is not None:
        with _saving(args.plot, "--plot"):
            plot_check(checks, args.plot)
        log.info("%s: the comparison drawn", args.plot)
    return EXIT_FAILURE if failing else EXIT_OK


def cmd_plot(args) -> int:
    """Plot a store's statistics, or a detection dataset."""
    from service.charts import plot_detection, plot_statistics
    from service.detect import DATASET_KIND
    from service.plots import PLOT_FORMATS
    from service.progress import phase

    _check_picture(args.output, PLOT_FORMATS)
    store = _store(args, args.store)
    said = functools.partial(phase, stream=_progress(args))
    if store.kind() == DATASET_KIND:
        with said("reading the detection dataset"):
            detection = store.dataset()
        with _saving(args.output), said(f"drawing {args.output}"):
            plot_detection(detection, args.output)
        log.info("%s", args.output)
        return EXIT_OK
    _open(store)
    statistics = _statistics(store)
    if statistics is None:
        raise UnusableOutputError(f"{store.url}: no statistics yet; run `oceanlidar stats` first")
    try:
        with said("reading the statistics"):
            stats = statistics.dataset().load()  # small: per point and gate
    except Exception as error:
        raise DamagedStoreError(
            f"{statistics.url}: a chunk cannot be read ({type(error).__name__}); run "
            f"`oceanlidar stats {store.url}` to write the statistics again"
        ) from None
    with _saving(args.output), said(f"drawing {args.output}"):
        plot_statistics(stats, args.output)
    log.info("%s", args.output)
    return EXIT_OK
