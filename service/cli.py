"""The ``oceanlidar`` command line: logging, the commands, and their exit codes.

Exit codes: 0 success, 2 bad input (a message, no traceback, nothing written; bad flags
too, argparse's own status), 1 failure (a sample that could not be rendered, an
interrupted run, an unreadable store). The arguments are in `service.parser`, the
commands in `service.run_commands` (run, validate, schema) and `service.store_commands`
(info, stats, detect, preview, plot).

Messages go through `logging`: the ``oceanlidar`` logger prints them plainly on stderr
(``-q``: errors only); dask's own messages and Python warnings, the embedded workers'
included, stay off the console unless ``-v`` asks for them (``-vv``: debugging).
"""

from __future__ import annotations

import logging
import sys

from service import client, run_commands, store_commands
from service.inputs import SweepError
from service.parser import parser
from service.store.shards import DamagedStoreError

__all__ = ["main"]

EXIT_FAILURE, EXIT_BAD_INPUT = 1, 2

COMMANDS = {
    "run": run_commands.cmd_run,
    "validate": run_commands.cmd_validate,
    "schema": run_commands.cmd_schema,
    "info": store_commands.cmd_info,
    "stats": store_commands.cmd_stats,
    "detect": store_commands.cmd_detect,
    "preview": store_commands.cmd_preview,
    "plot": store_commands.cmd_plot,
    **client.COMMANDS,
}

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
        return COMMANDS[args.command](args)
    except SweepError as error:
        print(f"oceanlidar {args.command}: error: {_capped(str(error))}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except DamagedStoreError as error:
        print(f"oceanlidar {args.command}: error: {error}", file=sys.stderr)
        return EXIT_FAILURE
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_FAILURE


if __name__ == "__main__":
    sys.exit(main())
