"""Reference images by photon transport with ``phase_function: paper`` (issue #40, item 1).

Renders with the Monte Carlo renderer (`workers.montecarlo.renderer`) the scenes of
`benchmarks.transport_reference` named in `SCENES`, with the paper's phase function in both
renderers (``water.phase_function`` and ``transport.phase_function``: `paper`), and writes
``tests/data/paper_reference.npz`` in the same layout as that module's file (per scene
``NAME/expected``, ``NAME/stderr``, ``NAME/mask``, ``NAME/scene``), which
``tests/test_paper_reference.py`` holds the fast renderer to.

The scenes: coastal water under the six ML(DC) gates without a target, and the paper's
Example 4 (its water, one gate 4–9 m) without and with its sphere at 3 m (same seed).

Usage, from the repository root: ``python -m benchmarks.paper_reference`` (24 million
photons each, 2.2, 2.0 and 4.0 minutes on one niced core shared with another job: 8 minutes
in all; 64 kB); ``--scale 0.1`` for a quick look (the file is then not written unless
``--write``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from benchmarks.transport_reference import reference_scene, stored_render
from workers.settings.scene import Scene

OUTPUT = Path(__file__).resolve().parent.parent / "tests" / "data" / "paper_reference.npz"

SCENES = {
    "coastal-none": ("coastal", False, 24_000_000),
    "example4-none": ("example4", False, 24_000_000),
    "example4": ("example4", True, 24_000_000),
}
"""Reference name: (`benchmarks.transport_reference` scene, with its target, photons)."""


def paper_scene(name: str, *, photons: int | None = None) -> Scene:
    """The Monte Carlo scene of reference `name`, the paper's phase function in both renderers."""
    base, target, default = SCENES[name]
    data = reference_scene(base, photons=photons or default, target=target).model_dump()
    data["water"]["phase_function"] = "paper"
    data["transport"]["phase_function"] = "paper"
    return Scene.model_validate(data)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scale", type=float, default=1.0, help="photons times this")
    parser.add_argument("--write", action="store_true", help="write even when scaled")
    parser.add_argument("--only", nargs="*", default=list(SCENES), help="scenes to render")
    args = parser.parse_args(argv)
    arrays = dict(np.load(OUTPUT)) if OUTPUT.exists() else {}
    for name in args.only:
        photons = int(SCENES[name][2] * args.scale)
        scene = paper_scene(name, photons=photons)
        print(stored_render(arrays, name, scene, photons=photons))
    if args.scale == 1.0 or args.write:
        np.savez_compressed(OUTPUT, **arrays)
        print(f"wrote {OUTPUT}")


if __name__ == "__main__":
    main()
