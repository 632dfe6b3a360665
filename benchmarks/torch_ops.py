"""The torch operators a `workers.render.render_batch` dispatches, counted (issue #39).

Every ATen operator the render calls on the torch backend passes a
`torch.utils._python_dispatch.TorchDispatchMode`, which counts them (`count_ops`):

- ``ops``: all of them, ``non_view`` those that are not views (a launch each on a GPU);
- ``from_host``: tensors made from host data (``aten::lift_fresh``: ``torch.tensor`` or
  ``torch.as_tensor`` of a Python or numpy value, a host-to-device copy on a GPU; not a
  Python scalar assigned to a slice, ``t[...] = 0.0``, which fills it) and copies from
  the CPU to another device; ``scalars`` those of them that are 0-d (Python scalars);
- ``scalar_reads``: ``aten::_local_scalar_dense`` (``float(t)``, ``bool(t)``, ``t.item()``:
  the host waits for the device) and copies from another device to the CPU;
- ``tolist`` and ``numpy``: calls of ``Tensor.tolist`` and ``Tensor.numpy``, host reads
  that dispatch no operator on the CPU (counted by wrapping the two methods).

Where the host's traffic (all but the first two kinds) comes from is recorded too
(``--sites``).

Usage, from the repository root: ``python -m benchmarks.torch_ops [--sizes 64 256]
[--batches 1 16] [--device cpu]``; it prints the counts a batch and a sample for the
six-gate scene of `benchmarks.gpu` (a 0.3 m sphere at 5 m, ML(DC) gates), each batch
counted after a warm-up batch (the scene's setup and frame geometry cached, as in a run).

On the shared 2-core machine, torch 2.14 on the CPU (2026-11-29), a sample (a batch's
counts over its samples; they are rendered one after another), before (main, a12c210) and
after this branch (torchops: `workers.backends.kernels_torch`'s scalars made once per value
and device, the gates' gains on the device, `clip` for the images' floor, one host read
in `workers.fast.stages._target_frame`):

====== ===== ====== ====== ======== ========= ======= ====== ====== =====
pixels batch code   ops    non-view from host scalars reads  tolist numpy
====== ===== ====== ====== ======== ========= ======= ====== ====== =====
64     1     before 9 353  8 109    406       386     8      21     6
64     1     after  8 997  8 143    8         0       7      21     4
64     16    before 9 371  8 123    406       386     8      21     6
64     16    after  9 015  8 157    8         0       7      21     4
256    1     before 9 206  7 984    380       362     8      21     6
256    1     after  8 874  8 018    6         0       7      21     4
256    16    before 9 127  7 928    380       362     8      21     6
256    16    after  8 795  7 962    6         0       7      21     4
====== ===== ====== ====== ======== ========= ======= ====== ====== =====

What is left from the host: the sample's sea modes (two a cascade) and, where the sea
moves the gates over the target, its maps for that height (two); the reads: the sea's
height over the target (1), the rays' convergence tests through the sea (6), the planes'
windows (21 ``tolist``) and the results (4 ``numpy``). The non-view operators grow by 34
a sample: the gains of every ray and gate on the device, where the host integrated only
the rays whose slab the surface cuts.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections import Counter
from pathlib import Path

import torch
from torch.utils._python_dispatch import TorchDispatchMode

import workers
from benchmarks.gpu import scene
from workers.render import render_batch
from workers.settings.seeds import SampleSeed

KINDS = ("ops", "non_view", "from_host", "scalars", "scalar_reads", "tolist", "numpy")
"""What `count_ops` counts, in the order the table prints them."""

READS = ("scalar_reads", "tolist", "numpy")
"""The kinds that read values back to the host."""

SITED = ("from_host", "scalars", *READS)
"""The kinds `count_ops` records the sites of: the host's traffic."""

_COPIES = ("aten._to_copy.default", "aten.copy_.default")

_WORKERS = Path(workers.__file__).parent
_BACKEND = str(_WORKERS / "backends" / "backend.py")


def _site() -> str:
    """``module:function`` of the innermost caller in `workers` (``?`` if none).

    `workers.backends.backend`'s conversions are skipped: their caller is the site.
    """
    frame = sys._getframe(2)
    while frame is not None and (
        not frame.f_code.co_filename.startswith(str(_WORKERS))
        or frame.f_code.co_filename == _BACKEND
    ):
        frame = frame.f_back
    if frame is None:
        return "?"
    return f"{frame.f_globals.get('__name__')}:{frame.f_code.co_name}"


