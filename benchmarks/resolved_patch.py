"""The sea finer than its grid, resolved: the reference for the sub-grid slopes' model.

A small patch (32 px over 1.7°, 1.0 m of sea seen from 34 m at nadir; clear ocean, a
5 m/s Elfouhaily sea on a 256-point grid of 1.55 cm, the default scene's spacing; the
ML(DC) gates; no target) is rendered by photon transport (`workers.montecarlo.renderer`)
through the receiver's 10 cm pupil (``pupil=True``) over four seas:

- ``resolved``: the sea's cascades plus one more of 512 points at 2.5 mm holding the
  spectrum between the grid's Nyquist wavenumber π/Δ₀ and π/2.5 mm (the band the sub-grid
  slopes stand for), and no sub-grid slopes: each pixel's lines of sight are 13 × 13 (a
  cell 2.4 mm on the sea), so the same waves refract the laser's photons and the receiver's
  lines;
- ``blur``: the sea with its sub-grid slopes as the project models them (a random slope a
  1.55 cm cell on the way down, an independent blur on the way up);
- ``facet``: the same sub-grid slopes, the same cell's facet refracting the way down and
  the way up (``subgrid_up="facet"``);

and a flat sea once; then the fast renderer on the same seas (printed, not stored).
Stored in ``tests/data/resolved_patch.npz``: each gate's mean over the
image and its standard error (the 16 batches, one pupil point each), per sea and model, and
the flat sea's. `tests/test_resolved_patch.py` reads it.

Usage, from the repository root: ``NUMBA_NUM_THREADS=1 python -m benchmarks.resolved_patch
[--photons 600000] [--seas 4] [--first 0] [--out tests/data/resolved_patch.npz]
[--append earlier.npz ...]`` (``--append``: earlier runs' seas, stored first).

The stored file: 6 × 10⁵ photons a run, seas 0–3 (16 min, 10 min of CPU, one core of a
2-core machine at load 3: the resolved runs 2.5–5 min a sea, 16 lookups of 417² lines
each, the blur's 4–6 s, the facet's 12–32 s) and seas 4–7 in a second run appended
(``--seas 0 --append first.npz second.npz`` wrote the file).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time

import numpy as np

from workers.montecarlo import renderer as montecarlo
from workers.render import render_arrays
from workers.sea.cascades import Sea, subgrid_slope_covariance
from workers.sea.surface import Surface, draw
from workers.settings.scene import Scene
from workers.settings.seeds import SampleSeed
from workers.setup.builder import scene_setup

FINE_POINTS = 512
"""Points a side of the resolving cascade."""

FINE_SPACING = 0.0025
"""Its spacing [m]: waves down to 5 mm."""

LASER_FIELD = 4.0
"""The laser's full field [deg]: its 1/e radius 1.19 m on the sea, so the 1 m patch is lit
within 19 % of its centre's light and the waves' spreading of the beam's edge is far."""

MODELS = ("resolved", "blur", "facet")


def patch_scene(*, wind: float, photons: int) -> Scene:
    """The small patch: 32 px over 1.7° from 34 m, clear ocean, no target (flat if wind 0)."""
    surface = (
        {"spectrum": "flat"}
        if wind == 0
        else {"spectrum": "elfouhaily", "wind_speed": wind, "grid_size": 256, "spacing": 0.0155}
    )
    return Scene.model_validate(
        {
            "surface": surface,
            "water": {"preset": "clear_ocean"},
            "target": {"shape": "none"},
            "platform": {"altitude": 34.0, "nadir_deg": 0.0},
            "laser": {"field_of_view_deg": LASER_FIELD},
            "receiver": {"pixels": 32, "field_of_view_deg": 1.7, "gates": "mldc"},
            "radiometry": {"mode": "normalised", "white_plane_photons": 0.0},
            "transport": {"method": "monte_carlo", "photons": photons, "batches": 16},
        }
    )


def small_angle(scene: Scene) -> Scene:
    """The same scene for the fast (small-angle) renderer."""
    return scene.model_copy(
        update={"transport": scene.transport.model_copy(update={"method": "small_angle"})}
    )


def resolved_surface(surface: Surface, sea: Sea, seed: SampleSeed) -> Surface:
    """`surface`'s cascades plus one resolving the band beyond its grid; no sub-grid slopes.

    The new cascade (`FINE_POINTS` at `FINE_SPACING`) draws its modes from the sample's
    stream of cascade index 8 (unused by any sea) and keeps those with
    π/Δ₀ ≤ |k| < π/`FINE_SPACING`: the band that `surface`'s sub-grid slopes stand for.
    Its amplitudes are then scaled so that its mean-square slope, as read (bilinearly, on
    a 400 × 400 lattice over its patch), equals the sub-grid slopes' trace Σ: the sub-grid
    slopes also stand for what bilinear interpolation loses of the resolved cascades
    (`workers.sea.cascades.subgrid_slope_covariance`), so the two seas' slopes have the
    same variance and differ only in how the finest are laid out (0.0044 before the
    scaling against Σ's 0.0072 on the default 5 m/s sea: amplitudes × 1.28).
    """
    fine = Sea(sea.spectrum, FINE_POINTS, (FINE_POINTS * FINE_SPACING,))
    modes = draw(fine, seed.surface_rng(8))
    k = fine.wavenumbers(0)
    half = FINE_POINTS // 2 + 1
    keep = np.hypot(k[None, :half], k[:, None]) >= math.pi / sea.spacing(0)
    extra = None
    for scale in (1.0, None):
        if scale is None:  # the second pass: Σ's trace over the band's read variance
            lattice = (np.arange(400) + 0.5) * (fine.patches[0] / 400)
            slope_x, slope_y = extra.slopes_at(lattice[None, :], lattice[:, None], 0)
            read = float(np.mean(slope_x.astype(np.float64) ** 2 + slope_y**2))
            scale = math.sqrt(np.trace(subgrid_slope_covariance(sea)) / read)
        scaled = dataclasses.replace(
            modes, ahead=(modes.ahead[0] * keep * scale,), behind=(modes.behind[0] * keep * scale,)
        )
        extra = dataclasses.replace(scaled.surface([0.0]), subgrid=None)
    return Surface(cascades=(*extra.cascades, *surface.cascades), subgrid=None)


