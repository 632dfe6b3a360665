"""The fused render equals the reference render within float32 round-off.

`tests/data/render_reference.npz` holds the noise-free images (``expected``) and target
masks of a few small scenes, written by the render of commit 149a566 (numpy splats,
gathers and full FFTs, before the fused kernels). The sea is an analytic swell (below),
so the references depend on the image formation only, not on the surface synthesis.
After an intended change of the physics, rewrite them with
``python -m tests.test_render_reference`` and say why in the commit.
"""

from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from workers.render import render
from workers.settings.scene import Scene
from workers.setup.compiled import Setup

REFERENCE = Path(__file__).parent / "data" / "render_reference.npz"

SCENES = {
    "sphere-nadir-waves": {"receiver": {"pixels": 40}},
    "sphere-oblique-absolute": {
        "receiver": {"pixels": 33},
        "platform": {"nadir_deg": 20.0, "azimuth_deg": 30.0},
        "radiometry": {"mode": "absolute"},
    },
    "large-disk-parallel-beam": {
        "receiver": {"pixels": 36},
        "laser": {"beam": "parallel", "rays": 44},
        "target": {"shape": "disk", "radius": 8.0, "depth": 6.0},
        "platform": {"nadir_deg": 10.0},
    },
    "no-target-wide-laser": {
        "receiver": {"pixels": 32},
        "laser": {"field_of_view_deg": 9.0},
        "target": {"shape": "none"},
    },
}
"""Scenes (sections over the defaults) covering the render's branches: the monostatic
default, odd pixels, slant gating, targets hiding the gates, a target larger than the fine
grid, a laser that is not the receiver's lattice, no target."""

RTOL = 2e-6
"""Tolerance on each image, relative to its largest value: float32 round-off of sums
taken in another order and of FFTs split into their two passes (at most 3e-7 seen)."""


class Swell:
    """An analytic sea (two crossing swells, 0.15 m and 0.1 m): elevation and slopes."""

    waves = ((0.15, 1.3, 0.4, 0.0), (0.1, -0.7, 2.1, 1.0))

    def elevation_at(self, x, y, frame=0):
        return sum(
            np.float32(a) * np.sin(kx * x + ky * y + p).astype(np.float32)
            for a, kx, ky, p in self.waves
        )

    def slopes_at(self, x, y, frame=0):
        cosines = [np.cos(kx * x + ky * y + p) for _, kx, ky, p in self.waves]
        return tuple(
            sum(
                np.float32(a * k) * c.astype(np.float32)
                for (a, *ks, _), c in zip(self.waves, cosines, strict=True)
                for k in [ks[axis]]
            )
            for axis in (0, 1)
        )


def rendered(name, monkeypatch):
    """``expected`` and ``target_mask`` of the named scene over the swell, seed 3."""
    sections = {"surface": {"grid_size": 64, "spacing": 0.1}, **SCENES[name]}
    monkeypatch.setattr(Setup, "surface", lambda *_, **__: Swell())
    sample = render(Scene.model_validate(sections), seed=3)
    return sample.expected.values, sample.target_mask.values


@pytest.mark.parametrize("name", list(SCENES))
def test_the_render_equals_the_reference_within_round_off(name, monkeypatch):
    expected, mask = rendered(name, monkeypatch)
    with np.load(REFERENCE) as reference:
        want, want_mask = reference[f"{name}/expected"], reference[f"{name}/mask"]
    side = want.shape[-2:]
    for got, image in zip(expected.reshape(-1, *side), want.reshape(-1, *side), strict=True):
        assert image.max() > 0
        assert_allclose(got, image, rtol=0, atol=RTOL * image.max())
    assert_array_equal(mask, want_mask)


if __name__ == "__main__":
    patch = pytest.MonkeyPatch()
    arrays = {}
    for name in SCENES:
        expected, mask = rendered(name, patch)
        arrays[f"{name}/expected"], arrays[f"{name}/mask"] = expected, mask
    np.savez_compressed(REFERENCE, **arrays)
