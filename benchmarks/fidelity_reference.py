"""A grid of reference scenes by photon transport: the fast renderer's bars, scene by scene.

Renders each scene of `SCENES` by the Monte Carlo renderer (`workers.fidelity.transport_light`:
the first frame and its no-target twin on the same sea and photon streams, seed
`SEED`) and writes ``tests/data/fidelity_reference/NAME.npz``: the scene as JSON
(``scene``), its images (``image``, ``twin``), their standard errors (``stderr``,
``twin_stderr``), the target's ``mask`` and the sea's elevation's standard deviation
(``sea_std``), and per gate what `workers.fidelity.compare` reads of them: the
background's mean and standard error (``background``, ``background_error``), the
target's contrast (target − twin)/twin over its mask, a shadow's below it, and its error
(``contrast``, ``contrast_error``) and the gate's kind (``kinds``);
``tests/test_fidelity_reference.py`` holds the fast renderer to them.

The scenes (issue #36, item 3) vary one thing at a time around the reference scene (32 px
over 6.7° from 34 m at nadir, a 0.3 m sphere at 5 m in clear water, the six ML(DC)
gates, a flat sea): nadir 10° and 20°; altitude 100 and 300 m; a 0.3 m sphere at 3 m,
0.5 m at 9 m and 1 m at 12 m; a 0.3 m disk at 5 m; a horizontal cylinder (0.3 m radius,
2 m long, axis at 5 m) east-west (heading 90°, along the image's rows), north-south
(heading 0°), and east-west in coastal water; coastal water; 1, 5 and 10 m/s
Elfouhaily seas with the default cascades (and coastal water under 5 m/s): one
realisation each (`SEED`). Photons: 8·10⁶ over a flat sea (backgrounds ±0.1–0.2 %, the
sphere's contrast in gate 1 ±2–3 % at 34 m, 13 % at 300 m), 2·10⁶ over waves
(backgrounds ±0.4–2 %, the sphere ±3–12 %);
the scenes' times summed 41 minutes (14 flat, 27 over waves; niced, on the shared
2-core machine under a load of about 12, 2026-11-28).

Usage, from the repository root: ``nice python -m benchmarks.fidelity_reference``
(resumable: a scene whose file exists is skipped unless ``--force``; ``--only NAME ...``;
``--scale 0.1`` renders a tenth of the photons and writes nothing, to time it). It prints
each scene's time. Never regenerate it to make a test pass: regenerate it after a change
of the transport physics, and say so.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from workers.fidelity import Light, compare, gate_kinds, transport_light
from workers.settings.scene import Scene
from workers.settings.seeds import SampleSeed

FOLDER = Path(__file__).resolve().parent.parent / "tests" / "data" / "fidelity_reference"

SEED = 2026

REFERENCE = {
    "receiver": {"pixels": 32, "field_of_view_deg": 6.7, "gates": "mldc"},
    "platform": {"altitude": 34.0, "nadir_deg": 0.0},
    "radiometry": {"mode": "normalised", "white_plane_photons": 0.0},
    "target": {"shape": "sphere", "radius": 0.3, "depth": 5.0, "reflectance": 0.2},
    "water": {"preset": "clear_ocean"},
    "surface": {"spectrum": "flat"},
}
"""The reference scene: every scene of `SCENES` changes one or two sections of it."""


def _sea(wind: float) -> dict:
    """An Elfouhaily sea of `wind` [m/s] with the default cascades (the waves users render)."""
    return {"spectrum": "elfouhaily", "wind_speed": wind}


def _cylinder(heading: float) -> dict:
    """A 2 m long, 0.3 m radius horizontal cylinder at 5 m, its axis along `heading` [deg]."""
    return {
        "shape": "cylinder",
        "radius": 0.3,
        "length": 2.0,
        "depth": 5.0,
        "heading_deg": heading,
    }


SCENES = {
    "reference": ({}, 8_000_000),
    "nadir-10": ({"platform": {"altitude": 34.0, "nadir_deg": 10.0}}, 8_000_000),
    "nadir-20": ({"platform": {"altitude": 34.0, "nadir_deg": 20.0}}, 8_000_000),
    "altitude-100": ({"platform": {"altitude": 100.0, "nadir_deg": 0.0}}, 8_000_000),
    "altitude-300": ({"platform": {"altitude": 300.0, "nadir_deg": 0.0}}, 8_000_000),
    "sphere-0.3-at-3": ({"target": {"shape": "sphere", "radius": 0.3, "depth": 3.0}}, 8_000_000),
    "sphere-0.5-at-9": ({"target": {"shape": "sphere", "radius": 0.5, "depth": 9.0}}, 8_000_000),
    "sphere-1-at-12": ({"target": {"shape": "sphere", "radius": 1.0, "depth": 12.0}}, 8_000_000),
    "disk": ({"target": {"shape": "disk", "radius": 0.3, "depth": 5.0}}, 8_000_000),
    "cylinder": ({"target": _cylinder(90.0)}, 8_000_000),
    "cylinder-along": ({"target": _cylinder(0.0)}, 8_000_000),
    "cylinder-coastal": ({"target": _cylinder(90.0), "water": {"preset": "coastal"}}, 8_000_000),
    "coastal": ({"water": {"preset": "coastal"}}, 8_000_000),
    "wind-1": ({"surface": _sea(1.0)}, 2_000_000),
    "wind-5": ({"surface": _sea(5.0)}, 2_000_000),
    "wind-10": ({"surface": _sea(10.0)}, 2_000_000),
    "coastal-wind-5": ({"water": {"preset": "coastal"}, "surface": _sea(5.0)}, 2_000_000),
}
"""Each scene: its sections replacing the reference's, and its photons per frame."""

