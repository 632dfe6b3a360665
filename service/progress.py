"""What a long command shows on stderr: a line per set-up phase, then tqdm's progress bar.

A phase (`phase`) is one line, ``starting the local cluster (2 workers)... 4.1 s``: its
name as it starts, its duration as it ends. The work itself is counted by `Progress`
(samples, points or pairs done of the total, rate, elapsed and time left): tqdm's bar on a
terminal; on a file or a pipe (a log), where a bar redrawn in place would leave a line per
update, a plain line every `LOG_EVERY` seconds and one at the end, with the total.

Kept rather than dask's progress bars (`distributed.progress`), which follow a fixed set of
futures: a run submits its tasks a window at a time, counts samples rather than tasks and
starts from the samples a resumed store already holds. `compute` is `dask.compute` with a
`Progress`, on the dask client in use or on local threads. A stream of None writes nothing
(``--quiet``, the job service).
"""

from __future__ import annotations

import contextlib
import os
import time

import dask
from dask.callbacks import Callback
from distributed import Client, as_completed
from tqdm import tqdm

__all__ = ["LOG_EVERY", "Progress", "compute", "phase"]

LOG_EVERY = 30.0
"""Seconds between progress lines written to a file or a pipe (not a terminal)."""


def _terminal(stream) -> bool:
    """Whether tqdm can draw on `stream`: a terminal that says how wide it is.

    A pseudo-terminal may say 0 columns (``script``, some ``docker -t`` and CI terminals),
    on which tqdm's bar is drawn 0 wide: it gets the log's lines.
    """
    if stream is None or not hasattr(stream, "isatty") or not stream.isatty():
        return False
    try:
        return os.get_terminal_size(stream.fileno()).columns > 0
    except (AttributeError, OSError, ValueError):
        return False


def _write(stream, text: str) -> None:
    if stream is not None:
        stream.write(text)
        stream.flush()


@contextlib.contextmanager
def phase(what: str, *, stream=None):
    """Say on `stream` that `what` starts, then how long it took (``what... 4.1 s``).

    A phase that raises ends its line with ``stopped after 4.1 s``. A `stream` of None
    writes nothing.
    """
    _write(stream, f"{what}... ")
    start = time.monotonic()
    try:
        yield
    except BaseException:
        _write(stream, f"stopped after {time.monotonic() - start:.1f} s\n")
        raise
    _write(stream, f"{time.monotonic() - start:.1f} s\n")


class Progress:
    """Work done of a total on `stream`: tqdm's bar on a terminal, else a line at times.

    Parameters
    ----------
    total : int
        Units of work in all.
    unit : str
        What is counted (``samples``, ``points``).
    already : int
        Units done before this command (a resumed run): counted done, not in the rate.
    stream : file, optional
        Where to write; None writes nothing.
    callback : callable, optional
        ``callback(done, rate)`` at every update (done units, units/s of this command).
    first : str, optional
        A phase line (`phase`) open until the first update, e.g. ``first shard``: the time
        to the first result, shown before the bar starts.
    """

    def __init__(
        self, total: int, *, unit: str, already: int = 0, stream=None, callback=None, first=None
    ):
        self.total, self.unit, self.already = total, unit, already
        self.done = already
        self.stream = stream
        self.callback = callback
        self.start = time.monotonic()
        self.logged = self.start
        self.bar = None
        self.shown = already  # the count of the last line written to a log
        self.first = first if already < total else None
        if self.first is not None:
            _write(stream, f"{first}... ")

    def update(self, count: int) -> None:
        """Count `count` more units done."""
        self.done += count
        now = time.monotonic()
        elapsed = max(now - self.start, 1e-9)
        if self.callback is not None:
            self.callback(self.done, (self.done - self.already) / elapsed)
        if self.first is not None:
            _write(self.stream, f"{elapsed:.1f} s\n")
            self.first = None
        if self.stream is None:
            return
        if _terminal(self.stream):
            if self.bar is None:
                self.bar = tqdm(
                    total=self.total,
                    initial=self.already,
                    unit=f" {self.unit}",
                    file=self.stream,
                    dynamic_ncols=True,
                    mininterval=0.2,
                )
                self.bar.start_t -= now - self.start  # elapsed since the command's start
            self.bar.update(count)
        elif now - self.logged >= LOG_EVERY or self.done >= self.total:
            self.logged = now
            self._line(now)

    def _line(self, now: float) -> None:
        """One plain progress line (a log's)."""
        meter = tqdm.format_meter(
            self.done,
            self.total,
            now - self.start,
            ncols=80,
            unit=f" {self.unit}",
            initial=self.already,
            ascii=True,
        )
        _write(self.stream, meter + "\n")
        self.shown = self.done

    def close(self) -> None:
        """End the bar (or the phase line still open); a log's last line has the count."""
        if self.first is not None:
            _write(self.stream, "stopped\n")
            self.first = None
        if self.bar is not None:
            self.bar.close()
        elif self.shown != self.done and not _terminal(self.stream):
            self._line(time.monotonic())


def compute(tasks, *, counts, progress: Progress) -> tuple:
    """`dask.compute(*tasks)` of delayed tasks, counting `counts[i]` when task i ends.

    On the dask client in use (`distributed.Client.current`) if there is one, else on
    dask's local scheduler (threads). Returns the tasks' results in order.
    """
    try:
        client = Client.current()
    except ValueError:
        client = None
    if client is None:
        weight = {task.key: count for task, count in zip(tasks, counts, strict=True)}

        def done(key, result, dsk, state, worker):
            if key in weight:
                progress.update(weight[key])

        with Callback(posttask=done):
            return dask.compute(*tasks)
    futures = client.compute(list(tasks))
    weight = {future.key: count for future, count in zip(futures, counts, strict=True)}
    for future in as_completed(futures):
        progress.update(weight[future.key])
    return tuple(client.gather(futures))
