"""Shot noise (paper §4.7) and the ICCD gain stage."""

import numpy as np
import pytest

from workers.noise import shot_noise


@pytest.mark.parametrize("lam", [0.5, 13.0, 200.0], ids=lambda v: f"lambda{v:g}")
def test_poisson_counts_have_mean_and_variance_lambda(lam):
    n = 200_000
    counts = shot_noise(np.full(n, lam), rng=np.random.default_rng(11))
    assert np.all(counts == np.round(counts))
    # Standard errors of the sample mean and variance of a Poisson(λ) sample of size n:
    # sd(mean) = sqrt(λ/n), sd(var) = sqrt((2λ² + λ)/n) (4th cumulant λ). Allow 5 sd.
    assert abs(counts.mean() - lam) < 5 * np.sqrt(lam / n)
    assert abs(counts.var() - lam) < 5 * np.sqrt((2 * lam**2 + lam) / n)


def test_gain_and_excess_noise_factor():
    n, lam, gain, excess = 200_000, 20.0, 50.0, 1.6
    counts = shot_noise(
        np.full(n, lam), rng=np.random.default_rng(5), gain=gain, excess_noise=excess
    )
    mean, var = gain * lam, gain**2 * excess * lam
    # sd(mean) = sqrt(var/n); the variance estimate is checked to 5 % (n = 2e5 gives ~0.5 %
    # relative sd for these near-Gaussian counts).
    assert abs(counts.mean() - mean) < 5 * np.sqrt(var / n)
    assert abs(counts.var() / var - 1) < 0.05


def test_same_seed_same_counts_and_zero_mean_gives_zero():
    lam = np.linspace(0, 30, 1000)
    a = shot_noise(lam, rng=np.random.default_rng(2))
    b = shot_noise(lam, rng=np.random.default_rng(2))
    assert a.tobytes() == b.tobytes()
    assert a[0] == 0


@pytest.mark.parametrize("lam", [1e-3, 0.2, 1.0, 1.7], ids=lambda v: f"lambda{v:g}")
def test_poisson_counts_follow_the_poisson_law(lam):
    # Pearson's χ² over the classes with at least 20 expected counts, against its 1e-4
    # quantile: both sides of INVERSION_LIMIT (inversion and numpy's sampler).
    from scipy import stats

    from workers.noise import poisson_counts

    n = 1_000_000
    counts = poisson_counts(np.full(n, lam), rng=np.random.default_rng(3))
    k = np.arange(counts.max() + 1)
    observed = np.bincount(counts)
    expected = stats.poisson.pmf(k, lam) * n
    keep = expected >= 20
    chi2 = ((observed[keep] - expected[keep]) ** 2 / expected[keep]).sum()
    assert chi2 < stats.chi2.isf(1e-4, max(keep.sum() - 1, 1))
    assert observed[~keep].sum() < 5 * max(expected[~keep].sum(), 1.0)


def test_poisson_counts_mixed_means_keep_shape_and_order():
    from workers.noise import poisson_counts

    lam = np.array([[0.0, 1e-3, 0.5], [1.0, 5.0, 300.0]])
    draws = np.stack([poisson_counts(lam, rng=np.random.default_rng(s)) for s in range(4000)])
    assert draws.shape == (4000, 2, 3) and draws.dtype == np.int64
    assert np.all(draws[:, 0, 0] == 0)
    sd = np.sqrt(lam / 4000)
    assert np.all(np.abs(draws.mean(axis=0) - lam) <= 5 * sd + 1e-12)
