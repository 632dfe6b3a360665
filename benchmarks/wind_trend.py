"""Does detection fall with wind? The figures of README's "Wind trend" (issue #29, item 4).

Reads a run of ``configs/wind-trend.yaml`` and its detection dataset and prints:

1. **Pd against wind**: per wind speed and detector (ideal observer, matched filter,
   logistic regression), the AUC with its bootstrap interval and Pd at Pfa = 10⁻¹ and 10⁻²
   with a binomial 95 % interval (``±1.96 √(Pd (1 − Pd) / n)``, n the evaluated pairs);
   with ``--png`` the curve beside Tulldahl & Steinvall's two figures.
2. **The sea at the footprint**, per wind, over ``--seas`` realisations (the store's seas:
   the surface depends on the root seed and the realisation only): the mean-square slope
   ⟨s_x² + s_y²⟩ at the pixels' sea points, resolved by the cascades and in all (sub-grid
   slopes added), against Cox & Munk's clean-sea fit 0.003 + 5.12 × 10⁻³ U [1]_, its
   spread from sea to sea, and the elevation's standard deviation.
3. **What the sea does to the target's signal**, per wind, from the store: the target's
   effect in each gate (``target_effect``, photoelectrons over the mask, sphere less its
   target-free twin on the same sea) averaged over the realisations, and its coefficient
   of variation from sea to sea (the noise-free signal's own spread: what a detector that
   does not know the sea has to absorb).
4. **Monte Carlo** (``--monte-carlo N``): the same effect rendered by photon transport
   (``transport.method: monte_carlo``, ``--photons`` a frame) on the first N seas at the
   lowest and highest winds, beside the fast renderer's on the same seas.

Usage, from the repository root, after ``oceanlidar run configs/wind-trend.yaml`` and
``oceanlidar detect wind-trend.zarr``::

    python -m benchmarks.wind_trend wind-trend.zarr [--seas 64] [--monte-carlo 4]
        [--png docs/gallery/wind-trend.png]

References
----------
.. [1] Cox, C., & Munk, W. (1954). Measurement of the roughness of the sea surface from
   photographs of the sun's glitter. J. Opt. Soc. Am. 44(11), 838-850.
"""

import argparse
import dataclasses

import numpy as np
import xarray as xr

from service.store.location import Store
from service.sweep import parse_sweep
from workers.dataset.labels import image_axes
from workers.render import render_arrays
from workers.settings.scene import Scene
from workers.settings.seeds import SampleSeed
from workers.setup.builder import scene_setup

TULLDAHL = ((1.0, 0.9, "above"), (6.0, 0.8, "below"))
"""Tulldahl & Steinvall's figures (wind m/s, Pd, side): above 90 % at 1 m/s, below 80 % at 6."""


def cox_munk(wind):
    """Clean-sea mean-square slope of Cox & Munk (1954) at wind speed `wind` (m/s) [1]."""
    return 0.003 + 5.12e-3 * wind


def pd_table(detection: xr.Dataset) -> list[str]:
    """Markdown rows: wind, detector, AUC [interval], Pd at each Pfa ± its binomial 95 %."""
    header = "| wind (m/s) | detector | AUC [95 %] | Pd, Pfa 0.1 | Pd, Pfa 0.01 |"
    rows = [header, "|" + "---|" * 5]
    winds = detection["surface_wind_speed"].values
    for p in np.argsort(winds):
        for d, name in enumerate(detection["detector"].values):
            auc = detection["auc"].values[p, d]
            low, high = detection["auc_low"].values[p, d], detection["auc_high"].values[p, d]
            n = int(detection["evaluated"].values[p, d])
            cells = []
            for pd in detection["pd"].values[p, d]:
                half = 1.96 * np.sqrt(pd * (1.0 - pd) / n)
                cells.append("n/a" if np.isnan(pd) else f"{pd:.3f} ± {half:.3f}")
            rows.append(
                f"| {winds[p]:g} | {name} | {auc:.3f} [{low:.3f}, {high:.3f}] | "
                + " | ".join(cells)
                + " |"
            )
    return rows


def draw_png(detection: xr.Dataset, path: str) -> None:
    """Pd at Pfa = 10⁻² against wind, one line per detector, Tulldahl & Steinvall's marks."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(5.5, 3.6), dpi=110)
    FigureCanvasAgg(figure)
    axes = figure.add_subplot()
    winds = detection["surface_wind_speed"].values
    order = np.argsort(winds)
    strict = int(np.flatnonzero(np.isclose(detection["pfa"].values, 1e-2))[0])
    for d, name in enumerate(detection["detector"].values):
        pd = detection["pd"].values[order, d, strict]
        n = detection["evaluated"].values[order, d]
        half = 1.96 * np.sqrt(pd * (1.0 - pd) / n)
        axes.errorbar(winds[order], pd, yerr=half, marker="o", capsize=3, label=str(name))
    for wind, pd, side in TULLDAHL:
        axes.plot([wind], [pd], marker="^" if side == "above" else "v", color="k", ms=9)
    axes.plot([], [], "k^", label="Tulldahl & Steinvall (bound)")
    axes.set_xlabel("wind speed U10 (m/s)")
    axes.set_ylabel("Pd at Pfa = 0.01")
    axes.set_ylim(0.0, 1.02)
    axes.grid(alpha=0.3)
    axes.legend(fontsize=8, loc="lower left")
    figure.tight_layout()
    figure.savefig(path)


def sea_rows(plan, seas: int) -> list[str]:
    """Markdown rows: the sea's slopes and elevation at the footprint, per wind."""
    rows = [
        "| wind (m/s) | mss resolved | mss total ± sea to sea | Cox–Munk | η std (m) |",
        "|" + "---|" * 5,
    ]
    root = int(plan.sweep.seed)
    for scene in _scenes_by_wind(plan, shape="none").values():
        setup = scene_setup(scene)
        y, x = image_axes(scene)
        xs, ys = np.meshgrid(x, y)
        resolved, total, eta = [], [], []
        for r in range(seas):
            surface = setup.surface(SampleSeed(root=root, realisation=r), [0.0])
            sx, sy = surface.slopes_at(xs, ys)
            total.append(np.mean(sx.astype(np.float64) ** 2 + sy.astype(np.float64) ** 2))
            sx, sy = dataclasses.replace(surface, subgrid=None).slopes_at(xs, ys)
            resolved.append(np.mean(sx.astype(np.float64) ** 2 + sy.astype(np.float64) ** 2))
            eta.append(np.std(surface.elevation_at(xs, ys)))
        wind = scene.surface.wind_speed
        rows.append(
            f"| {wind:g} | {np.mean(resolved):.4f} | {np.mean(total):.4f} ± "
            f"{np.std(total):.4f} | {cox_munk(wind):.4f} | {np.mean(eta):.3f} |"
        )
    return rows


