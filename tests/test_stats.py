"""The statistics of a parameter point (`service.stats.point_statistics`).

On rendered samples, and the CNR on images made here (issue #38 item 5)."""

import numpy as np
import pytest
from conftest import ring_around
from numpy.testing import assert_allclose

from service.stats import point_statistics
from workers.dataset.labels import RING_FRACTION
from workers.render import render_arrays
from workers.settings.scene import Scene
from workers.settings.seeds import SampleSeed


def stacked_samples(surface, realisations=3):
    """A 0.5 m sphere at 8.5 m below two gates and inside a third: its point's samples.

    (A 0.3 m sphere at 8 m until issue #36: over the 10 m/s sea the sub-grid slopes now
    smear so small and deep a sphere that no pixel's view is half covered, and its mask
    is the one pixel it covers most, whose ring reads the sea's texture.)
    """
    scene = Scene.model_validate(
        {
            "surface": {**surface, "grid_size": 64, "spacing": 0.064},
            "water": {"preset": "coastal"},
            "target": {"shape": "sphere", "radius": 0.5, "depth": 8.5, "reflectance": 0.2},
            "platform": {"altitude": 34.0},
            "receiver": {"pixels": 32, "gates": [[1.0, 5.0], [3.0, 7.5], [6.0, 10.0]]},
            "radiometry": {"mode": "normalised", "white_plane_photons": 200.0},
        }
    )
    samples = [
        render_arrays(scene, seed=SampleSeed(root=1, realisation=r)) for r in range(realisations)
    ]
    return {name: np.stack([s[name] for s in samples]) for name in samples[0]}


@pytest.mark.parametrize(
    "surface",
    [{"spectrum": "flat"}, {"spectrum": "elfouhaily", "wind_speed": 10.0}],
    ids=["flat", "wavy"],
)
def test_target_contrast_is_zero_where_the_target_changes_nothing(surface):
    # Issue #24, item 7: the sphere lies below the gates 1-5 m and 3-7.5 m, whose images
    # are those of its target-free twin. The local contrast (T - B) / B of the mask and its
    # ring reads the beam's fall-off between them there (+0.09 on the flat sea, +0.19 to
    # +0.25 on the wavy one); the statistic, against the twin over the same mask, reads 0.
    s = stacked_samples(surface)
    stats = point_statistics(
        image=s["image"],
        target=s["target_signal"],
        background=s["background_signal"],
        mask=s["target_mask"].astype(bool),
        relative=s["target_effect_relative"],
        visibility=s["target_visibility"],
    )
    target, ring = (s[name].astype(np.float64) for name in ("target_signal", "background_signal"))
    local = np.mean((target - ring) / ring, axis=(0, 1))
    assert (local[:2] > 0.04).all()  # the fall-off the statistic must not read
    assert np.abs(stats["target_contrast"][:2]).max() < 1e-6
    assert stats["target_contrast"][2] > 5  # the sphere in the gate 6-10 m
    assert stats["visible_fraction"].tolist() == [0.0, 0.0, 1.0]


def cnr_of(image, mask):
    """`point_statistics`' ``cnr`` of images (samples, frames, gates, y, x) over their masks.

    The rest of a point's samples (signals, effect, labels) is zeros: the CNR reads only
    the noisy images and the masks.
    """
    per_gate = np.zeros(image.shape[:3])
    return point_statistics(
        image=image,
        target=per_gate,
        background=per_gate,
        mask=mask,
        relative=per_gate,
        visibility=per_gate.astype(np.uint8),
    )["cnr"]


