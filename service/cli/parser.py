"""The ``oceanlidar`` command line's arguments: one `argparse` parser, one subparser a command.

Bad flags exit with status 2, argparse's own (the command line's "bad input", as
`service.cli` uses it), after the usage line; nothing is overridden. Light by design: it
imports no command (`service.cli.main` does, once one is chosen), so ``--help`` is quick.
"""

from __future__ import annotations

import argparse
import sys

from service.cli import arguments
from service.inputs import json_object
from service.records import JobState

__all__ = ["DEFAULT_SERVER", "parser"]

DEFAULT_SERVER = "http://127.0.0.1:8000"
"""The job service the clients talk to without ``--server`` or ``OCEANLIDAR_SERVER``."""


def _run(commands) -> None:
    run = commands.add_parser("run", help="run a sweep into a zarr store")
    run.add_argument("sweep", help="sweep YAML file")
    run.add_argument(
        "--output",
        type=arguments.output,
        help="store path or fsspec URL (default: the file's output)",
    )
    where = run.add_mutually_exclusive_group()
    where.add_argument(
        "--workers",
        type=int,
        default=None,
        help="worker processes of the embedded cluster (default: one per core)",
    )
    where.add_argument("--scheduler", help="address of an existing dask scheduler")
    run.add_argument(
        "--dashboard",
        action="store_true",
        help="serve dask's dashboard (on 127.0.0.1 for the embedded cluster) and print its link",
    )
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
        default=None,
        help="samples per shard and task of a new store (default: as many as fit in "
        "16 MiB uncompressed, at most 256, leaving at least 8 shards)",
    )
    run.add_argument(
        "--task-timeout",
        type=float,
        default=600.0,
        help="seconds after its submission that a task is given up as stuck (default 600)",
    )
    arguments.backend(run, "the samples")
    arguments.batch_memory(run)
    arguments.limits(run)
    arguments.storage_options(run)


def _preview(commands) -> None:
    preview = commands.add_parser(
        "preview",
        help="draw one sample's gated images, rendered from a sweep or read from a store",
    )
    preview.add_argument("source", help="sweep YAML file (rendered now) or store path or URL")
    which = preview.add_mutually_exclusive_group()
    which.add_argument("--sample", type=int, default=None, help="sample index (default 0)")
    which.add_argument(
        "--point", type=int, default=None, help="parameter point (with --realisation)"
    )
    preview.add_argument(
        "--realisation", type=int, default=None, help="realisation of --point (default 0)"
    )
    preview.add_argument(
        "--frame", type=int, default=None, help="frame to draw as PNG (default 0)"
    )
    preview.add_argument(
        "--shared-scale",
        action="store_true",
        help="one colour scale for every gate and frame (default: one per gate, shared "
        "by a GIF's frames)",
    )
    preview.add_argument(
        "--full-range",
        action="store_true",
        help="colour scales up to the brightest pixel (default: the 99.5th percentile, so "
        "that a few hot caustic pixels saturate instead of darkening the rest)",
    )
    preview.add_argument(
        "--output",
        type=arguments.output,
        required=True,
        help="FILE.png, or FILE.gif for a sequence",
    )
    preview.add_argument(
        "--dpi",
        type=float,
        default=None,
        help="dots per inch (default: 100, or more where a gate's image would have fewer "
        "than 2 screen pixels across each of its pixels)",
    )
    arguments.backend(preview, "a sweep file's sample")
    arguments.limits(preview)
    arguments.storage_options(preview)


def _check(commands) -> None:
    check = commands.add_parser(
        "check",
        help="hold the fast renderer to photon transport on a few points of a sweep",
        description="Render a few points of the sweep (its corners first: --points) by the "
        "fast renderer and by Monte Carlo photon transport on the same sea (realisation "
        "0's, frame 0) and print per point and gate the fast/transport ratio of the "
        "background, the target's contrast and its shadow, with the transport's errors, "
        "marking those outside the bars: backgrounds within 5 %, the target's contrast "
        "within 5 % inside a gate and 10 % where a gate's edge cuts it, shadows within "
        "0.05 (each plus two standard errors). Exit 0 when every point holds, 1 "
        "otherwise, 2 for bad input. Writes nothing but --plot.",
    )
    check.add_argument("sweep", help="sweep YAML file (of small_angle points)")
    check.add_argument(
        "--points", type=int, default=4, help="most points to check (default %(default)s)"
    )
    check.add_argument(
        "--photons",
        type=int,
        default=None,
        help="Monte Carlo photons per point (default: the sweep's transport.photons); "
        "more narrow the errors, in proportion to the time",
    )
    check.add_argument("--plot", help="FILE.png: the images side by side and ratios by gate")
    arguments.limits(check)


