"""Where in time the fast renderer misses turbid water's return: 1 m slabs against transport.

The turbid reference scene of `benchmarks.transport_reference` (turbid harbour water, 32 px
over 6.7° from 34 m, nadir, flat sea, no target) with 16 gates of 1 m from the surface to
16 m, rendered by the Monte Carlo renderer and by the fast renderer without its
time-resolved gains (`workers.setup.builder.time_resolved` turned off in
`workers.render`: the small-angle theory alone), once with the default laser (its field
the image's) and once with a laser of 20°, far wider than the image, which the water's
spread can no longer carry light out of.
Prints, per slab, transport's mean image, its relative error and fast / transport.

Measured on 2026-11-28 (issue #40 item 2), 3 × 10⁶ photons (51 s) and 8 × 10⁶ photons
(109 s, 20° laser), one core:

=========  ==============  ===============
slab [m]   fast / MC       fast / MC, 20°
=========  ==============  ===============
0–1        0.97 ± 0.004    0.98 ± 0.006
1–2        0.94 ± 0.009    0.92 ± 0.013
2–3        0.86 ± 0.024    0.85 ± 0.017
3–4        0.89 ± 0.019    0.82 ± 0.021
4–5        0.82 ± 0.033    0.78 ± 0.029
5–6        0.89 ± 0.035    0.76 ± 0.030
6–7        0.74 ± 0.051    0.61 ± 0.052
7–8        0.74 ± 0.045    0.66 ± 0.051
8–9        0.58 ± 0.073    0.59 ± 0.060
9–10       0.66 ± 0.11     0.46 ± 0.094
10–11      0.71 ± 0.079    0.60 ± 0.046
11–12      0.58 ± 0.11     0.50 ± 0.069
=========  ==============  ===============

The fast renderer's share falls with the light's time whatever the beam's width: the light
it misses is not spread out of the image (the wide laser lights the water far beyond it)
but returns later than the small-angle theory lets it, close to e^(−2 b_b z) (0.97, 0.90,
0.84, 0.78, 0.73, 0.68, 0.64, 0.59, 0.55 at the slabs' centres): the backscattered share
b_b that Wells' attenuation K = a + b_b counts as lost comes back in water that scatters
many times. Usage: ``python -m benchmarks.turbid_time [--photons 3e6] [--laser-deg 20]``.
"""

from __future__ import annotations

import argparse
import time
from unittest import mock

import numpy as np

from benchmarks.transport_reference import reference_scene
from workers.render import render_arrays
from workers.settings.scene import Scene

SLABS = 16
"""1 m slabs from the surface."""


def slab_scene(*, photons: int, laser_deg: float | None) -> Scene:
    """The turbid reference scene, no target, with `SLABS` 1 m gates (Monte Carlo)."""
    scene = reference_scene("turbid", photons=photons, target=False)
    data = scene.model_dump()
    data["receiver"]["gates"] = [[float(z), float(z + 1)] for z in range(SLABS)]
    if laser_deg is not None:
        data["laser"]["field_of_view_deg"] = laser_deg
    return Scene.model_validate(data)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--photons", type=float, default=3e6)
    parser.add_argument("--laser-deg", type=float, default=None, help="laser field [deg]")
    args = parser.parse_args(argv)
    scene = slab_scene(photons=int(args.photons), laser_deg=args.laser_deg)
    start = time.perf_counter()
    transport = render_arrays(scene, seed=11)
    seconds = time.perf_counter() - start
    fast_scene = scene.model_copy(
        update={"transport": scene.transport.model_copy(update={"method": "small_angle"})}
    )
    with mock.patch("workers.render.time_resolved", return_value=False):
        fast = render_arrays(fast_scene, seed=11)["expected"][0].mean(axis=(1, 2))
    image = transport["expected"][0]
    mean = image.mean(axis=(1, 2))
    error = np.sqrt((transport["expected_stderr"][0] ** 2).sum(axis=(1, 2))) / image[0].size
    print(f"{int(args.photons):,d} photons, {seconds:.0f} s")
    for z in range(SLABS):
        print(
            f"{z:2d}-{z + 1:2d} m  transport {mean[z]:.4e} ± {error[z] / mean[z]:.3f}"
            f"  fast / transport {fast[z] / mean[z]:.3f}"
        )


if __name__ == "__main__":
    main()
