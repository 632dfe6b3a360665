"""`render_batch` on each backend: batches of one, determinism, agreement across backends."""

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from workers.render import render_arrays, render_batch, render_images, render_pair
from workers.settings.scene import Scene
from workers.settings.section import SceneError
from workers.settings.seeds import SampleSeed

torch = pytest.importorskip("torch")

BACKENDS = [
    pytest.param(("numpy", "cpu"), id="numpy"),
    pytest.param(("torch", "cpu"), id="torch-cpu"),
    pytest.param(
        ("torch", "cuda"),
        id="torch-cuda",
        marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device here"),
    ),
]

PEAK_TOLERANCE = 1e-5
"""Across backends, each expected (frame, gate) image agrees within this share of its peak."""


def scene(**sections):
    """A small scene (32 pixels, a 64² sea) with `sections` merged over these defaults."""
    base = {
        "surface": {"grid_size": 64, "spacing": 0.064},
        "receiver": {"pixels": 32},
        "radiometry": {"mode": "normalised", "white_plane_photons": 50.0},
    }
    for key, value in sections.items():
        base[key] = {**base.get(key, {}), **value} if isinstance(value, dict) else value
    return Scene.model_validate(base)


CORPUS = {
    "flat-none-noiseless": scene(
        surface={"spectrum": "flat"},
        target={"shape": "none"},
        radiometry={"white_plane_photons": 0.0},  # the white plane's units, no noise
    ),
    "wavy-sphere-absolute": scene(radiometry={"mode": "absolute", "white_plane_photons": None}),
    "wavy-sphere-oblique": scene(platform={"nadir_deg": 20.0, "azimuth_deg": 30.0}),
    "wavy-large-sphere-64px": scene(target={"radius": 2.0, "depth": 3.0}, receiver={"pixels": 64}),
    # seen through 2°, the waves' slopes bend some lines of sight off the fine grids: they
    # read the coarse level (`workers.backends.kernels.gather_levels`)
    "wavy-narrow-lines-off-the-grid": scene(
        surface={"spacing": 0.02}, receiver={"pixels": 48, "field_of_view_deg": 2.0}
    ),
    "frames-moving-saved-sea": scene(
        sequence={"frames": 2, "velocity": (2.0, 0.0, 0.0)}, save_surface=True
    ),
    "conditioned-gain": scene(
        surface={"conditioning": {"points": [[1.0, 1.0, 0.05], [1.5, 1.0, -0.02]]}},
        target={"shape": "none"},
        noise={"gain": 10.0, "excess_noise": 1.5},
    ),
}

LABELS = ("target_mask", "target_visibility")
"""What the scene's light decides by a threshold: equal on every backend."""


def expected_agree(a, b):
    """Each (frame, gate) image of `a` and `b` within PEAK_TOLERANCE of its peak."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    peak = np.abs(a).max(axis=(-2, -1))
    difference = np.abs(a - b).max(axis=(-2, -1))
    return difference <= PEAK_TOLERANCE * peak


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_batch_holds_each_sample_as_rendered_alone(backend):
    name, device = backend
    sample = CORPUS["wavy-sphere-oblique"]
    seeds = [SampleSeed(root=3, point=1, realisation=r) for r in (0, 4, 2)]
    batch = render_batch(sample, seeds, backend=name, device=device)
    for i, seed in enumerate(seeds):
        alone = render_arrays(sample, seed=seed, backend=name, device=device)
        assert set(alone) == set(batch)
        for key, values in alone.items():
            assert batch[key][i].dtype == values.dtype, key
            assert batch[key][i].tobytes() == values.tobytes(), key
    assert not np.array_equal(batch["image"][0], batch["image"][1])


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("case", ["frames-moving-saved-sea", "conditioned-gain"])
def test_the_same_seeds_give_the_same_bytes_twice(backend, case):
    name, device = backend
    first = render_batch(CORPUS[case], [5, 6], backend=name, device=device)
    again = render_batch(CORPUS[case], [5, 6], backend=name, device=device)
    for key, values in first.items():
        assert values.tobytes() == again[key].tobytes(), key


@pytest.mark.parametrize("case", list(CORPUS))
def test_the_backends_agree_on_a_corpus_of_scenes(case):
    sample = CORPUS[case]
    host = render_arrays(sample, seed=9)
    moved = render_arrays(sample, seed=9, backend="torch")
    assert set(host) == set(moved)
    assert np.all(expected_agree(host["expected"], moved["expected"]))
    assert host["expected"].max() > 0  # light to compare
    for key in LABELS:
        assert_array_equal(host[key], moved[key], err_msg=key)
    if "surface_elevation" in host:  # the same modes, transformed by another FFT
        sea = host["surface_elevation"]
        assert np.abs(sea - moved["surface_elevation"]).max() <= 1e-5 * np.abs(sea).max()


def test_the_twins_agree_across_backends():
    sample = CORPUS["wavy-sphere-oblique"]
    seed, twin = SampleSeed(root=2, point=0), SampleSeed(root=2, point=1)
    host = render_pair(sample, seed=seed, twin_seed=twin)
    moved = render_pair(sample, seed=seed, twin_seed=twin, backend="torch")
    for one, other in zip(host[::2], moved[::2], strict=True):  # the expected images
        assert np.all(expected_agree(one, other))
    assert host[0].tobytes() != host[2].tobytes()  # the target shows


@pytest.mark.parametrize("gain", [1.0, 4.0], ids=["poisson", "gain-stage"])
def test_the_backends_draw_noise_from_the_same_distribution(gain):
    # a flat sea under a parallel beam: 3 to 20 photoelectrons a pixel in the first gates
    sample = scene(
        surface={"spectrum": "flat"},
        laser={"beam": "parallel"},
        target={"shape": "none"},
        receiver={"pixels": 64},
        radiometry={"white_plane_photons": 40000.0},
        noise={"gain": gain, "excess_noise": 1.0 if gain == 1.0 else 1.5},
    )
    factor = gain * gain * (1.0 if gain == 1.0 else 1.5)  # Var = G²Fλ, E = Gλ
    for name in ("numpy", "torch"):
        expected, image = render_images(sample, seed=SampleSeed(root=4), backend=name)
        lit = expected > 1.0
        lam = expected[lit].astype(np.float64)
        residual = image[lit].astype(np.float64) - gain * lam
        n = residual.size
        assert n > 10_000
        # the mean of the residual: 0 within 5 standard errors
        assert abs(residual.mean()) < 5.0 * np.sqrt(factor * lam.mean() / n)
        # its variance: G²Fλ within 5 standard errors (Poisson's fourth moment ≈ 3 Var²)
        ratio = (residual**2).sum() / (factor * lam).sum()
        assert abs(ratio - 1.0) < 5.0 * np.sqrt(2.0 / n), name


def test_monte_carlo_renders_on_numpy_only():
    sample = scene(transport={"method": "monte_carlo", "photons": 1000, "batches": 4})
    with pytest.raises(SceneError, match="monte_carlo renders on the numpy backend only"):
        render_batch(sample, [1], backend="torch")


def test_a_batch_needs_a_seed_and_a_backend_that_runs_here():
    with pytest.raises(ValueError, match=r"^seeds: "):
        render_batch(CORPUS["flat-none-noiseless"], [])
    with pytest.raises(ValueError, match=r"^backend: 'jax'"):
        render_arrays(CORPUS["flat-none-noiseless"], seed=1, backend="jax")
