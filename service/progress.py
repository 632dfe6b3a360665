"""The progress line of a run: samples done, samples/s, time left.

Kept rather than dask's progress bars (`distributed.progress`), which follow a fixed set of
futures: a run submits its tasks a window at a time, counts samples rather than tasks and
starts from the samples a resumed store already holds.
"""

from __future__ import annotations

import sys
import time

from dask.utils import format_time

__all__ = ["Progress"]


class Progress:
    """A progress line on stderr: samples done, samples/s, time left."""

    def __init__(self, total: int, already: int, stream=None, callback=None):
        self.total = total
        self.callback = callback
        self.done = already
        self.fresh = 0
        self.start = time.monotonic()
        self.stream = stream or sys.stderr
        self.last = 0.0
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()

    def update(self, count: int) -> None:
        """Count `count` more samples done."""
        self.done += count
        self.fresh += count
        now = time.monotonic()
        if self.callback is not None:
            self.callback(self.done, self.fresh / max(now - self.start, 1e-9))
        if now - self.last < (0.2 if self.tty else 5.0) and self.done < self.total:
            return
        self.last = now
        elapsed = max(now - self.start, 1e-9)
        rate = self.fresh / elapsed
        left = "?" if rate <= 0 else format_time((self.total - self.done) / rate)
        if self.done >= self.total:
            left = "0 s"
        width = 30
        filled = int(width * self.done / max(self.total, 1))
        bar = "#" * filled + "-" * (width - filled)
        line = f"[{bar}] {self.done}/{self.total} samples  {rate:.2f} samples/s  left {left}"
        self.stream.write(("\r" + line) if self.tty else line + "\n")
        self.stream.flush()

    def close(self) -> None:
        """End the progress line."""
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()
