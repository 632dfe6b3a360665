"""The renderer's inline air-to-water interface against the reference optics functions."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from workers.optics.fresnel import fresnel_reflectance, refract
from workers.setup.interface import ray_components, through_surface

N_WATER = 1.34


class TiltedFacets:
    """A sea of zero elevation whose facet under ray i has slopes (sx[i], sy[i])."""

    def __init__(self, sx, sy):
        self.sx, self.sy = sx, sy

    def elevation_at(self, x, y, frame=0):
        return np.zeros_like(np.asarray(x, dtype=np.float32))

    def slopes_at(self, x, y, frame=0):
        return self.sx, self.sy


@pytest.mark.parametrize("seed", [0, 1, 2], ids=lambda s: f"seed{s}")
def test_the_inline_refraction_and_fresnel_equal_the_reference_functions(seed):
    # Random downward rays (up to 40° off nadir) on random facets (slopes up to ±0.5):
    # the in-water slopes, secant and transmittance of `through_surface` are those of
    # vector Snell (`optics.refract`) and unpolarised Fresnel (`optics.fresnel_reflectance`)
    # at the facet's upward normal (-sx, -sy, 1)/√(1 + s²).
    rng = np.random.default_rng(seed)
    count = 2000
    theta = np.radians(rng.uniform(0.0, 40.0, count))
    phi = rng.uniform(0.0, 2 * np.pi, count)
    direction = np.stack(
        [np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), -np.cos(theta)], axis=-1
    )
    origin = np.tile([0.0, 0.0, 30.0], (count, 1))
    sx = rng.uniform(-0.5, 0.5, count).astype(np.float32)
    sy = rng.uniform(-0.5, 0.5, count).astype(np.float32)
    got = through_surface(ray_components(origin, direction), TiltedFacets(sx, sy), 0, N_WATER)
    normal = np.stack([-sx, -sy, np.ones(count)], axis=-1).astype(np.float64)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    transmitted, _ = refract(direction, normal, n1=1.0, n2=N_WATER)
    cos_incidence = -(direction * normal).sum(axis=-1)
    facing = cos_incidence > 0
    assert facing.mean() > 0.95
    down = -transmitted[facing, 2]
    assert_allclose(got.tan_x[facing], transmitted[facing, 0] / down, rtol=1e-4, atol=1e-5)
    assert_allclose(got.tan_y[facing], transmitted[facing, 1] / down, rtol=1e-4, atol=1e-5)
    assert_allclose(got.secant[facing], 1 / down, rtol=1e-5)
    expected = 1 - fresnel_reflectance(cos_incidence[facing], n1=1.0, n2=N_WATER)
    assert_allclose(got.transmittance[facing], expected, rtol=1e-5)
    assert np.all(got.transmittance[~facing] == 0)
    assert_allclose(got.air, 30.0 / np.cos(theta), rtol=1e-5)