def test_cnr_is_the_contrast_over_the_standard_deviation_of_the_ring():
    # Issue #38 item 5 (b), closed form: a 2 x 2 mask in 16 x 16 images (a ring 2 pixels
    # wide: 32 pixels) reading T, its ring a checkerboard of B - s and B + s (16 each:
    # mean B, standard deviation s), everything beyond the ring far brighter (never read).
    # Each image's CNR is (T - B) / s; the statistic their mean over samples and frames.
    # s is 0.5, 2 and 4 in the three gates, so that the variance s^2 is never s.
    rng = np.random.default_rng(38)
    samples, frames, gates, n = 2, 3, 3, 16
    mask = np.zeros((samples, frames, n, n), bool)
    mask[..., 7:9, 7:9] = True
    y, x = np.mgrid[:n, :n]
    ring = (abs(y - 7.5) < 3) & (abs(x - 7.5) < 3) & ~mask[0, 0]
    assert ring.sum() == 32 and (ring_around(mask[0, 0], 2) == ring).all()
    sign = np.where((y + x) % 2, 1.0, -1.0)[ring]
    assert sign.sum() == 0
    T = rng.uniform(20.0, 40.0, (samples, frames, gates))
    B = rng.uniform(5.0, 15.0, (samples, frames, gates))
    s = np.array([0.5, 2.0, 4.0])
    image = rng.uniform(1e3, 2e3, (samples, frames, gates, n, n))
    image[..., 7:9, 7:9] = T[..., None, None]
    image[..., ring] = B[..., None] + s[:, None] * sign
    assert_allclose(image[..., ring].std(axis=-1), np.broadcast_to(s, B.shape), rtol=1e-12)
    expected = ((T - B) / s).mean(axis=(0, 1))
    assert_allclose(cnr_of(image.astype(np.float32), mask), expected, rtol=1e-6)


def test_cnr_of_noisy_images_is_the_brute_force_mean_over_samples_and_frames():
    # Issue #38 item 5 (b), brute force: Poisson images (mean 9, so a ring's variance is
    # about 9 times its standard deviation) under masks of several shapes and places; per
    # image, (mean over the mask - mean over its ring) / the ring's standard deviation
    # (population, numpy's default), the ring every pixel within RING_FRACTION of the
    # image's width of the mask (Chebyshev) outside it, brute force.
    rng = np.random.default_rng(5)
    samples, frames, gates, n = 3, 2, 2, 20
    image = rng.poisson(9.0, (samples, frames, gates, n, n)).astype(np.uint16)
    image[..., 2:12, 4:9] += np.uint16(6)  # a brighter patch the masks overlap
    mask = np.zeros((samples, frames, n, n), bool)
    for k, (top, left, height, width) in enumerate(
        [(3, 5, 4, 3), (0, 0, 2, 5), (8, 14, 6, 6), (10, 2, 1, 1), (5, 5, 3, 8), (15, 9, 3, 2)]
    ):
        mask[np.unravel_index(k, (samples, frames))][top : top + height, left : left + width] = 1
    width = max(2, round(RING_FRACTION * n))
    expected = np.zeros((samples, frames, gates))
    for i in range(samples):
        for j in range(frames):
            ring = ring_around(mask[i, j], width)
            for g in range(gates):
                values = image[i, j, g].astype(np.float64)
                background = values[ring]
                expected[i, j, g] = (values[mask[i, j]].mean() - background.mean()) / (
                    background.std()
                )
    assert 1.0 < np.abs(expected).max() < 10.0  # the variance would read 3 to 4 times less
    assert_allclose(cnr_of(image, mask), expected.mean(axis=(0, 1)), rtol=1e-6)


def test_image_std_is_the_sample_standard_deviation_over_samples_and_frames():
    # A planted bug survived the suite (issue #38's fifteen): `image_std` with ddof=0. Three
    # images reading 1, 2 and 3 at a pixel (two samples' frames and one more) have the
    # sample standard deviation exactly 1 (the population one, 0.816).
    image = np.zeros((3, 1, 2, 4, 4), np.float32)
    image[:, 0, 0, 1, 2] = [1.0, 2.0, 3.0]
    image[:, 0, 1] = np.arange(3.0)[:, None, None] * 2.0  # every pixel: 0, 2, 4 (std 2)
    per_gate = np.zeros(image.shape[:3])
    stats = point_statistics(
        image=image,
        target=per_gate,
        background=per_gate,
        mask=np.zeros((3, 1, 4, 4), bool),
        relative=per_gate,
        visibility=per_gate.astype(np.uint8),
    )
    assert stats["image_std"][0, 1, 2] == 1.0
    assert (stats["image_std"][0][np.arange(16).reshape(4, 4) != 6] == 0.0).all()
    assert_allclose(stats["image_std"][1], 2.0, rtol=1e-12)
    assert_allclose(stats["image_mean"][0, 1, 2], 2.0, rtol=1e-12)