def _job_commands(commands) -> None:
    """``serve`` (the job service) and its clients (``submit``, ``logs``, ...)."""
    serve = commands.add_parser("serve", help="run the batch service (HTTP API and web page)")
    serve.add_argument(
        "--host", default="127.0.0.1", help="address to listen on (default: %(default)s)"
    )
    serve.add_argument(
        "--port", type=arguments.port, default=8000, help="port (default: %(default)s)"
    )
    serve.add_argument("--db", default="oceanlidar-jobs.sqlite", help="job table, SQLite file")
    serve.add_argument(
        "--data-root",
        default="oceanlidar-data",
        help="folder or URL prefix that every job's output lies under (default: %(default)s)",
    )
    serve.add_argument("--storage-options", type=json_object, help="data root's fsspec options")
    serve.add_argument("--token-file", help="tokens, 'OWNER TOKEN' a line (else OCEANLIDAR_TOKEN)")
    serve.add_argument("--no-auth", action="store_true", help="no token (127.0.0.1 only)")
    serve.add_argument("--max-running", type=int, default=4, help="jobs run at once (default 4)")
    serve.add_argument(
        "--queue-limit", type=int, default=100, help="most unfinished jobs (default 100)"
    )
    serve.add_argument(
        "--batch",
        type=int,
        default=None,
        help="samples per shard and task of a new store (default: as many as fit in "
        "16 MiB uncompressed, at most 256, leaving at least 8 shards)",
    )
    where = serve.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None, help="embedded cluster's workers")
    where.add_argument("--scheduler", help="address of an existing dask scheduler")
    arguments.backend(serve, "every job's samples")
    arguments.batch_memory(serve)
    tls = serve.add_argument_group("TLS (for tls:// schedulers; else dask's configuration)")
    tls.add_argument("--tls-ca-file", help="CA certificate(s), PEM")
    tls.add_argument("--tls-cert", help="client certificate, PEM")
    tls.add_argument("--tls-key", help="client private key, PEM")

    submit = commands.add_parser("submit", help="submit a sweep to the service")
    submit.add_argument("sweep", help="sweep YAML file")
    mode = submit.add_mutually_exclusive_group()
    mode.add_argument("--resume", action="store_true", help="complete an existing store")
    mode.add_argument("--overwrite", action="store_true", help="replace an existing store")
    submit.add_argument(
        "--submission-id",
        help="this submission's id (1-64 of A-Z a-z 0-9 . _ -): the same id again answers "
        "the same job (default: a new random one, kept for the client's own retries)",
    )
    jobs = commands.add_parser("jobs", help="list the service's jobs, newest first")
    jobs.add_argument(
        "--state", choices=[str(state) for state in JobState], help="only jobs in this state"
    )
    status = commands.add_parser("status", help="a job's state and progress")
    status.add_argument("id", help="job id")
    status.add_argument("--watch", action="store_true", help="follow it until it finishes")
    logs = commands.add_parser("logs", help="a job's log: accepted, validated, run, finished")
    logs.add_argument("id", help="job id")
    logs.add_argument("--follow", action="store_true", help="print new lines until it finishes")
    cancel = commands.add_parser("cancel", help="cancel a job (its store stays resumable)")
    cancel.add_argument("id", help="job id")
    for parser in (submit, jobs, status, logs, cancel):
        parser.add_argument(
            "--server", help=f"service URL (else OCEANLIDAR_SERVER, {DEFAULT_SERVER})"
        )
        parser.add_argument("--token-file", help="file holding the token (else OCEANLIDAR_TOKEN)")


