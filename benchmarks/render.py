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
absolute]``. A sample is timed as a store's task renders it (`workers.render.render_arrays`);
until 2026-11-24 the tables below timed `workers.render.render`, which also builds the
sample's dataset (about 1 ms at 128 pixels, 1.3 ms at 256).

The price of linear spreading (issue #9: two-level planes wide enough that no light
wraps around, a round-trip filter per gate, the beam's tail): on the 2-core machine,
normalised mode (the figures before it: 6.4 / 21.6 / 132 ms at 128 / 256 / 512 pixels,
ratios 28 / 36 / 57), now 13 / 42 / 171 ms, ratios 57 / 76 / 106 (measured once, wall
clock). Absolute radiometry adds the cost of Poisson draws at large means (about 20 ms a
256² sample).

Issue #10, compiled splats and gathers (`workers.backends.kernels`), the beam tail spread once per
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

Issue #10, render near the floor, second pass: the sample's dataset in one xarray
constructor, the sea sampled at the rays by one compiled pass per cascade and field, the
sub-grid slopes' cell hash compiled, the gates' shared gain terms computed once, the target
and ring means on the mask's box, the coarse level's few lit rows convolved by direct
column sums in place of two column FFT passes (images within 3.2e-7 of an image's largest
value; everything else the same bytes), block means only where light is. One run each,
back to back, CPU time, sphere / no target, on the 2-core machine at load 1.6–1.9; the code
before (f81312b) / after. The same code f81312b gives larger ratios today than the table
above measured for it (111 against 79–83 at 256²): the pair and the render do not slow
alike with the machine's state, so compare ratios only within one table.

====== ======= ============ ============ ================= =================
pixels target  ms before    ms after     scipy ratio       numpy ratio
====== ======= ============ ============ ================= =================
128    sphere  22.2         16.6         108.6 → 88.5      67.4 → 54.2
128    none    18.8         13.1         88.9 → 70.6       57.5 → 42.4
256    sphere  53.9         44.5         110.9 → 93.2      69.7 → 60.2
256    none    42.4         34.5         91.7 → 74.8       53.0 → 46.1
512    sphere  191.3        164.0        118.4 → 101.2     72.0 → 65.5
512    none    162.6        131.9        99.3 → 80.4       63.7 → 54.4
====== ======= ============ ============ ================= =================

Where a 256² sphere sample's 44 ms go now (CPU, measured by wrapping the functions): the
spreads' FFTs 10.9 ms (about 23 scipy pairs: fine planes of 324²–486² cells, the floor of
the present plane sizes), gathers 7.5 ms (assembly and bilinear reads, with the window
search), splats 4.6 ms, the rays through the sea 5.6 ms, the sea's synthesis 5.3 ms, shot
noise 2.0 ms, the dataset and its means 2.0 ms, the rest (target maps, hiding, gains,
Python) about 6 ms. The 30-pair target (14 ms) is below the FFTs plus one pass of the
rays over seven planes; closing it needs smaller fine planes (the guard of four coarse
cells on every side is sized for light anywhere on the plane, while the traced lattice
lights and the pixels read little more than the image) and fewer passes over the rays
(each ray is located once per plane, seven times), not faster loops.

Shot noise at large means, still exact (`workers.receiver.noise.poisson_counts`: compiled
sequential
search for 1 < λ < 10, vectorised over blocks of values, and Hörmann's PTRS for λ >= 10, in
place of ``rng.poisson``): the draws alone, CPU time, old and new interleaved, medians of 61
rounds, take 5.4 → 3.1 ms on the 98304 expected counts of the 128-pixel sweep scene
(`benchmarks/sweep.py`: 18k of them in (1, 10), 80k above) and 21.5 → 11.9 ms on those of
this script's 256² absolute scene (130k in (1, 10), 260k above). This script with
``--sizes 128 256 --mode absolute``, two runs each, alternating, the code before (36a2e5a)
/ after, CPU time, on the 2-core machine at load 0.9–2.1:

====== ======= ============ ============ ================= =================
pixels target  ms before    ms after     scipy ratio       numpy ratio
====== ======= ============ ============ ================= =================
128    sphere  22.5, 21.6   19.7, 19.0   105–106 → 94–99   71–72 → 63–64
128    none    18.7, 17.7   16.5, 15.6   87–91 → 70–82     56–60 → 50–52
256    sphere  64.3, 62.3   54.1, 54.5   136–137 → 114–116 89–91 → 78
256    none    55.5, 54.2   44.8, 46.0   116–117 → 95      73–77 → 59–62
====== ======= ============ ============ ================= =================

