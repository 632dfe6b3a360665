"""The ``oceanlidar`` command line: logging, the commands, and their exit codes.

Exit codes: 0 success, 2 bad input (a `service.errors.InputError`: a message, no
traceback, nothing written; bad flags too, argparse's own status), 1 failure (a sample
that could not be rendered, an interrupted run, an unreadable store; quietly, a standard
output closed by its reader as ``| head`` does: Python's convention for a broken pipe).
The arguments are in `service.cli.parser`; the commands, ``cmd_NAME`` each, in
`service.cli.run_commands` (run, validate, schema), `service.cli.store_commands` (info,
stats, detect, preview, plot, check) and `service.cli.job_commands` (serve, submit, jobs, status,
logs, cancel). A command's module is imported when the command runs: parsing the command line
imports neither dask, zarr nor the server.

Messages go through `logging`: the ``oceanlidar`` logger prints them plainly on stderr
(``-q``: errors only); dask's own messages and Python warnings, the embedded workers'
included, stay off the console unless ``-v`` asks for them (``-vv``: debugging).
"""

from __future__ import annotations

import importlib
import logging
import os
import sys

from service.cli.parser import parser
from service.errors import DamagedStoreError, InputError

__all__ = ["main"]

EXIT_FAILURE, EXIT_BAD_INPUT = 1, 2

COMMANDS = {
    **dict.fromkeys(("run", "validate", "schema"), "service.cli.run_commands"),
    **dict.fromkeys(
        ("info", "stats", "detect", "preview", "plot", "check"), "service.cli.store_commands"
    ),
    **dict.fromkeys(
        ("serve", "submit", "jobs", "status", "logs", "cancel"), "service.cli.job_commands"
    ),
}
"""The module that holds each command's ``cmd_NAME``, by command."""

MESSAGE_LINE = 500
"""Longest line of an error message: whatever a message quotes of the input, it is cut."""


class _Console(logging.StreamHandler):
    """A handler that writes to the ``sys.stderr`` of the moment (a redirection, a capture)."""

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value):
        pass  # always the current sys.stderr


def configure_logging(verbosity: int) -> None:
    """Console logging for a verbosity of ``-v`` count minus ``-q`` count.

    The ``oceanlidar`` logger prints its messages as they are (info and above; warnings
    and above with ``-q``; debug with ``-vv``); dask's loggers and Python's warnings
    (`logging.captureWarnings`) print errors only, warnings with ``-v``, info with ``-vv``.
    """
    console = _Console()
    console.setFormatter(logging.Formatter("%(message)s"))
    logging.captureWarnings(True)
    ours, captured = logging.getLogger("oceanlidar"), logging.getLogger("py.warnings")
    for logger in (ours, captured):
        logger.handlers = [h for h in logger.handlers if not isinstance(h, _Console)]
        logger.addHandler(console)
        logger.propagate = False
    ours.setLevel(
        logging.DEBUG if verbosity > 1 else logging.INFO if verbosity >= 0 else logging.WARNING
    )
    others = logging.INFO if verbosity > 1 else logging.WARNING if verbosity > 0 else logging.ERROR
    for name in ("distributed", "dask", "py.warnings", "bokeh", "tornado"):
        logging.getLogger(name).setLevel(others)


def _capped(message: str) -> str:
    """`message` with every line cut to `MESSAGE_LINE` characters.

    Not `textwrap.shorten`, which joins the lines and cuts at words: each line of a
    multi-line message (one per parameter point or field) keeps its place.
    """
    return "\n".join(
        line if len(line) <= MESSAGE_LINE else f"{line[:MESSAGE_LINE]}... (cut)"
        for line in message.splitlines()
    )


def main(argv=None) -> int:
    """Entry point of the ``oceanlidar`` console script."""
    args = parser().parse_args(argv)
    configure_logging(args.verbose - args.quiet)
    try:
        module = importlib.import_module(COMMANDS[args.command])
        code = getattr(module, f"cmd_{args.command}")(args)
        sys.stdout.flush()  # a closed pipe is found here, not at exit
        return code
    except BrokenPipeError:  # stdout's reader left (``| head``): stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no error at exit
        return EXIT_FAILURE
    except InputError as error:
        print(f"oceanlidar {args.command}: error: {_capped(str(error))}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_FAILURE
    except DamagedStoreError as error:
        print(f"oceanlidar {args.command}: error: {error}", file=sys.stderr)
        return EXIT_FAILURE
