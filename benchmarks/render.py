"""Render speed: time per sample over the time of one rfft2+irfft2 pair of the same size.

Both are measured in the same run, interleaved round by round (one render, one pair of
each FFT), each timed once per round the same way, and the medians are compared (the
machines are shared and noisy: the ratio is the figure to quote). Times are the process's
CPU time (the render and the FFTs run on one thread), which other processes on the machine
disturb far less than the wall clock. The multi-scale sea (issue #14: the default cascades
over the same finest grid, sub-grid slopes) is also timed against the single patch of the
same grid (``surface.coarse_patches: []``), in the same rounds; its target is at most 1.5
times the single patch. The reference pair is numpy.fft on float32 (scipy.fft's, faster, is
printed too; the renderer uses scipy.fft). Usage, from the repository root (so that its
``workers`` are imported): ``python -m benchmarks.render [--sizes 128 256 512] [--mode
absolute]``.

The price of linear spreading (issue #9: two-level planes wide enough that no light
wraps around, a round-trip filter per gate, the beam's tail): on the 2-core machine,
normalised mode (the figures before it: 6.4 / 21.6 / 132 ms at 128 / 256 / 512 pixels,
ratios 28 / 36 / 57), now 13 / 42 / 171 ms, ratios 57 / 76 / 106 (measured once, wall
clock). Absolute radiometry adds the cost of Poisson draws at large means (about 20 ms a
256² sample).

Issue #10, compiled splats and gathers (`workers.kernels`), the beam tail spread once per
plane, FFT passes skipped on rows without light or not read: CPU time, sphere, two runs
each on the loaded 2-core machine (load 5–6), the code before / after:

====== ============== ============== ============ ============
pixels ms before      ms after       scipy ratio  numpy ratio
====== ============== ============== ============ ============
128    13.9–16.3      9.2–11.0       115–132 →    57–60 →
                                     75–82        41–43
256    44.2–47.0      28.6–30.0      134 → 79–83  79–80 → 47–49
512    182–198        101–107        156–162 →    97–99 → 50
                                     87–89
====== ============== ============== ============ ============

The spectra alone now take about 8.5 ms a 256² sample and 29 ms a 512² one, some 24
scipy pairs at both sizes: the fine planes the linear spread needs (up to 486² cells for
the deepest gates at 256²) set that floor.
"""

import argparse
import statistics
import time

import numpy as np
import scipy.fft

import workers
from service.tuning import tune_allocator
from workers.render import render
from workers.scene import Scene


def scene(n, *, target="sphere", mode="normalised", single=False):
    # The finest patch covers the ~4 m footprint at every size (n points, 4.1 m / n apart);
    # `single`: that patch alone, else the default coarser cascades too.
    radiometry = {"mode": mode}
    if mode == "normalised":
        radiometry["white_plane_photons"] = 13.0
    surface = {"grid_size": n, "spacing": 4.1 / n}
    if single:
        surface["coarse_patches"] = []
    return Scene.model_validate(
        {
            "surface": surface,
            "target": {"shape": target},
            "receiver": {"pixels": n},
            "radiometry": radiometry,
        }
    )


def timed(function):
    start = time.process_time()
    function()
    return time.process_time() - start


def measure(n, target, rounds, mode):
    s = scene(n, target=target, mode=mode)
    one = scene(n, target=target, mode=mode, single=True)
    a = np.random.default_rng(0).standard_normal((n, n), dtype=np.float32)
    render(s, seed=0)
    render(one, seed=0)
    samples, singles, numpy_pairs, scipy_pairs = [], [], [], []
    for seed in range(1, rounds + 1):
        samples.append(timed(lambda seed=seed: render(s, seed=seed)))
        singles.append(timed(lambda seed=seed: render(one, seed=seed)))
        numpy_pairs.append(timed(lambda: np.fft.irfft2(np.fft.rfft2(a), s=a.shape)))
        scipy_pairs.append(timed(lambda: scipy.fft.irfft2(scipy.fft.rfft2(a), s=a.shape)))
    return (
        len(s.sea().patches),
        statistics.median(samples),
        statistics.median(singles),
        statistics.median(numpy_pairs),
        statistics.median(scipy_pairs),
    )


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--sizes", type=int, nargs="+", default=[128, 256, 512])
    parser.add_argument("--rounds", type=int, default=25)
    parser.add_argument("--mode", choices=["normalised", "absolute"], default="normalised")
    args = parser.parse_args()
    print(
        f"allocator tuned: {tune_allocator()}; six ML(DC) gates, 0.3 m sphere at 5 m, "
        f"coastal water, {args.mode} radiometry; workers from {workers.__path__[0]}"
    )
    print(
        f"{'pixels':>6} {'target':>7} {'cascades':>8} {'sample ms':>10} {'1 patch ms':>10} "
        f"{'ratio':>6} {'numpy pair ms':>14} {'ratio':>6} {'scipy pair ms':>14} {'ratio':>6}"
    )
    for n in args.sizes:
        for target in ("sphere", "none"):
            cascades, sample, single, numpy_pair, scipy_pair = measure(
                n, target, args.rounds, args.mode
            )
            print(
                f"{n:>6} {target:>7} {cascades:>8} {sample * 1e3:>10.1f} {single * 1e3:>10.1f} "
                f"{sample / single:>6.2f} {numpy_pair * 1e3:>14.3f} "
                f"{sample / numpy_pair:>6.1f} {scipy_pair * 1e3:>14.3f} "
                f"{sample / scipy_pair:>6.1f}"
            )


if __name__ == "__main__":
    main()
