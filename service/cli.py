"""The ``oceanlidar`` command line.

Exit codes: 0 success, 2 bad input (a message, no traceback, nothing written), 1 failure
(a sample that could not be rendered, an interrupted run, an unreadable store).
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import dask

from service import integrity, lock, storage, store
from service.inputs import SweepError, shown
from service.sweep import DEFAULT_MAX_MEMORY, human_bytes, load_sweep

__all__ = ["main"]

EXIT_OK, EXIT_FAILURE, EXIT_BAD_INPUT = 0, 1, 2
MAX_MEMORY_HELP = f"most memory one sample may need, GiB (default {DEFAULT_MAX_MEMORY / 2**30:g})"


def _json_object(text: str) -> dict:
    """Parse --storage-options: a JSON object."""
    try:
        value = json.loads(text)
    except json.JSONDecodeError as error:
        raise argparse.ArgumentTypeError(f"not JSON: {error}") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError("must be a JSON object, e.g. '{\"anon\": false}'")
    return value


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        self.print_usage(sys.stderr)
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message}\n")


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="oceanlidar",
        description="Simulate airborne range-gated LIDAR images through a rough sea.",
    )
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    run = commands.add_parser("run", help="run a sweep into a zarr store")
    run.add_argument("sweep", help="sweep YAML file")
    run.add_argument("--output", help="store path or fsspec URL (default: the file's output)")
    where = run.add_mutually_exclusive_group()
    where.add_argument(
        "--workers",
        type=int,
        default=None,
        help="worker processes of the embedded cluster (default: one per core)",
    )
    where.add_argument("--scheduler", help="address of an existing dask scheduler")
    tls = run.add_argument_group("TLS (for tls:// schedulers; else dask's configuration)")
    tls.add_argument("--tls-ca-file", help="CA certificate(s), PEM")
    tls.add_argument("--tls-cert", help="client certificate, PEM")
    tls.add_argument("--tls-key", help="client private key, PEM")
    mode = run.add_mutually_exclusive_group()
    mode.add_argument("--resume", action="store_true", help="complete an interrupted run")
    mode.add_argument("--overwrite", action="store_true", help="replace an existing store")
    run.add_argument(
        "--verify",
        action="store_true",
        help="with --resume: read back every completed sample, recompute damaged ones",
    )
    run.add_argument(
        "--batch",
        type=int,
        default=store.SHARD_SAMPLES,
        help=f"samples per shard and task of a new store (default {store.SHARD_SAMPLES})",
    )
    run.add_argument(
        "--task-timeout",
        type=float,
        default=600.0,
        help="seconds after its submission that a task is given up as stuck (default 600)",
    )
    run.add_argument("--no-limits", action="store_true", help="lift the size and memory limits")
    run.add_argument("--max-memory", type=float, default=None, help=MAX_MEMORY_HELP)
    run.add_argument(
        "--storage-options", type=_json_object, default=None, help="fsspec options as JSON"
    )

    validate = commands.add_parser("validate", help="check a sweep and print its plan")
    validate.add_argument("sweep", help="sweep YAML file")
    validate.add_argument(
        "--no-limits", action="store_true", help="lift the size and memory limits"
    )
    validate.add_argument("--max-memory", type=float, default=None, help=MAX_MEMORY_HELP)

    info = commands.add_parser("info", help="what a store holds and how complete it is")
    info.add_argument("store", help="store path or URL")
    info.add_argument(
        "--verify", action="store_true", help="read back every completed sample (slow)"
    )
    info.add_argument("--storage-options", type=_json_object, default=None)

    stats = commands.add_parser("stats", help="(re)compute a store's statistics dataset")
    stats.add_argument("store", help="store path or URL")
    stats.add_argument("--storage-options", type=_json_object, default=None)
    detect = commands.add_parser(
        "detect", help="detection study of a store: ROC, AUC and Pd per parameter point"
    )
    detect.add_argument("store", help="store path or URL")
    detect.add_argument("--output", help="DET.zarr (default: beside the store, .detect.zarr)")
    detect.add_argument("--storage-options", type=_json_object, default=None)
    preview = commands.add_parser("preview", help="draw one sample's gated images")
    preview.add_argument("sweep", help="sweep YAML file")
    preview.add_argument("--sample", type=int, default=0, help="sample index (default 0)")
    preview.add_argument("--output", required=True, help="FILE.png, or FILE.gif for a sequence")

    plot = commands.add_parser("plot", help="plot a store's statistics or a detection dataset")
    plot.add_argument("store", help="store path or URL")
    plot.add_argument("--output", required=True, help="FILE.png")
    plot.add_argument("--storage-options", type=_json_object, default=None)
    return parser


def _load(args):
    """The plan of ``args.sweep`` under the memory limit the flags set."""
    limit = DEFAULT_MAX_MEMORY if args.max_memory is None else args.max_memory * 2**30
    if args.max_memory is not None and not args.max_memory > 0:
        raise SweepError("--max-memory must be a positive number of GiB")
    return load_sweep(args.sweep, max_memory=None if args.no_limits else limit)


def _plan_lines(plan, batch: int = store.SHARD_SAMPLES, url: str | None = None) -> list[str]:
    tasks = -(-plan.samples // batch)
    lines = [
        f"sweep {plan.sweep.name!r}: {len(plan.points)} parameter points x "
        f"{plan.realisations} realisations = {plan.samples} samples",
        f"  tasks: {tasks} (shards of {batch} samples)",
        f"  storage: about {human_bytes(plan.total_bytes())} uncompressed "
        f"({human_bytes(plan.sample_bytes())} per sample)",
        f"  swept: {', '.join(plan.swept) or '(nothing)'}",
        f"  output: {url or plan.sweep.output}",
    ]
    return lines


def _cmd_validate(args) -> int:
    plan = _load(args)
    if not args.no_limits:
        plan.check_limits()
    store.check_uniform(plan)
    print("\n".join(_plan_lines(plan)))
    return EXIT_OK


def _security(args):
    """A `distributed.Security` from the TLS flags (all three, encryption required)."""
    given = [args.tls_ca_file, args.tls_cert, args.tls_key]
    if not any(given):
        if (args.scheduler or "").startswith("tls://") and not dask.config.get(
            "distributed.comm.tls.ca-file", None
        ):
            raise SweepError(
                f"--scheduler {shown(args.scheduler)}: a tls:// scheduler needs "
                "--tls-ca-file, --tls-cert and --tls-key (or dask's TLS configuration)"
            )
        return None
    if not all(given):
        raise SweepError("--tls-ca-file, --tls-cert and --tls-key go together")
    for path in given:
        if not os.path.isfile(path):
            raise SweepError(f"{path}: no such file")
    from distributed import Security

    return Security(
        tls_ca_file=args.tls_ca_file,
        tls_client_cert=args.tls_cert,
        tls_client_key=args.tls_key,
        require_encryption=True,
    )


def _cmd_run(args) -> int:
    from service.cluster import ClusterError
    from service.run import describe_sample, execute

    if args.workers is not None and args.workers < 1:
        raise SweepError("--workers must be at least 1")
    if args.batch < 1:
        raise SweepError("--batch must be at least 1")
    if not args.task_timeout > 0:
        raise SweepError("--task-timeout must be a positive number of seconds")
    if args.verify and not args.resume:
        raise SweepError("--verify goes with --resume (a new store has nothing to verify)")
    plan = _load(args)
    if not args.no_limits:
        plan.check_limits()
    store.check_uniform(plan)
    url = args.output or plan.sweep.output
    print("\n".join(_plan_lines(plan, args.batch, url)), file=sys.stderr)
    try:
        result = execute(
            plan,
            url,
            workers=args.workers,
            scheduler=args.scheduler,
            security=_security(args),
            resume=args.resume,
            verify=args.verify,
            overwrite=args.overwrite,
            storage_options=args.storage_options,
            batch_size=args.batch,
            task_timeout=args.task_timeout,
        )
    except ClusterError as error:
        print(f"oceanlidar run: error: {error}", file=sys.stderr)
        return EXIT_FAILURE
    _print_problems("damaged or missing, recomputed", result.damaged)
    rate = result.written / result.seconds if result.seconds > 0 else 0.0
    print(
        f"{url}: wrote {result.written} samples in {result.seconds:.1f} s ({rate:.2f} samples/s)"
        + (f", {result.skipped} already complete" if result.skipped else ""),
        file=sys.stderr,
    )
    if result.interrupted:
        print(f"interrupted: run again with --resume to complete {url}", file=sys.stderr)
        return EXIT_FAILURE
    for sample, reason in result.rejected:
        print(f"{describe_sample(plan, sample)} not stored: {reason}", file=sys.stderr)
    for start, count, error in result.failed:
        print(f"samples {start}..{start + count - 1} failed: {error}", file=sys.stderr)
    for start, count in result.stuck:
        print(
            f"samples {start}..{start + count - 1}: no result {args.task_timeout:g} s after "
            "submission (a frozen worker?); given up",
            file=sys.stderr,
        )
    if result.stopped:
        print(f"stopped: {result.stopped}; run again with --resume", file=sys.stderr)
    if result.failed or result.rejected or result.stuck or result.stopped:
        print("statistics not written: some samples failed", file=sys.stderr)
        return EXIT_FAILURE
    print(f"statistics: {storage.stats_url(url)}", file=sys.stderr)
    return EXIT_OK


SHOWN_PROBLEMS = 20
"""Most samples listed one per line in a report; the rest are counted."""


def _print_problems(what: str, problems: list, stream=sys.stderr) -> None:
    """One line per damaged sample (at most `SHOWN_PROBLEMS`), then a count."""
    for sample, reason in problems[:SHOWN_PROBLEMS]:
        print(f"  sample {sample}: {what}: {reason}", file=stream)
    if len(problems) > SHOWN_PROBLEMS:
        print(f"  ... and {len(problems) - SHOWN_PROBLEMS} more samples", file=stream)


def _open(args):
    args.store = storage.normalise(args.store, args.storage_options)
    if not storage.store_exists(args.store, args.storage_options):
        raise SweepError(f"{args.store}: no store there")
    attributes = storage.root_attributes(args.store, args.storage_options) or {}
    if attributes.get(storage.KIND) != "samples":
        raise SweepError(f"{args.store}: not an oceanlidar samples store")
    try:
        return store.open_store(args.store, storage_options=args.storage_options)
    except Exception as error:
        raise SweepError(f"{args.store}: not an oceanlidar store ({error})") from None


def _statistics(url: str, storage_options: dict | None) -> str | None:
    """The statistics store beside `url`, if one is there."""
    stats = storage.stats_url(url)
    attributes = storage.root_attributes(stats, storage_options) or {}
    return stats if attributes.get(storage.KIND) == "statistics" else None


def _cmd_info(args) -> int:
    ds = _open(args)
    done = int(integrity.completed_samples(args.store, storage_options=args.storage_options).sum())
    total = ds.sizes["sample"]
    swept = [f"{name} ({path})" for name, path in store.swept_parameters(ds).items()]
    print(f"{args.store}: {ds.attrs.get('title', '')}")
    print(f"  samples: {done}/{total} complete ({100 * done / max(total, 1):.1f} %)")
    print(f"  points: {ds.attrs.get('points')}  realisations: {ds.attrs.get('realisations')}")
    print("  dimensions: " + ", ".join(f"{k}={v}" for k, v in ds.sizes.items()))
    print("  variables: " + ", ".join(map(str, ds.data_vars)))
    print(f"  swept: {', '.join(map(str, swept)) or '(nothing)'}")
    print(f"  sweep sha256: {ds.attrs.get('sweep_sha256')}")
    print(f"  written by: oceanlidar {ds.attrs.get('oceanlidar_version')}")
    print(f"  statistics: {_statistics(args.store, args.storage_options) or '(none)'}")
    if not args.verify:
        return EXIT_OK
    problems = integrity.verify(args.store, args.storage_options)
    print(f"  verified: {done - len(problems)} of {done} complete samples read back intact")
    _print_problems("damaged or missing", problems, sys.stdout)
    if problems:
        print("  run the sweep again with --resume --verify to recompute them")
        return EXIT_FAILURE
    return EXIT_OK


def _cmd_stats(args) -> int:
    from service.stats import write_statistics

    _open(args)
    with lock.writer_lock(args.store, args.storage_options):
        print(write_statistics(args.store, storage_options=args.storage_options))
    return EXIT_OK


def _cmd_detect(args) -> int:
    from service.detect import write_detection

    _open(args)
    target, unpaired = write_detection(
        args.store, output=args.output, storage_options=args.storage_options
    )
    if unpaired:
        print(f"points with no target-free twin, left out: {unpaired}", file=sys.stderr)
    print(target)
    return EXIT_OK


def _cmd_preview(args) -> int:
    from service.plots import render_preview, save_preview

    plan = load_sweep(args.sweep)
    ds = render_preview(plan, args.sample)
    point = divmod(args.sample, plan.realisations)[0]
    values = ", ".join(f"{k}={v}" for k, v in plan.points[point].items())
    title = f"{plan.sweep.name}, sample {args.sample}" + (f" ({values})" if values else "")
    measurements = plan.scenes[point].surface.conditioning.points
    frames = save_preview(ds, args.output, title=title, measurements=measurements)
    print(f"{args.output}: {frames} frame(s)", file=sys.stderr)
    return EXIT_OK


def _cmd_plot(args) -> int:
    from service.detect import DATASET_KIND
    from service.plots import plot_detection, plot_statistics

    args.store = storage.normalise(args.store, args.storage_options)
    attributes = storage.root_attributes(args.store, args.storage_options) or {}
    if attributes.get(storage.KIND) == DATASET_KIND:
        detection = store.open_store(args.store, storage_options=args.storage_options)
        plot_detection(detection, args.output)
        print(args.output, file=sys.stderr)
        return EXIT_OK
    _open(args)
    stats_path = _statistics(args.store, args.storage_options)
    if stats_path is None:
        raise SweepError(f"{args.store}: no statistics yet; run `oceanlidar stats` first")
    stats = store.open_store(stats_path, storage_options=args.storage_options)
    try:
        stats = stats.load()  # small: per point and gate
    except Exception as error:
        raise integrity.DamagedStoreError(
            f"{stats_path}: a chunk cannot be read ({type(error).__name__}); run "
            f"`oceanlidar stats {args.store}` to write the statistics again"
        ) from None
    plot_statistics(stats, args.output)
    print(args.output, file=sys.stderr)
    return EXIT_OK


MESSAGE_LINE = 500
"""Longest line of an error message: whatever a message quotes of the input, it is cut."""


def _capped(message: str) -> str:
    """`message` with every line cut to `MESSAGE_LINE` characters."""
    return "\n".join(
        line if len(line) <= MESSAGE_LINE else f"{line[:MESSAGE_LINE]}... (cut)"
        for line in message.splitlines()
    )


def main(argv=None) -> int:
    """Entry point of the ``oceanlidar`` console script."""
    args = _parser().parse_args(argv)
    commands = {
        "run": _cmd_run,
        "validate": _cmd_validate,
        "info": _cmd_info,
        "stats": _cmd_stats,
        "detect": _cmd_detect,
        "preview": _cmd_preview,
        "plot": _cmd_plot,
    }
    try:
        return commands[args.command](args)
    except SweepError as error:
        print(f"oceanlidar {args.command}: error: {_capped(str(error))}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except integrity.DamagedStoreError as error:
        print(f"oceanlidar {args.command}: error: {error}", file=sys.stderr)
        return EXIT_FAILURE
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_FAILURE


if __name__ == "__main__":
    sys.exit(main())
