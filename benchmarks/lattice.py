"""Does the fast renderer's rough-sea light converge with its rays and lines? (issue #24.1)

For each sea, the gates' mean over the image's central three quarters, wavy over the flat
sea's (the same scene with ``spectrum: flat``), and the pixel texture (a pixel over its
7 × 7 neighbourhood's mean: the standard deviation of that ratio over the same region),
averaged over a few seas (seeds), at:

- ``1x``: the default lattice (one ray per pixel pitch);
- ``1.5x``, ``3x``: 1.5 and 3 times the rays per side (`laser.rays`);
- ``2x lines``: two lines of sight per pixel and side (the scene rendered at twice the
  pixels with the default's rays, its images binned 2 × 2).

Usage, from the repository root: ``python -m benchmarks.lattice [--seeds 4] [--pixels
128]``. No target; normalised radiometry without noise.
"""

import argparse

import numpy as np
from scipy.ndimage import uniform_filter

from workers.render import render_arrays
from workers.settings.scene import Scene

SEAS = {
    "coastal 5 m/s": ("coastal", 5.0),
    "clear 1 m/s": ("clear_ocean", 1.0),
    "clear 5 m/s": ("clear_ocean", 5.0),
    "clear 10 m/s": ("clear_ocean", 10.0),
}


def scene(water, wind, *, pixels, rays=None, flat=False):
    return Scene.model_validate(
        {
            "water": {"preset": water},
            "surface": {"spectrum": "flat" if flat else "elfouhaily", "wind_speed": wind},
            "target": {"shape": "none"},
            "receiver": {"pixels": pixels},
            "laser": {"rays": rays},
            "radiometry": {"mode": "normalised", "white_plane_photons": 0.0},
        }
    )


def image(water, wind, *, pixels, variant, seed, flat=False):
    """The frame's gate images of one variant, (gates, pixels, pixels)."""
    if variant == "2x lines":
        s = scene(water, wind, pixels=2 * pixels, rays=pixels, flat=flat)
        e = render_arrays(s, seed=seed)["expected"][0]
        return e.reshape(len(e), pixels, 2, pixels, 2).mean(axis=(2, 4))
    rays = {"1x": None, "1.5x": 3 * pixels // 2, "3x": 3 * pixels}[variant]
    return render_arrays(scene(water, wind, pixels=pixels, rays=rays, flat=flat), seed=seed)[
        "expected"
    ][0]


def measures(images):
    """Gate means and pixel textures over the central three quarters."""
    n = images.shape[-1]
    inner = slice(n // 8, n - n // 8)
    means = images[:, inner, inner].mean(axis=(1, 2))
    texture = [(g / uniform_filter(g, 7))[inner, inner].std() for g in images.astype(np.float64)]
    return means, np.array(texture)


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--pixels", type=int, default=128)
    args = parser.parse_args()
    variants = ("1x", "1.5x", "3x", "2x lines")
    for name, (water, wind) in SEAS.items():
        print(name)
        for variant in variants:
            kw = {"pixels": args.pixels, "variant": variant}
            flat, _ = measures(image(water, wind, seed=0, flat=True, **kw))
            got = [measures(image(water, wind, seed=s, **kw)) for s in range(args.seeds)]
            ratio = np.mean([m for m, _ in got], axis=0) / flat
            texture = np.mean([t for _, t in got], axis=0)
            print(
                f"  {variant:>8}  wavy/flat {' '.join(f'{r:.3f}' for r in ratio)}"
                f"   CV {' '.join(f'{t:.3f}' for t in texture)}"
            )


if __name__ == "__main__":
    main()
