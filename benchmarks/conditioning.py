"""Conditioning cost: a sample conditioned on 100 measured points over an unconditioned one.

The same scene with and without ``surface.conditioning`` (100 points scattered over the
finest patch, elevations drawn from the sea's own variance, 1 mm noise), measured in one
run, interleaved round by round, medians compared (the machines are shared and noisy: the
ratio is the figure to quote). Two costs: the whole rendered sample (``render``) and the
surface synthesis alone (``draw``, ``Kriging.condition``, ``Modes.surface``), the part
conditioning changes, over every cascade of the default multi-scale sea; the kriging system
is built once per scene (cached) and reported apart. ``--times`` spreads the points over that
many distinct measurement times (one extra irfft2 + rfft2 each).
Usage: ``python benchmarks/conditioning.py [--sizes 128 256 512] [--times 1]``.
"""

import argparse
import statistics
import time

import numpy as np

from service.tuning import tune_allocator
from workers.render import render
from workers.sea.conditioning import kriging
from workers.sea.surface import draw
from workers.settings.scene import Scene
from workers.setup.seasetup import scene_sea, surface_kriging


def scenes(n, points, times):
    # As benchmarks/render.py: the finest patch covers the ~4 m footprint at every size.
    base = {"surface": {"grid_size": n, "spacing": 4.1 / n}, "receiver": {"pixels": n}}
    free = Scene.model_validate(base)
    rng = np.random.default_rng(0)
    std = np.sqrt(scene_sea(free).spectrum.variance())
    patch = 4.1 * (1 - 1e-9)
    data = [
        [x, y, e, t]
        for x, y, e, t in zip(
            rng.uniform(0, patch, points),
            rng.uniform(0, patch, points),
            std * rng.standard_normal(points),
            np.repeat(np.arange(times) * 0.1, -(-points // times))[:points],
            strict=True,
        )
    ]
    surface = {**base["surface"], "conditioning": {"points": data, "noise": 0.001}}
    return free, Scene.model_validate({**base, "surface": surface})


def timed(function):
    start = time.perf_counter()
    function()
    return time.perf_counter() - start


def measure(n, points, times, rounds):
    free, tied = scenes(n, points, times)
    kriging.cache_clear()
    sea = scene_sea(tied)
    build = timed(lambda: surface_kriging(tied.surface, sea))
    system = surface_kriging(tied.surface, sea)
    render(free, seed=0)
    render(tied, seed=0)
    columns = {"render free": [], "render tied": [], "surface free": [], "surface tied": []}
    for seed in range(1, rounds + 1):
        columns["render free"].append(timed(lambda seed=seed: render(free, seed=seed)))
        columns["render tied"].append(timed(lambda seed=seed: render(tied, seed=seed)))
        rng = np.random.default_rng(seed)
        columns["surface free"].append(timed(lambda rng=rng: draw(sea, rng).surface()))
        rng = np.random.default_rng(seed)
        columns["surface tied"].append(
            timed(lambda rng=rng: system.condition(draw(sea, rng), rng).surface())
        )
    return build, {name: statistics.median(values) for name, values in columns.items()}


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--sizes", type=int, nargs="+", default=[128, 256, 512])
    parser.add_argument("--points", type=int, default=100)
    parser.add_argument("--times", type=int, default=1)
    parser.add_argument("--rounds", type=int, default=25)
    args = parser.parse_args()
    print(
        f"allocator tuned: {tune_allocator()}; {args.points} points at {args.times} time(s), "
        "Elfouhaily 5 m/s, six ML(DC) gates, 0.3 m sphere at 5 m"
    )
    print(
        f"{'grid':>5} {'system ms':>10} {'render ms':>10} {'tied ms':>8} {'ratio':>6} "
        f"{'surface ms':>11} {'tied ms':>8} {'ratio':>6}"
    )
    for n in args.sizes:
        build, t = measure(n, args.points, args.times, args.rounds)
        print(
            f"{n:>5} {build * 1e3:>10.1f} {t['render free'] * 1e3:>10.1f} "
            f"{t['render tied'] * 1e3:>8.1f} {t['render tied'] / t['render free']:>6.2f} "
            f"{t['surface free'] * 1e3:>11.2f} {t['surface tied'] * 1e3:>8.2f} "
            f"{t['surface tied'] / t['surface free']:>6.2f}"
        )


if __name__ == "__main__":
    main()