class _Version(argparse.Action):
    """``--version``: print the installed version and exit (looked up only when asked)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS):
        super().__init__(
            option_strings,
            dest,
            nargs=0,
            default=default,
            help="show program's version number and exit",
        )

    def __call__(self, parser, namespace, values, option_string=None):
        from service import package_version

        print(f"{parser.prog} {package_version()}", file=sys.stdout)
        parser.exit()


def parser() -> argparse.ArgumentParser:
    """The command line's parser: global flags, then one subcommand."""
    top = argparse.ArgumentParser(
        prog="oceanlidar",
        description="Simulate airborne range-gated LIDAR images through a rough sea.",
    )
    top.add_argument("--version", action=_Version)
    _verbosity(top, default=0)
    commands = top.add_subparsers(dest="command", required=True)
    _run(commands)

    validate = commands.add_parser(
        "validate", help="check a sweep, print its plan and an estimated run time"
    )
    validate.add_argument("sweep", help="sweep YAML file")
    validate.add_argument(
        "--show-scene",
        action="store_true",
        help="print the first point's scene with every default filled in (YAML)",
    )
    validate.add_argument(
        "--workers",
        type=int,
        default=None,
        help="worker processes the run time is estimated for (default: one per core)",
    )
    validate.add_argument(
        "--no-estimate",
        action="store_true",
        help="skip the timed renders of sample 0's first frame (and the run-time estimate)",
    )
    arguments.backend(validate, "the timed renders")
    arguments.batch_memory(validate)
    arguments.limits(validate)

    commands.add_parser("schema", help="print the JSON Schema of sweep files (for editors)")

    info = commands.add_parser("info", help="what a store holds and how complete it is")
    info.add_argument("store", help="store path or URL")
    info.add_argument(
        "--verify", action="store_true", help="read back every completed sample (slow)"
    )
    arguments.storage_options(info)

    stats = commands.add_parser("stats", help="(re)compute a store's statistics dataset")
    stats.add_argument("store", help="store path or URL")
    stats.add_argument(
        "--partial",
        action="store_true",
        help="compute the statistics of an incomplete store's written samples (refused "
        "without it)",
    )
    arguments.storage_options(stats)
    detect = commands.add_parser(
        "detect", help="detection study of a store: ROC, AUC and Pd per parameter point"
    )
    detect.add_argument("store", help="store path or URL")
    detect.add_argument(
        "--output",
        type=arguments.output,
        help="DET.zarr (default: beside the store, .detect.zarr)",
    )
    detect.add_argument(
        "--workers",
        type=int,
        default=None,
        help="score the points on an embedded cluster of this many processes, and render "
        "--samples in as many (default: threads of this process, which share one core while "
        "they render)",
    )
    detect.add_argument(
        "--cnn",
        action="store_true",
        help="also train a small convolutional network on the even realisations of every "
        "point (or those --train-on picks) and score it on the odd ones (a GPU if there is "
        "one; needs "
        "pip install 'oceanlidar[train]')",
    )
    arguments.training(detect)
    arguments.storage_options(detect)
    _preview(commands)

    plot = commands.add_parser("plot", help="plot a store's statistics or a detection dataset")
    plot.add_argument("store", help="store path or URL")
    plot.add_argument(
        "--output",
        type=arguments.output,
        required=True,
        help="FILE.png (or .pdf, .svg: what matplotlib writes)",
    )
    arguments.storage_options(plot)
    _check(commands)
    _job_commands(commands)
    for command in commands.choices.values():  # after the command too: run x.yaml -q
        _verbosity(command, default=argparse.SUPPRESS)
    return top


def _verbosity(parser: argparse.ArgumentParser, *, default) -> None:
    """``-v`` and ``-q``, before the command (`default` 0) or after it (unset if not given).

    Given after the command, a flag's count replaces the one given before it.
    """
    parser.add_argument(
        "-v",
        "--verbose",
        action="count",
        default=default,
        help="more messages: -v dask's and the workers' warnings, -vv debugging",
    )
    parser.add_argument(
        "-q", "--quiet", action="count", default=default, help="errors only (no plan, no progress)"
    )
