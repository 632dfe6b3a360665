"""The slopes below the sea's grid, held to a sea that resolves them (issue #40 item 3).

`tests/data/resolved_patch.npz` (`python -m benchmarks.resolved_patch`) holds, over eight
5 m/s seas, the Monte Carlo renderer's gate means of a small patch (32 px over 1.7° from
34 m, clear water, the receiver's 10 cm pupil) with the spectrum resolved down to 5 mm
waves (no sub-grid slopes), with the project's sub-grid model (a random slope a 1.55 cm
cell on the way down, an independent blur on the way up) and with one faceted sea (the
same cell's facet both ways), and the flat sea's. The renderer's sub-grid model
(`render_frame`'s default) is held to the resolved sea on the same seas.
"""

import pathlib

import numpy as np
import pytest
from test_montecarlo import ALTITUDE, N_WATER, beam_profile, block_ratio, white_plane

from benchmarks.resolved_patch import MODELS, patch_scene
from workers.montecarlo import renderer as montecarlo
from workers.settings.seeds import SampleSeed
from workers.setup.builder import scene_setup

DATA = pathlib.Path(__file__).parent / "data" / "resolved_patch.npz"


@pytest.fixture(scope="module")
def reference():
    with np.load(DATA) as data:
        return {key: data[key] for key in data.files}


def ratios(reference, model):
    """Gate 1's wavy/flat per sea, and the wavy run's error over the flat gate.

    The flat run's own error (0.85 %) scales every ratio alike: it drops out of their
    differences, which the tests compare.
    """
    index = list(reference["models"]).index(model)
    mean, error = reference["means"][:, index, 0], reference["errors"][:, index, 0]
    flat = reference["flat_mean"][0]
    return mean / flat, error / flat


BAR = 0.02
"""How far the kept model may read gate 1 from the resolved sea's, beyond three standard
errors [1]: the blur reads it 1.9 ± 0.5 % low (a real bias, four of its errors: the waves
keep a little of the way down's correlation on the way up that the blur drops), the
faceted sea 5.4 ± 0.7 % high."""


def paired(model_ratio, resolved):
    """The seas' mean of model / resolved (gate 1) and its standard error from their spread."""
    share = np.asarray(model_ratio) / resolved
    return share.mean(), share.std(ddof=1) / np.sqrt(share.size)


def test_the_reference_parts_the_two_models(reference):
    # the stored runs: the resolved sea's gate 1 read within 1 % a sea, the faceted sea
    # reads it beyond the bar high, the blur within it
    assert tuple(reference["models"]) == MODELS
    resolved, resolved_error = ratios(reference, "resolved")
    assert np.all(resolved_error < 0.01 * resolved)
    assert reference["flat_error"][0] < 0.01 * reference["flat_mean"][0]
    facet, error = paired(ratios(reference, "facet")[0], resolved)
    assert facet - 1 > BAR + 3 * error, (facet, error)
    blur, error = paired(ratios(reference, "blur")[0], resolved)
    assert abs(blur - 1) < BAR + 3 * error, (blur, error)


def test_the_sub_grid_model_reproduces_the_resolved_sea(reference):
    # the renderer as it renders a scene (its default sub-grid model, through the pupil,
    # the reference's photons) on the reference's seas: gate 1's wavy/flat over the
    # resolved sea's, the seas' mean, within the bar and three standard errors (from the
    # seas' spread). Its estimates are heavy-tailed over rough seas at fewer photons (a
    # batch of a pupil point now and then catches a focused path straight at the
    # receiver: one sea's error 0.10 at 3·10⁵), so it renders the reference's photon
    # count (while the renderer is unchanged, its runs are the stored `blur` runs)
    setup = scene_setup(patch_scene(wind=5.0, photons=int(reference["photons"])))
    resolved, _ = ratios(reference, "resolved")
    flat = reference["flat_mean"][0]
    again = []
    for root in reference["roots"]:
        seed = SampleSeed(root=int(root))
        frame = montecarlo.render_frame(setup, setup.surface(seed, [0.0]), 0, seed, pupil=True)
        again.append(frame.expected[0].mean(dtype=np.float64) / flat)
    share, error = paired(again, resolved)
    assert error < 0.01
    assert abs(share - 1) < BAR + 3 * error, (np.array(again) / resolved, share, error)


def test_pupil_points_sample_the_disc_evenly():
    # equal areas: the points' mean square radius is the disc's, D²/8, to round-off; the
    # centroid within a sixteenth of the radius; all inside
    points = montecarlo.pupil_points(0.1, 16)
    radius = np.hypot(points[:, 0], points[:, 1])
    assert points.shape == (16, 2) and np.all(radius < 0.05)
    np.testing.assert_allclose(np.mean(radius**2), 0.1**2 / 8, rtol=1e-12)
    assert np.hypot(*points.mean(axis=0)) < 0.05 / 16
    np.testing.assert_array_equal(montecarlo.pupil_points(0.0, 4), np.zeros((4, 2)))


def test_the_pupil_keeps_the_lidar_equation():
    # an unscattered Lambertian plane seen through the pupil (each batch from its own
    # point of the 10 cm aperture) still reads rho e^(-2cz) (H / (H + z/n))^2 in units of
    # the white plane, as the pinhole does (test_montecarlo), within four standard errors
    c, depth = 0.15, 5.0
    s = white_plane(depth=depth, absorption=c, bottom=10.0, transport={"photons": 1_000_000})
    setup = scene_setup(s)
    frame = montecarlo.render_frame(setup, None, 0, SampleSeed(root=3), pupil=True)
    closed = np.exp(-2 * c * depth) * (ALTITUDE / (ALTITUDE + depth / N_WATER)) ** 2
    ratio, error = block_ratio(frame.expected[0], frame.stderr[0], closed * beam_profile())
    assert error < 0.005
    assert abs(ratio - 1) < 4 * error, (ratio, error)


def test_the_way_up_is_named():
    with pytest.raises(ValueError, match="subgrid_up must be 'blur' or 'facet'"):
        montecarlo.render_frame(
            scene_setup(patch_scene(wind=0.0, photons=1000)),
            None,
            0,
            SampleSeed(root=0),
            subgrid_up="faceted",
        )
