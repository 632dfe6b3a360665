"""Monte Carlo renderer speed: photons per second per core, and time to a 2 % error.

For each water (clear, coastal, turbid) and sea (flat, 5 m/s), a 64-pixel ML(DC) scene with
a 0.3 m sphere at 5 m (the quickstart's) is rendered by photon transport
(`workers.montecarlo.renderer`), one frame, on one core (the kernels are sequential). Printed:

- photons per second of CPU time in the transport kernel, and for the whole frame
  (launch through the surface, the pixels' lookup, transport, the batches' statistics);
- per gate, the median relative standard error of the 4 × 4-pixel block means over the
  blocks the beam lights (block mean above a tenth of the brightest block), and the time
  it would take to bring it to 2 % (the error falls as 1/√photons: time × (error/2 %)²);
- the same for the light over the target's mask in gate 2, whose top (4.9 m) cuts the
  sphere (the estimator's hard case: forward-scattered light of the target, docs/model.md
  §9), its error from the pixels' errors as if independent;
- the same for the FFT of the same size, as a yardstick of the machine's speed (one
  64² float32 rfft2+irfft2 pair, scipy.fft).

Usage, from the repository root: ``python -m benchmarks.transport [--photons 2000000]
[--waters coastal] [--winds 0 5]``.

Figures (2-core machine, load 0.6-1.8, 10⁶ photons, one run each, 2026-11-24; the FFT pair
of 64² took 35 µs in the same runs):

=============== ====== ============= ============= ==================================
water           sea    photons/s     photons/s     time to a 2 % error on 4 × 4 blocks,
                       (transport)   (a frame)     gates 1-6 [s]
=============== ====== ============= ============= ==================================
clear ocean     flat   2 150 000     1 680 000     1, 6, 6, 8, 12, 14
clear ocean     5 m/s  448 000       394 000       11, 35, 30, 36, 41, 44
coastal         flat   481 000       452 000       230, 24, 36, 62, 116, 165
coastal         5 m/s  103 000       100 000       448, 385, 440, 588, 985, 2693
turbid harbour  flat   160 000       157 000       1019, 4847, 7296, 11850, ... (starved)
turbid harbour  5 m/s  81 000        79 000        starved: most blocks hold one batch
=============== ====== ============= ============= ==================================

The target's light over its mask in gate 2, flat sea, 10⁶ photons (2026-11-28, load 8 on
two cores): coastal 4.3 % (20 s to 2 %), clear 2.4 % (1 s); before the target's reflection
was biased toward the receiver (issue #36) the same runs reported 16.8 % (258 s) and
11.2 % (27 s), and the runs' real spread was several times their reported error
(heavy-tailed, docs/model.md §9). The gates' 4 × 4 blocks in the same runs: coastal
7.2, 7.2, 8.3, 9.9, 14.3, 16.4 % (before 12.0, 7.4, 8.3, 9.9, 14.4, 16.5 %).

Over a rough sea a local estimate is found in 4-5 cells' triangles on average (the lines
fold under focusing waves at these depths) among about 50 candidates, against 1 among 5
over a flat sea: that, not the photons' flights, is where the time goes (the kernel without
its estimates runs 0.8-0.9 million photons/s in coastal water over either sea). The first
gate's error in coastal water is the forward-scattered light of photons heading at the
receiver (docs/model.md §9).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.fft

from workers.montecarlo import renderer as montecarlo
from workers.settings.scene import Scene
from workers.settings.seeds import SampleSeed
from workers.setup.builder import scene_setup


def scene(water: str, wind: float, photons: int) -> Scene:
    """The benchmark's scene: the quickstart's sphere, 64 px, Monte Carlo."""
    surface = (
        {"spectrum": "flat"}
        if wind == 0
        else {"spectrum": "elfouhaily", "wind_speed": wind, "grid_size": 128, "spacing": 0.032}
    )
    return Scene.model_validate(
        {
            "surface": surface,
            "water": {"preset": water},
            "target": {"shape": "sphere", "radius": 0.3, "depth": 5.0, "reflectance": 0.2},
            "receiver": {"pixels": 64},
            "radiometry": {"mode": "normalised", "white_plane_photons": 0.0},
            "transport": {"method": "monte_carlo", "photons": photons, "batches": 16},
        }
    )


def block_errors(expected: np.ndarray, stderr: np.ndarray) -> np.ndarray:
    """Median relative standard error of the lit 4 × 4 blocks' means, per gate."""
    gates, size, _ = expected.shape
    blocks = size // 4
    mean = expected.reshape(gates, blocks, 4, blocks, 4).mean(axis=(2, 4))
    error = np.sqrt((stderr.reshape(gates, blocks, 4, blocks, 4) ** 2).sum(axis=(2, 4))) / 16
    out = []
    for g in range(gates):
        lit = mean[g] > 0.1 * mean[g].max()
        out.append(np.median(error[g][lit] / mean[g][lit]))
    return np.array(out)


def fft_pair_seconds(size: int, rounds: int = 200) -> float:
    """Median CPU time of one float32 rfft2 + irfft2 pair of size² [s]."""
    field = np.random.default_rng(0).random((size, size), dtype=np.float32)
    times = []
    for _ in range(rounds):
        start = time.process_time()
        scipy.fft.irfft2(scipy.fft.rfft2(field), s=field.shape)
        times.append(time.process_time() - start)
    return float(np.median(times))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--photons", type=int, default=2_000_000)
    parser.add_argument(
        "--waters", nargs="*", default=["clear_ocean", "coastal", "turbid_harbour"]
    )
    parser.add_argument("--winds", nargs="*", type=float, default=[0.0, 5.0])
    args = parser.parse_args(argv)
    kernel = {"seconds": 0.0}
    transport = montecarlo.transport

    def timed(*arguments):
        start = time.process_time()
        transport(*arguments)
        kernel["seconds"] += time.process_time() - start

    montecarlo.transport = timed
    print(f"scipy rfft2+irfft2 pair, 64² float32: {1e6 * fft_pair_seconds(64):.1f} µs")
    for water in args.waters:
        for wind in args.winds:
            s = scene(water, wind, args.photons)
            setup = scene_setup(s)
            seed = SampleSeed(root=1)
            surface = setup.surface(seed, [0.0])
            montecarlo.render_frame(setup, surface, 0, seed)  # compile, fill caches
            kernel["seconds"] = 0.0
            start = time.process_time()
            frame = montecarlo.render_frame(setup, surface, 0, seed)
            total = time.process_time() - start
            errors = block_errors(frame.expected, frame.stderr)
            to_two = total * (errors / 0.02) ** 2
            print(
                f"{water:15s} wind {wind:3.0f} m/s: {args.photons / kernel['seconds']:>10,.0f} "
                f"photons/s in transport, {args.photons / total:>10,.0f} photons/s a frame "
                f"({total:.2f} s)"
            )
            print(
                "   4x4 block error by gate "
                + " ".join(f"{100 * e:5.1f}%" for e in errors)
                + "\n   time to 2 %           "
                + " ".join(f"{t:6.0f}s" for t in to_two)
            )
            mask = frame.mask.astype(bool)
            edge = np.sqrt((frame.stderr[1][mask] ** 2).sum()) / frame.expected[1][mask].sum()
            print(
                f"   target's mask, gate 2: error {100 * edge:.1f}%, "
                f"time to 2 % {total * (edge / 0.02) ** 2:.0f}s"
            )


if __name__ == "__main__":
    main()