Second session of 2026-11-24 (`render_arrays`, no dataset; a monostatic scene's pixel
window found in the splat's pass): CPU time, sphere / no target, two runs at load 1.3–1.6,
scipy ratio 88 / 68 at 128 px (88.5 / 70.6 before), 89–91 / 72–73 at 256 (93.2 / 74.8),
99.7 / 80.7 at 512 (101.2 / 80.4). The 30-pair target at 256² is not in reach of such
steps: see the FFT floor above.

Third session of 2026-11-24, the quiet machine (load 0.4–0.7): scipy ratio 88.6 / 68.3 at
128 px, 88.7 / 71.9 at 256, 100.1 / 81.5 at 512 (sphere / none), unchanged. Where a sample
goes, in scipy pairs of its size (CPU time by wrapping the functions, 15 samples, sphere;
256² / 512²): the spreads' FFT passes 22.3 / 22.5, the sea's synthesis (the multi-scale
cascades of issue #14) 11.0 / 11.4, the rays through the sea 11.4 / 11.5, splats 13.6 /
15.1, the gathers' reads and assembly 12.0 / 13.7, shot noise 4.0 / 4.6, the arrays 1.6 /
1.5, the rest (target maps, hiding, gains) about 12. The FFTs of the linear spread's
planes and the sea's synthesis alone come to 33–34 pairs at both sizes, above the issue's
30 (256²) and near its 35 (512²): the target needs another spreading scheme (smaller fine
planes: a third level, or a near kernel narrower than four coarse cells) and a cheaper sea,
both image-changing, not faster loops.

Issue #24 item 1 (the laser lattice offset from the pixels' lines of sight, which are now
traced through the sea on their own; a Gaussian in each plane's spread for the read scale):
this script with ``--sizes 128 256 --rounds 15``, the code before (051395d) and after run
alternately, twice each, CPU time, on the shared 2-core machine (load about 2). Milliseconds
a sample, before → after: 12.4, 12.5 → 13.9, 15.5 (128, sphere); 9.9, 10.4 → 11.3, 11.9
(128, none); 34.2, 33.5 → 39.3, 41.1 (256, sphere); 27.9, 30.3 → 33.2, 34.5 (256, none):
1.12–1.24 times. Scipy ratios 85.6, 82.9 → 89.5, 86.3; 67.8, 66.1 → 78.4, 74.7; 82.5, 87.9 →
93.2, 89.9; 67.6, 74.3 → 80.2, 79.9 (1.04–1.19 times). Two lines of sight a pixel and side
(the texture's remedy, docs/model.md §3) took about 1.9 times in a prototype (128 pixels, no
target, one run).

Issue #24 (a sample with a target also yields its target-free twin, for the target's
effect and its visibility labels: `workers.render.render_arrays`, gathered from the same
spread light in the same pass), with items 1-5 (the lattice offset and read scale, the
Fournier-Forand spread, the shadows, the gated shares and delays): one run, loaded
machine, ``--sizes 128 256``, numpy-pair ratios before (051395d) → after: sphere 49.6 →
57.2 at 128 px, 58.0 → 62.1 at 256 (1.15 and 1.07 times); no target 38.8 → 41.4, 45.3 →
48.2. Rendering the twin apart, as a second sample, had cost 1.6-1.9 times.

Issue #28 item 4 (the CPU renderer at the floor), 2026-11-25. Where a sphere sample goes
(CPU time by wrapping the functions, 20 samples at 256², 8 at 512², load about 1; ratio
91.6 / 110 in that run), in scipy pairs of its size, 256² / 512²: the gathers (assembly
and bilinear reads, 14 a sample) 18.7 / 21.1, the rays through the sea 16.7 / 19.7, the
spreads' FFT passes 16.2 / 19.0, the sea's synthesis 10.3 / 10.3, splats 8.0 / 9.4, the
mask's and shadows' reads 6.7 / 7.4, shot noise 3.5 / 6.3, the arrays 2.2 / 2.0, the rest
(gains, target maps, Python) 8.7 / 14.3. Nine tenths of the FFT passes are the fine
planes' column passes (320²–360² cells at 256 px, 648²–720² at 512); the coarse level
costs about one pair. Half the sea is its normals (2N² per cascade), half the inverse FFTs.

The fine planes are not wider than where the light is read. Over 20 seas of this scene
(256 px) the pixels' lines of sight move from their flat-sea place on the planes (5 m to
13.4 m) by 10–22 fine cells (median), 27–62 (99 %) and 39–90 (99.99 %), against guard
bands of 32–52 cells; 3e-5 to 1.3e-3 of them leave the fine grid (they read nothing
there) and 0.3–11 % lie within the near spread's support (four coarse cells) of its edge.
Planes sized to the lit lattice and the image alone would move those pixels; planes that
hold the lines' 99.99 % drift and the near support would be wider than today's at the deep
gates (at 512 px the drift doubles in cells: 72–165 at 99.99 %, guards 64–104). So the
planes keep their size (`tests/test_spread.py` checks that planes with four times the
guard move no pixel beyond the two levels' own error, and goes red on a guard of one
coarse cell). Not even their rounding is waste: at 512 px four of the seven planes fit
in 640² with another coarsening factor (today 648² and 720², about 1.3 pairs), but the
images then moved by up to 0.19 of a gate's peak (8.1 m, 720² → 640²): the rounding
holds lines of sight the waves push out. The coarser cascades, whose bands end at a
quarter of their Nyquist wavenumber, now draw normals only for the square of modes that
holds the band (1/16 of them). The sea alone, old and new interleaved in one process (41
rounds, medians, load 5): 14.3 → 10.3 pairs at 128 px (three cascades), 10.7 → 8.2 at
256, 11.2 → 8.3 at 512 (the finest cascade and a single patch keep their bytes). This
script, the code before (7ebc7d2) and after run alternately, twice each, CPU time, on the
shared 2-core machine at load 6–7 (too loaded for a 3 % change to show in the ratios to
the pair; the multi-scale sea's cost over the single patch, timed in the same rounds,
shows it):

