"""Reference images by photon transport: the scenes the fast renderer is held to.

Renders each scene of `SCENES` with the Monte Carlo renderer (`workers.montecarlo.renderer`) and
writes ``tests/data/transport_reference.npz``: per scene, the noise-free image
(``NAME/expected``), its standard error (``NAME/stderr``), the target mask
(``NAME/mask``) and the scene itself as JSON (``NAME/scene``), so that a test can render the
same scene with either renderer. Every scene with a sphere has its no-target twin
(``NAME-none``), rendered from the same seed, for contrasts.

The scenes (issue #23, item 5): clear, coastal and turbid water with a 0.3 m sphere at 5 m
under the six ML(DC) gates (gate 1, 3.7–9.8 m, holds it; gate 2's top, 4.9 m, cuts it;
gates 5 and 6, 10.7–15.2 m, lie in its shadow); the paper's Example 4 (its water, the
sphere at 3 m, one gate 4–9 m: a shadow); and the coastal scene under a 5 m/s sea. 32 pixels
over 6.7° from 34 m, flat seas at nadir except the last.

Usage, from the repository root: ``python -m benchmarks.transport_reference`` (about
ten minutes on one core); ``--scale 0.1`` for a quick look (the file is then not written
unless ``--write``).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from workers.render import render_arrays
from workers.settings.scene import Scene

OUTPUT = Path(__file__).resolve().parent.parent / "tests" / "data" / "transport_reference.npz"

_BASE = {
    "receiver": {"pixels": 32, "field_of_view_deg": 6.7, "gates": "mldc"},
    "platform": {"altitude": 34.0},
    "radiometry": {"mode": "normalised", "white_plane_photons": 0.0},
    "target": {"shape": "sphere", "radius": 0.3, "depth": 5.0, "reflectance": 0.2},
    "surface": {"spectrum": "flat"},
}

SCENES = {
    "clear": ({"water": {"preset": "clear_ocean"}}, 16_000_000),
    "coastal": ({"water": {"preset": "coastal"}}, 16_000_000),
    "turbid": ({"water": {"preset": "turbid_harbour"}}, 4_000_000),
    "example4": (
        {
            "water": {"preset": None, "absorption": 0.1, "scattering": 0.4, "backscatter": 0.0154},
            "target": {"shape": "sphere", "radius": 0.3, "depth": 3.0, "reflectance": 0.2},
            "receiver": {"pixels": 32, "field_of_view_deg": 6.7, "gates": [[4.0, 9.0]]},
        },
        16_000_000,
    ),
    "coastal-waves": (
        {
            "water": {"preset": "coastal"},
            "surface": {
                "spectrum": "elfouhaily",
                "wind_speed": 5.0,
                "grid_size": 128,
                "spacing": 0.032,
            },
        },
        8_000_000,
    ),
}

SEED = 2026


def reference_scene(name: str, *, photons: int | None = None, target: bool = True) -> Scene:
    """The Monte Carlo scene of reference `name` (its no-target twin with `target` False)."""
    sections, default = SCENES[name]
    data = {**_BASE, **sections}
    if not target:
        data["target"] = {**data["target"], "shape": "none"}
    data["transport"] = {"method": "monte_carlo", "photons": photons or default, "batches": 32}
    return Scene.model_validate(data)


def stored_render(arrays: dict, key: str, scene: Scene, *, photons: int) -> str:
    """Render `scene` by transport into ``arrays[key/...]``; the line that reports it.

    Parameters
    ----------
    arrays : dict
        The reference's arrays by name, added to: ``key/expected``, ``/stderr``, ``/mask``
        (the first frame's) and ``/scene`` (the scene as JSON).
    key : str
        The scene's name in the reference.
    scene : Scene
        A Monte Carlo scene.
    photons : int
        Its photons, for the report.

    Returns
    -------
    str
        The render's photons, seconds and gate means with their relative errors.
    """
    start = time.perf_counter()
    out = render_arrays(scene, seed=SEED)
    seconds = time.perf_counter() - start
    expected, stderr = out["expected"][0], out["expected_stderr"][0]
    arrays[f"{key}/expected"] = expected
    arrays[f"{key}/stderr"] = stderr
    arrays[f"{key}/mask"] = out["target_mask"][0]
    arrays[f"{key}/scene"] = np.array(json.dumps(scene.model_dump(mode="json")))
    means = expected.mean(axis=(1, 2))
    errors = np.sqrt((stderr**2).sum(axis=(1, 2))) / stderr[0].size
    gates = " ".join(f"{m:.3e}±{100 * e / m:.1f}%" for m, e in zip(means, errors, strict=True))
    return f"{key:20s} {photons:>11,d} photons {seconds:7.1f} s  gate means {gates}"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scale", type=float, default=1.0, help="photons times this")
    parser.add_argument("--write", action="store_true", help="write even when scaled")
    parser.add_argument("--only", nargs="*", default=list(SCENES), help="scenes to render")
    args = parser.parse_args(argv)
    arrays = dict(np.load(OUTPUT)) if OUTPUT.exists() else {}
    for name in args.only:
        for target in (True, False):
            photons = int(SCENES[name][1] * args.scale)
            scene = reference_scene(name, photons=photons, target=target)
            key = name if target else f"{name}-none"
            print(stored_render(arrays, key, scene, photons=photons))
    if args.scale == 1.0 or args.write:
        np.savez_compressed(OUTPUT, **arrays)
        print(f"wrote {OUTPUT}")


if __name__ == "__main__":
    main()