SUMMARY_ORDER = ("kinds", "background", "background_error", "contrast", "contrast_error")


def fidelity_scene(name: str, *, photons: int | None = None) -> Scene:
    """Scene `name` of `SCENES` (with `photons` instead of its own, if given)."""
    sections, default = SCENES[name]
    data = {**REFERENCE, **sections}
    data["target"] = {**REFERENCE["target"], **data["target"]}
    data["transport"] = {"method": "monte_carlo", "photons": photons or default, "batches": 16}
    return Scene.model_validate(data)


def summaries(light: Light, kinds) -> dict[str, np.ndarray]:
    """Per gate, the background, the contrast and their standard errors, and the kinds."""
    checks = compare(light, light, kinds=kinds)  # against itself: its own values and errors
    background = light.twin.mean(axis=(1, 2), dtype=np.float64)
    return {
        "background": background,
        "background_error": np.array([c.background.error for c in checks]) * background,
        "contrast": np.array([c.reference_contrast for c in checks]),
        "contrast_error": np.array([c.reference_error for c in checks]),
        "kinds": np.array(kinds),
    }


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", nargs="*", default=list(SCENES), choices=list(SCENES))
    parser.add_argument("--force", action="store_true", help="render scenes already written")
    parser.add_argument(
        "--scale", type=float, default=1.0, help="photons times this (not 1: nothing written)"
    )
    args = parser.parse_args(argv)
    FOLDER.mkdir(parents=True, exist_ok=True)
    total = 0.0
    for name in args.only:
        path = FOLDER / f"{name}.npz"
        if path.exists() and not args.force and args.scale == 1.0:
            print(f"{name:16s} written already: skipped")
            continue
        scene = fidelity_scene(name, photons=int(SCENES[name][1] * args.scale))
        start = time.perf_counter()
        light = transport_light(scene, seed=SampleSeed(root=SEED))
        seconds = time.perf_counter() - start
        total += seconds
        kinds = gate_kinds(scene, sea_std=light.sea_std)
        summary = summaries(light, kinds)
        print(
            f"{name:16s} {scene.transport.photons:>10,d} photons {seconds:7.1f} s  "
            + "  ".join(
                f"g{g + 1} {kind} bg±{100 * error / mean:.1f}% c {value:+.2f}±{spread:.2f}"
                for g, (kind, mean, error, value, spread) in enumerate(
                    zip(*(summary[k] for k in SUMMARY_ORDER), strict=True)
                )
            ),
            flush=True,
        )
        if args.scale == 1.0:
            np.savez_compressed(
                path,
                scene=np.array(json.dumps(scene.model_dump(mode="json"))),
                image=light.image,
                twin=light.twin,
                stderr=light.stderr,
                twin_stderr=light.twin_stderr,
                mask=light.mask,
                sea_std=np.float64(light.sea_std),
                **summary,
            )
    print(f"{total:.0f} s in all")


if __name__ == "__main__":
    main()