====== ======= ======================= =====================
pixels target  scipy ratio             sea / 1 patch
====== ======= ======================= =====================
128    sphere  97.0, 96.4 → 91.5, 92.6 1.18, 1.20 → 1.15, 1.16
128    none    72.7, 72.4 → 69.7, 65.5 1.27, 1.25 → 1.22, 1.22
256    sphere  101, 103 → 105, 103     1.09, 1.11 → 1.06, 1.06
256    none    80.6, 70.2 → 68.2, 73.9 1.26, 1.17 → 1.16, 1.11
512    sphere  113, 113 → 114, 110     1.12, 1.11 → 1.05, 1.06
512    none    80.0, 82.7 → 73.6, 80.4 1.15, 1.15 → 1.12, 1.11
====== ======= ======================= =====================

The same samples with the old draw and the new interleaved in one process (31 rounds,
medians, load 11): old/new 1.04 / 1.05 at 128 px (sphere / none), 1.02 / 1.05 at 256,
1.03 / 1.05 at 512; scipy pairs 78.1 → 75.4, 89.0 → 87.4, 110.6 → 106.6 (sphere).

The floor of this design is far above the issue's 30 pairs (aim 20) at 256²: without any
FFT and sea at all a sample would still cost about 65 pairs (256²) and 81 (512²), and
the spreads' FFTs on planes that hold the light are some 16–19 pairs alone. What would
reach it is fewer passes over the rays, not smaller planes: each laser ray and each
pixel's line is located and interpolated on seven planes (splats, gathers and reads, 33
pairs at 256²) and traced through every cascade at each fixed-point step (17 pairs). One
location per ray for all planes (a line is affine in depth), the six gates gathered in
one pass over the pixels, and the cascades summed over the footprint once before the
surface iteration are the changes to make. Even then the FFT passes of the present planes
(about 20 pairs a sample, all FFTs counted) leave the aim of 20 out of reach of the
two-level spread as it is.

Issue #36 item 2 (the target read through the resolved sea with the sub-grid sway, one
more trace of the pixels' lines with a target; its gates moved by the sea's height over
it): on the loaded 2-core machine (load 8–10) the medians jump by ±15 % between runs of
the same code (the target-free samples, whose code did not change, read 44–58 pairs), so
the code before (05c28fd) and after were also timed by a plain loop, alternated twice,
CPU time, 128 px, coastal, the 5 m/s sea: medians over 40 new seas 30.6, 30.3 ms before,
27.6, 32.3 after; the same seas again 32.6, 29.7 before, 27.7, 33.3 after: the same within
the noise. The first ten seas of a scene cost 38.6, 42.6 ms against 22.9, 31.3: each new
centimetre of the sea's height over the target integrates the gates that cut the target
once (about 5 ms, `workers.fast.targetgating.TargetGating`), kept for the scene's later samples.
Since each step's depths (on time and late, both gate edges) go through one
`workers.targets.impostor.disc_cover` (the same bytes), a step takes 1.3 ms at 32 px and 2.0 ms at
128 px where it took 6.1 and 7.4 (the test's 10 m/s scene, 20 new steps); the first ten
seas over the same seas again, 128 px, coastal, 5 m/s, two alternated runs: 1.18, 1.13
after, 1.23, 1.28 before (the medians themselves moved by ±25 % between runs).
Over a rough sea the shadows' facets rule (`workers.fast.shadows._through_facets`, 32 nodes a
gate) is built with a frame's geometry, once per scene and frame: 0.31 s at 128 px and
1.1 s at 256 px of CPU time where the geometry took 0.13 and 0.55 s (the test's 10 m/s
scene; a sweep that changes the scene every sample pays it every sample).

