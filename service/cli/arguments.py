"""The command line's shared arguments: argparse types and the options several commands take.

`service.cli.parser` builds the commands of them; light, as it is (no command imported).
"""

from __future__ import annotations

import argparse

from service.inputs import DEFAULT_MAX_MEMORY, json_object

__all__ = [
    "backend",
    "batch_memory",
    "count",
    "limits",
    "output",
    "port",
    "selection",
    "storage_options",
    "training",
]

MAX_MEMORY_HELP = f"most memory one sample may need, GiB (default {DEFAULT_MAX_MEMORY / 2**30:g})"


def port(text: str) -> int:
    """A TCP port, 1 to 65535 (argparse's type for ``--port``)."""
    try:
        port = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a port number: {text!r}") from None
    if not 1 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"{port} is not a port (1 to 65535)")
    return port


def output(text: str) -> str:
    """A path or URL to write (argparse's type for ``--output``): not empty, printable."""
    if not text.strip():
        raise argparse.ArgumentTypeError("must name a path or URL, got an empty one")
    if any(ord(character) < 32 or ord(character) == 127 for character in text):
        raise argparse.ArgumentTypeError(f"control characters are not allowed, got {text!r}")
    return text


def storage_options(command) -> None:
    """``--storage-options``: the store's fsspec options, a JSON object."""
    command.add_argument(
        "--storage-options", type=json_object, default=None, help="fsspec options as JSON"
    )


def backend(command, renders: str) -> None:
    """``--backend`` and ``--device``: where `renders` (the samples, the timed renders)."""
    command.add_argument(
        "--backend",
        choices=("numpy", "torch"),
        default=None,
        help=f"array backend {renders} render on (default: numpy, torch on a CUDA device)",
    )
    command.add_argument(
        "--device",
        default=None,
        help=f"device {renders} render on: cpu (default), cuda or cuda:N (implies torch)",
    )


def batch_memory(command) -> None:
    """``--batch-memory``: the memory a batch of one scene's samples may take on a worker."""
    command.add_argument(
        "--batch-memory",
        type=gibibytes,
        default=None,
        metavar="GIB",
        help="memory a batch of one scene's samples may take, GiB (default: half of what a "
        "task has: a GPU's memory shared by its worker's tasks, a CPU worker's share of the "
        "machine's)",
    )


def gibibytes(text: str) -> float:
    """An argparse type: a number of GiB, written without its unit (``--batch-memory``)."""
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a number of GiB (write the number alone: 2 for 2 GiB)"
        ) from None


def count(least: int):
    """An argparse type: a whole number, at least `least`."""

    def parse(text: str) -> int:
        try:
            number = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
        if number < least:
            raise argparse.ArgumentTypeError(f"must be at least {least}, got {number}")
        return number

    return parse


def selection(text: str) -> str:
    """``PATH=VALUE`` (argparse's type for ``--train-on``; the store checks both)."""
    path, equals, value = text.partition("=")
    if not equals or not path.strip() or not value.strip():
        raise argparse.ArgumentTypeError(f"give PATH=VALUE (surface.wind_speed=3), got {text!r}")
    return f"{path.strip()}={value.strip()}"


def training(detect) -> None:
    """``detect``'s options of the trained network (each needs ``--cnn``)."""
    detect.add_argument(
        "--epochs", type=count(1), default=None, help="passes over the training samples (5)"
    )
    detect.add_argument(
        "--samples",
        type=count(0),
        default=None,
        help="fresh realisations rendered a training point from the store's sweep, trained "
        "on besides the store's (default 0)",
    )
    detect.add_argument(
        "--batch-size", type=count(1), default=None, help="samples a batch holds (64)"
    )
    detect.add_argument(
        "--device",
        default=None,
        help="where the network trains: cpu, cuda or cuda:N (default: a GPU if there is one)",
    )
    detect.add_argument(
        "--seed", type=count(0), default=None, help="seed of the weights and the shuffling (0)"
    )
    detect.add_argument(
        "--train-on",
        type=selection,
        action="append",
        default=None,
        metavar="PATH=VALUE",
        help="train only on the pairs whose swept parameter PATH has VALUE (repeatable); "
        "every pair is scored",
    )


def limits(command) -> None:
    """``--no-limits`` and ``--max-memory``: the size and memory limits of a run."""
    command.add_argument(
        "--no-limits", action="store_true", help="lift the size and memory limits"
    )
    command.add_argument("--max-memory", type=float, default=None, help=MAX_MEMORY_HELP)
