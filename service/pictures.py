"""The job pages' pictures: a finished job's statistics plot and preview strip (PNG).

A picture is drawn once, in a worker thread off the event loop, however many requests
ask for it at once (they wait for the one drawing), and kept in a cache bounded in bytes
(the least recently shown go first); at most `DRAWING` pictures are drawn at a time.
Drawing uses `service.plots` (matplotlib's object-oriented API on Agg canvases, no
pyplot), safe in several threads.
"""

from __future__ import annotations

import asyncio
import io
from collections import OrderedDict

from starlette.concurrency import run_in_threadpool

from service.records import Job
from service.store.location import Store
from service.sweep import parse_sweep

__all__ = ["KINDS", "PICTURE_BYTES", "Pictures", "preview_png", "statistics_png"]

PREVIEW_SAMPLES = 3
"""Samples drawn in a finished job's preview strip."""
PICTURE_BYTES = 64 * 2**20
"""Most bytes of pictures the cache holds."""
DRAWING = 2
"""Most pictures drawn at once (each renders samples or reads statistics)."""


def statistics_png(job: Job, data_root: Store) -> bytes:
    """The statistics plot of a finished job (`service.charts.plot_statistics`).

    Raises
    ------
    InputError
        If the sweep swept nothing: nothing to plot against.
    """
    from service import charts

    stats = data_root.other(job.url).stats.dataset().load()
    buffer = io.BytesIO()
    charts.plot_statistics(stats, buffer)
    return buffer.getvalue()


def preview_png(job: Job, data_root: Store) -> bytes:
    """The gated images of the first samples, one row each (rendered again, as stored)."""
    from PIL import Image

    from service import plots

    plan = parse_sweep(job.sweep, folder=data_root.url, max_memory=None)
    rows = [
        plots.figure_pixels(
            plots.preview_figure(plots.render_preview(plan, sample), title=f"sample {sample}")
        )
        for sample in range(min(PREVIEW_SAMPLES, plan.samples))
    ]
    strip = Image.new("RGB", (max(r.width for r in rows), sum(r.height for r in rows)), "white")
    for index, row in enumerate(rows):
        strip.paste(row, (0, sum(r.height for r in rows[:index])))
    buffer = io.BytesIO()
    strip.save(buffer, format="PNG")
    return buffer.getvalue()


KINDS = {"statistics": statistics_png, "preview": preview_png}
"""How each picture of a job page is drawn, by its name."""


class Pictures:
    """Finished jobs' pictures, each drawn once, the most recently shown kept.

    Used from the server's event loop alone (no lock: its coroutines take turns).

    Parameters
    ----------
    data_root : Store
        The service's data root (the stores, and the sweeps' measurement files).
    max_bytes : int
        Most bytes of pictures kept.
    """

    def __init__(self, data_root: Store, *, max_bytes: int = PICTURE_BYTES):
        self.data_root, self.max_bytes = data_root, max_bytes
        self._kept: OrderedDict[tuple[str, str], bytes] = OrderedDict()
        self._drawing: dict[tuple[str, str], asyncio.Task] = {}
        self._slots = asyncio.Semaphore(DRAWING)

    async def get(self, job: Job, kind: str) -> bytes:
        """The picture `kind` (one of `KINDS`) of `job`, drawn if nobody has yet.

        Raises
        ------
        InputError
            As the drawing raises it (to every request that waited for it).
        """
        key = (job.id, kind)
        if key in self._kept:
            self._kept.move_to_end(key)
            return self._kept[key]
        if key not in self._drawing:
            self._drawing[key] = asyncio.ensure_future(self._draw(key, job, kind))
        # a request that goes away leaves the drawing to those that wait for it
        return await asyncio.shield(self._drawing[key])

    async def _draw(self, key: tuple[str, str], job: Job, kind: str) -> bytes:
        try:
            async with self._slots:
                picture = await run_in_threadpool(KINDS[kind], job, self.data_root)
        finally:
            del self._drawing[key]
        self._kept[key] = picture
        while sum(map(len, self._kept.values())) > self.max_bytes:
            self._kept.popitem(last=False)
        return picture