Issue #39, torch's host traffic (torchops branch; numpy's bytes unchanged): callgrind
instructions of one 256² sample (sphere, normalised; a warm-up render first, the sample
alone collected, ``--toggle-collect=starmap_next``), one thread: main (a12c210) 626.89 M,
torchops 626.98 M (+0.015 %: the array API's ``clip`` for the images' floor and a
``where``; every compiled kernel and FFT the same count), against a scipy.fft float32
rfft2 + irfft2 pair of 256² counted the same way, 4.37 M: 143.4 and 143.5 pairs. Torch's
operators are counted by `benchmarks/torch_ops.py`.

Issue #39 item "rays through the sea" (`workers.setup.interface.surface_hit`: the fixed-point
steps in one compiled kernel, `workers.backends.kernels.surface_hits`; on torch a fixed count
of 8 steps, no host read; the pixels' lines through the resolved sea share the hits and
cascades' slopes of those through the sea; numpy bytes unchanged). Callgrind instructions of
the rays through the sea of one frame (`workers.fast.stages._sea_rays`, this script's 256²
sphere scene: 73 984 laser rays, 65 536 pixels' lines), 5 frames counted after a warm-up, over
a scipy.fft float32 rfft2 + irfft2 pair of 256² (4.82 M instructions): 28.05 → 23.19 pairs
(135.3 M → 111.8 M). The numba sea samples 18.1 → 14.5 pairs (elevations and slopes
12.3, the steps' own loops 2.2), np.where 3.5 → 3.1, the sub-grid hash 0.65 (unchanged). A
whole sample (3 after a warm-up): 128.5 → 123.6 pairs (619.6 M → 596.1 M). The steps needed
(`docs/model.md` §3): 1–3 over the shipped configurations, 1–2 at nadir, up to 6 at 40°. On
torch (CPU) the rays through the sea of a 256² frame take 1 649 operators and no host read
(main: 1 703 and 6).

Issue #39 items 1-2, CPU part (fewer passes over the lines of sight): a gate's field is
assembled once and read at each line of sight for the image and its target-free twin in
one pass (`workers.backends.kernels.gather_levels` takes every output), the gates' `unseen`
maps are read in one pass (one `kernels.sample`), `span` and `outside_rows` are one pass
(`kernels.reach`); then the kernels index cells unsigned (numba's negative-index
wraparound off). The same bytes (32 samples: 64-256 px, sphere / none, flat / 5 / 10 m/s).
Callgrind, one sample of ``scene(256)`` (sphere) after two warm-up renders, each stage's
own instructions in scipy float32 rfft2+irfft2 pairs of 256² counted the same way (4.38 M
instructions), main (a12c210) → the passes → unsigned indices: gathers 31.3 → 19.5 →
11.7, splats 12.9 → 12.9 → 11.5, reach 4.9 → 3.7, the hidden and mask reads 6.8 → 2.8; the
sample 143.2 → 126.3 → 117.0 (this count, toggled around the one render, reads more than
the issue's 118 for main: compare within it). At 512² (pair 19.8 M instructions), main →
unsigned: gathers 26.6 → 10.0, splats 10.4 → 9.2, reach 4.1 → 3.2, reads 6.0 → 2.5; the
sample 117.7 → 95.4. Splatting every gate plane in one loop over
the rays (each ray's crossing of every plane in turn, the same bytes) was slower on one
core, 10.6-11.4 ms against 6.2-6.4 ms for the six planes one by one (a plane's 0.4-0.5 MB
fields stay in cache while it is splatted alone; with all the planes in one flat buffer,
its deposits alone took 3.4-4.7 ms against 3.1-3.8 ms for the whole per-plane splats): not
kept.

Issue #39, the three merged (torch's scalars, the rays' hits, the passes above), the whole
sample by callgrind (valgrind 3.19; a warm-up render, then ``callgrind_control -d`` dumps
around 8 renders of seeds 1-8 and around 20 scipy float32 pairs of 256², so the seas'
first target gating steps are in both): main (a12c210) 6.05e8 instructions a sphere sample,
138.7 pairs (no target 3.61e8, 82.7); merged (8b83e63) 4.68e8, 107.3 pairs (-23 %; no
target 3.45e8, 78.9, -5 %: the one gather and the one hidden read pay where a target is). CPU
time, 128 px, batches of 4, medians of 3, one thread, loaded machine: numpy + numba 17.7 →
15.5 ms a sample; torch on the CPU 111.9 → 116.6 ms (its 8 fixed steps through the sea),
6.3 → 7.5 times numba. The issue's targets (at most 45 pairs at 256², torch within 1.5
times numba) are not met: see issue #39's closing note for the floor.
"""

import argparse
import statistics
import time

import numpy as np
import scipy.fft

import workers
from service.tuning import tune_allocator
from workers.render import render_arrays as render
from workers.settings.scene import Scene
from workers.setup.seasetup import scene_sea


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
        len(scene_sea(s).patches),
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
