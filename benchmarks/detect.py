"""What `oceanlidar detect` spends on one pair of points, before and after issue #27 item 6.

A store without its expected images has them rendered again: the sample with the target
and the target-free one of the same realisation rendered apart (`render_images` twice,
before) or in one pass (`render_pair`, now); then per pair six bootstrap intervals of the
AUC (three detectors and three gates), 2000 resamples ranked one by one (scipy's
``rankdata``, before) or counted on scores sorted once (`_resampled_aucs`, now). Prints the
CPU seconds of each, the fastest of ``--repeat``, on the scene of
``configs/detection-study.yaml`` (32 x 32 pixels, three gates). Usage: ``python
benchmarks/detect.py [--realisations 1000] [--renders 40] [--repeat 3]``.

Figures, 2026-11-25, the 2-core machine shared (load 8 to 10), CPU time: a sample and its
twin 4.1 → 2.3 ms; a bootstrap of 1000 pairs 0.314 → 0.054 s (the same interval to the bit).
A pair of the study's points (1000 realisations) then costs 4.1 + 6 × 0.31 ≈ 6.0 s → 2.3 + 6 ×
0.05 ≈ 2.6 s, besides reading and scoring. `detect` on two of the study's pairs (a copy
with one depth and one water, 4000 samples): 57.6 → 21.7 s wall, 19.2 → 11.3 s CPU with
the process's start; its 12 pairs took 5 min 42 s on the loaded machine before.
"""

import argparse
import time
from pathlib import Path

import numpy as np
from scipy.stats import rankdata

from service.sweep import load_sweep
from workers.detectors.detection import BOOTSTRAP_BLOCK, bootstrap_auc
from workers.render import render_images, render_pair

STUDY = Path(__file__).resolve().parent.parent / "configs" / "detection-study.yaml"


def fastest(work, repeat: int) -> float:
    """The least CPU time of `repeat` calls of `work`, s."""
    times = []
    for _ in range(repeat):
        start = time.process_time()
        work()
        times.append(time.process_time() - start)
    return min(times)


def ranked_bootstrap(s1, s0, resamples=2000, seed=0):
    """The bootstrap as it was: every resample ranked by scipy's ``rankdata``."""
    n = len(s1)
    picks = np.random.Generator(np.random.PCG64(seed)).integers(0, n, size=(resamples, n))
    values = []
    for block in np.array_split(picks, -(-resamples // BOOTSTRAP_BLOCK)):
        ranks = rankdata(np.concatenate([s1[block], s0[block]], axis=-1), axis=-1)
        values.append((ranks[:, :n].sum(axis=-1) - n * (n + 1) / 2) / (n * n))
    return np.quantile(np.concatenate(values), [0.025, 0.975])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--realisations", type=int, default=1000)
    parser.add_argument("--renders", type=int, default=40)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    plan = load_sweep(str(STUDY))
    positive, negative = plan.sample(0), plan.sample(plan.realisations)
    assert negative.scene == positive.scene.without_target()
    render_pair(positive.scene, seed=positive.seed, twin_seed=negative.seed)  # caches, JIT

    def apart():
        for r in range(args.renders):
            a, b = plan.sample(r), plan.sample(plan.realisations + r)
            render_images(a.scene, seed=a.seed)
            render_images(b.scene, seed=b.seed)

    def together():
        for r in range(args.renders):
            a, b = plan.sample(r), plan.sample(plan.realisations + r)
            render_pair(a.scene, seed=a.seed, twin_seed=b.seed)

    for name, work in (("apart (before)", apart), ("in one pass (now)", together)):
        seconds = fastest(work, args.repeat) / args.renders
        print(f"a sample and its twin rendered {name}: {1e3 * seconds:.1f} ms CPU")
    scores = np.random.Generator(np.random.PCG64(1)).normal(size=(2, args.realisations))
    s1, s0 = scores[0] + 1.0, scores[1]
    assert np.array_equal(ranked_bootstrap(s1, s0), bootstrap_auc(positives=s1, negatives=s0))
    for name, work in (
        ("each resample ranked (before)", lambda: ranked_bootstrap(s1, s0)),
        ("scores sorted once (now)", lambda: bootstrap_auc(positives=s1, negatives=s0)),
    ):
        seconds = fastest(work, args.repeat)
        print(f"a bootstrap of {args.realisations} pairs, {name}: {seconds:.3f} s CPU")


if __name__ == "__main__":
    main()