def signal_rows(store: xr.Dataset, plan) -> list[str]:
    """Markdown rows: the target's effect per gate, mean and sea-to-sea CV, per wind."""
    gates = store.sizes["gate"]
    header = " | ".join(f"gate {g + 1}: mean, CV" for g in range(gates))
    rows = [f"| wind (m/s) | {header} |", "|" + "---|" * (gates + 1)]
    realisations = plan.realisations
    for point, scene in _scenes_by_wind(plan, shape="sphere", index=True).items():
        rows_of = slice(point * realisations, (point + 1) * realisations)
        effect = store["target_effect"].isel(sample=rows_of, frame=0).values.astype(np.float64)
        cells = [
            f"{effect[:, g].mean():.4f}, {effect[:, g].std() / abs(effect[:, g].mean()):.3f}"
            for g in range(gates)
        ]
        rows.append(f"| {scene.surface.wind_speed:g} | " + " | ".join(cells) + " |")
    return rows


def monte_carlo_rows(plan, seas: int, photons: int) -> list[str]:
    """Markdown rows: the target's effect per gate, fast renderer and transport, same seas."""
    rows = ["| wind (m/s) | sea | gate effects: fast | transport ± error |", "|" + "---|" * 4]
    root = int(plan.sweep.seed)
    scenes = _scenes_by_wind(plan, shape="sphere")
    for wind in (min(scenes), max(scenes)):
        fast_scene = scenes[wind]
        mc_scene = Scene.model_validate(
            {
                **fast_scene.model_dump(),
                "transport": {"method": "monte_carlo", "photons": photons},
            }
        )
        for r in range(seas):
            seed = SampleSeed(root=root, realisation=r)
            fast = render_arrays(fast_scene, seed=seed)["target_effect"][0]
            mc = render_arrays(mc_scene, seed=seed)
            pairs = zip(mc["target_effect"][0], _effect_error(mc), strict=True)
            rows.append(
                f"| {wind:g} | {r} | {' '.join(f'{v:.4f}' for v in fast)} | "
                + " ".join(f"{v:.4f} ± {e:.4f}" for v, e in pairs)
                + " |"
            )
    return rows


def _effect_error(arrays) -> np.ndarray:
    """Standard error of the Monte Carlo sample's mean over its mask, per gate (frame 0).

    The batches' pixel errors (``expected_stderr``) combined over the mask as if
    independent: an indication, the twin's photons being the sample's own.
    """
    mask = arrays["target_mask"][0].astype(bool)
    stderr = arrays["expected_stderr"][0].astype(np.float64)
    return np.sqrt((stderr[:, mask] ** 2).sum(axis=1)) / max(mask.sum(), 1)


def _scenes_by_wind(plan, *, shape: str, index: bool = False) -> dict:
    """The plan's scenes with target `shape`, by wind speed (or by point, `index`)."""
    found = {}
    for point, scene in enumerate(plan.scenes):
        if scene.target.shape == shape:
            found[point if index else scene.surface.wind_speed] = scene
    return dict(sorted(found.items()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("store", help="the run's store (its .detect.zarr beside it)")
    parser.add_argument("--seas", type=int, default=64, help="seas for the slope statistics")
    parser.add_argument("--monte-carlo", type=int, default=0, help="seas by transport, a wind")
    parser.add_argument("--photons", type=int, default=400_000, help="photons a frame")
    parser.add_argument("--png", help="write the Pd-against-wind curve there")
    args = parser.parse_args()
    store = Store.at(args.store)
    dataset = store.dataset()
    plan = parse_sweep(dataset.attrs["sweep"], max_memory=None)
    detection = store.sibling("detect").dataset()
    print("\n".join(pd_table(detection)), end="\n\n")
    if args.png:
        draw_png(detection, args.png)
    print("\n".join(signal_rows(dataset, plan)), end="\n\n")
    print("\n".join(sea_rows(plan, args.seas)), end="\n\n")
    if args.monte_carlo:
        print("\n".join(monte_carlo_rows(plan, args.monte_carlo, args.photons)))


if __name__ == "__main__":
    main()