def gate_means(frame) -> tuple[np.ndarray, np.ndarray]:
    """Each gate's mean over the image and its standard error (the batches') [scene units]."""
    mean = frame.expected.mean(axis=(1, 2), dtype=np.float64)
    pixels = frame.expected.shape[1] * frame.expected.shape[2]
    # from the pixels' errors as if independent: a lower bound (each batch's pupil point
    # correlates its pixels); the seas' spread is the comparison's error
    error = np.sqrt((frame.stderr.astype(np.float64) ** 2).sum(axis=(1, 2))) / pixels
    return mean, error


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--photons", type=int, default=600_000)
    parser.add_argument("--seas", type=int, default=4)
    parser.add_argument("--first", type=int, default=0, help="the first sea's root seed")
    parser.add_argument("--out", default="tests/data/resolved_patch.npz")
    parser.add_argument(
        "--append", nargs="*", default=[], help="earlier runs' files whose seas come first"
    )
    args = parser.parse_args(argv)
    wavy = scene_setup(patch_scene(wind=5.0, photons=args.photons))
    fine = dataclasses.replace(wavy, surface_spacing=FINE_SPACING)
    flat = scene_setup(patch_scene(wind=0.0, photons=args.photons))
    start = time.time()
    frame = montecarlo.render_frame(flat, None, 0, SampleSeed(root=100), pupil=True)
    flat_mean, flat_error = gate_means(frame)
    print(f"flat: {np.array2string(flat_mean, precision=4)} ({time.time() - start:.0f} s)")
    means = np.zeros((args.seas, len(MODELS), flat_mean.size))
    errors = np.zeros_like(means)
    for sea_index in range(args.seas):
        seed = SampleSeed(root=args.first + sea_index)
        surface = wavy.surface(seed, [0.0])
        runs = {
            "resolved": (fine, resolved_surface(surface, wavy.sea, seed), "blur"),
            "blur": (wavy, surface, "blur"),
            "facet": (wavy, surface, "facet"),
        }
        for model_index, model in enumerate(MODELS):
            setup, sea, up = runs[model]
            start = time.time()
            frame = montecarlo.render_frame(setup, sea, 0, seed, pupil=True, subgrid_up=up)
            mean, error = gate_means(frame)
            means[sea_index, model_index], errors[sea_index, model_index] = mean, error
            print(
                f"sea {sea_index} {model:8s} wavy/flat "
                + " ".join(f"{r:.3f}" for r in mean / flat_mean)
                + f" (gate 1 ± {error[0] / flat_mean[0]:.3f}; {time.time() - start:.0f} s)"
            )
    roots = np.arange(args.first, args.first + args.seas)
    for path in reversed(args.append):  # the same flat run and photons, other seas
        with np.load(path) as earlier:
            if int(earlier["photons"]) != args.photons:
                raise SystemExit(f"{path}: {int(earlier['photons'])} photons, not {args.photons}")
            means = np.concatenate([earlier["means"], means])
            errors = np.concatenate([earlier["errors"], errors])
            kept = (
                earlier["roots"] if "roots" in earlier.files else np.arange(len(earlier["means"]))
            )
            roots = np.concatenate([kept, roots])
    args.seas = roots.size
    ratio = means / flat_mean
    for model_index, model in enumerate(MODELS):
        spread = ratio[:, model_index].std(axis=0, ddof=1) / math.sqrt(args.seas)
        print(
            f"{model:8s} mean over seas: "
            + " ".join(f"{r:.3f}" for r in ratio[:, model_index].mean(axis=0))
            + f" (gate 1 ± {spread[0]:.3f} over seas)"
        )
    for model_index, model in enumerate(MODELS[1:], start=1):
        paired = ratio[:, model_index, 0] / ratio[:, 0, 0]
        print(f"{model:8s} / resolved, gate 1, per sea: {np.array2string(paired, precision=3)}")
    # the fast renderer on the same seas, each over its own flat sea (not stored)
    fast = {wind: small_angle(patch_scene(wind=wind, photons=args.photons)) for wind in (0, 5)}
    fast_flat = render_arrays(fast[0], seed=0)["expected"][0].mean(axis=(1, 2))
    shares = (
        np.array(
            [
                render_arrays(fast[5], seed=int(root))["expected"][0].mean(axis=(1, 2)) / fast_flat
                for root in roots
            ]
        )
        / ratio[:, 0]
    )
    print(
        "fast renderer / resolved, gates 1-6, seas' mean: "
        + " ".join(f"{r:.3f}" for r in shares.mean(axis=0))
        + f" (gate 1 per sea {np.array2string(shares[:, 0], precision=3)})"
    )
    np.savez_compressed(
        args.out,
        models=np.array(MODELS),
        means=means.astype(np.float32),
        errors=errors.astype(np.float32),
        flat_mean=flat_mean.astype(np.float32),
        flat_error=flat_error.astype(np.float32),
        photons=args.photons,
        roots=roots,
    )


if __name__ == "__main__":
    main()