class _Counting(TorchDispatchMode):
    """Counts every operator dispatched while active: by kind, by name, reads by site."""

    def __init__(self, counts: Counter, names: Counter, sites: Counter):
        super().__init__()
        self.counts, self.names, self.sites = counts, names, sites
        self.lifted = None

    def _add(self, kind: str, step: int = 1):
        self.counts[kind] += step
        if kind in SITED:
            self.sites[kind, _site()] += step

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        result = func(*args, **kwargs)
        name = str(func)
        self._add("ops")
        self.names[name] += 1
        if name == "aten.fill_.Tensor" and args[1] is self.lifted:
            # ``t[:k] = 0.0``: a host scalar fills the slice (no copy on a GPU)
            self._add("from_host", -1)
            self._add("scalars", -1)
        if not func.is_view:
            self._add("non_view")
            self.lifted = None  # a setitem's scalar is used at once, after its slices
        if name.startswith("aten.lift_fresh"):
            self._add("from_host")
            if result.dim() == 0:
                self._add("scalars")
                self.lifted = result
        elif name == "aten._local_scalar_dense.default":
            self._add("scalar_reads")
        elif name in _COPIES:
            source = args[1] if name == "aten.copy_.default" else args[0]
            target = args[0] if name == "aten.copy_.default" else result
            if source.device.type == "cpu" and target.device.type != "cpu":
                self._add("from_host")
            elif source.device.type != "cpu" and target.device.type == "cpu":
                self._add("scalar_reads")
        return result


@contextlib.contextmanager
def count_ops():
    """Count the torch operators and host reads of the enclosed code.

    Yields
    ------
    tuple of collections.Counter
        ``(counts, names, sites)``: the counts by kind (`KINDS`), the operators by name,
        and the host's traffic (`SITED`) by kind and site (``module:function``, the
        innermost function of `workers` that made it); filled while the context is open.
    """
    counts, names, sites = Counter({kind: 0 for kind in KINDS}), Counter(), Counter()
    counting = _Counting(counts, names, sites)
    wrapped = {name: getattr(torch.Tensor, name) for name in ("tolist", "numpy")}

    def reading(name):
        method = wrapped[name]

        def call(self, *args, **kwargs):
            counting._add(name)
            return method(self, *args, **kwargs)

        return call

    try:
        for name in wrapped:
            setattr(torch.Tensor, name, reading(name))
        with counting:
            yield counts, names, sites
    finally:
        for name, method in wrapped.items():
            setattr(torch.Tensor, name, method)


def batch_ops(s, batch: int, *, device: str = "cpu") -> tuple[Counter, Counter, Counter]:
    """`count_ops` of one `render_batch` of `batch` samples of scene `s` on torch.

    A batch of one is rendered first (not counted), so that the scene's setup and its
    frame geometry are cached, as in a run.
    """
    seeds = [SampleSeed(root=7, point=0, realisation=r) for r in range(batch)]
    render_batch(s, seeds[:1], backend="torch", device=device)
    with count_ops() as counted:
        render_batch(s, seeds, backend="torch", device=device)
    return counted


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 256])
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 16])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--top", type=int, default=0, help="print the most called operators")
    parser.add_argument("--sites", action="store_true", help="print the host's traffic's sites")
    args = parser.parse_args()
    print(f"torch {torch.__version__} on {args.device}; counts a batch / a sample")
    print("pixels  batch  " + "  ".join(f"{kind:>17}" for kind in KINDS))
    for n in args.sizes:
        s = scene(n)
        for batch in args.batches:
            counts, names, sites = batch_ops(s, batch, device=args.device)
            cells = (f"{counts[kind]:>8} / {counts[kind] / batch:>6.0f}" for kind in KINDS)
            print(f"{n:>6}  {batch:>5}  " + "  ".join(cells), flush=True)
            for name, count in names.most_common(args.top):
                print(f"        {count:>8}  {name}")
            for (kind, site), count in sorted((+sites).items()) if args.sites else ():
                print(f"        {count:>8}  {kind} in {site}")


if __name__ == "__main__":
    main()
