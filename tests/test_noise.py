"""Shot noise (paper §4.7) and the ICCD gain stage."""

import math

import numpy as np
import pytest
from scipy import stats

from workers.receiver import noise
from workers.receiver.noise import poisson_counts, shot_noise

MEANS = [1e-3, 0.2, 1.0, 1.5, 1.7, 5.0, 9.99, 10.0, 30.0, 1e3, 1e5, 1e7]
"""Both sides of every branch limit: inversion (λ <= 1, exactly 1 included), sequential
search (1 < λ < 10), PTRS (λ >= 10, exactly 10 included), up to large means."""


@pytest.mark.parametrize(
    "lam", [0.5, 1.5, 5.0, 9.99, 10.0, 13.0, 30.0, 200.0, 1e3, 1e5, 1e7], ids=lambda v: f"{v:g}"
)
def test_poisson_counts_have_mean_and_variance_lambda(lam):
    n = 200_000
    counts = shot_noise(np.full(n, lam), rng=np.random.default_rng(11))
    assert np.all(counts == np.round(counts))
    counts = counts.astype(np.float64)  # float32 sums would round at λ = 1e7
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
    lam = np.concatenate([np.linspace(0, 30, 1000), np.geomspace(30, noise.LARGEST_MEAN, 300)])
    a = shot_noise(lam, rng=np.random.default_rng(2))
    b = shot_noise(lam, rng=np.random.default_rng(2))
    assert a.tobytes() == b.tobytes()
    assert a[0] == 0


@pytest.mark.parametrize("lam", MEANS, ids=lambda v: f"lambda{v:g}")
def test_poisson_counts_follow_the_poisson_law(lam):
    # Pearson's X² = Σ (O − E)²/E over classes of `width` consecutive counts (1 below
    # λ = 1600, sd/20 above: some 200 classes at large λ) with E >= 20, the rest pooled into
    # one class (kept if its E >= 20): asymptotically χ² with (classes − 1) degrees of
    # freedom (every E >= 5 suffices, Cochran's rule); compared with its 1e-4 quantile.
    n = 1_000_000
    counts = poisson_counts(np.full(n, lam), rng=np.random.default_rng(3))
    width = max(1, math.isqrt(int(lam)) // 20)
    observed = np.bincount(counts // width)
    first = np.arange(observed.size) * width  # each class's least count
    expected = n * (stats.poisson.cdf(first + width - 1, lam) - stats.poisson.cdf(first - 1, lam))
    keep = expected >= 20
    rest_observed = observed[~keep].sum()
    rest_expected = n - expected[keep].sum()  # the tail beyond the largest count included
    x2 = ((observed[keep] - expected[keep]) ** 2 / expected[keep]).sum()
    classes = keep.sum()
    if rest_expected >= 20:
        x2 += (rest_observed - rest_expected) ** 2 / rest_expected
        classes += 1
    else:
        assert rest_observed < 5 * max(rest_expected, 1.0)
    assert x2 < stats.chi2.isf(1e-4, max(classes - 1, 1))


def test_poisson_counts_mixed_means_keep_shape_and_order():
    lam = np.array([[0.0, 1e-3, 0.5, 1.0], [1.5, 9.99, 10.0, 300.0], [5.0, 30.0, 1e5, 2.0]])
    draws = np.stack([poisson_counts(lam, rng=np.random.default_rng(s)) for s in range(4000)])
    assert draws.shape == (4000, *lam.shape) and draws.dtype == np.int64
    assert np.all(draws[:, 0, 0] == 0)
    sd = np.sqrt(lam / 4000)  # of the mean of 4000 Poisson(λ) counts
    assert np.all(np.abs(draws.mean(axis=0) - lam) <= 5 * sd + 1e-12)


def test_small_means_draw_as_before_and_branch_limits():
    # λ <= 1 keeps its stream: these counts are those of the code before search and PTRS
    # (commit 36a2e5a, rng.poisson for λ > 1), whatever the larger means beside them.
    lam = np.tile([0.9, 1.0, 2.5, 0.4, 50.0, 0.999], 8)
    counts = poisson_counts(lam, rng=np.random.default_rng(7))
    assert counts[lam <= 1].tolist() == [
        0, 0, 1, 0, 4, 0, 0, 1, 1, 1, 0, 0, 0, 0, 1, 3,
        3, 1, 0, 1, 1, 2, 1, 2, 1, 4, 1, 0, 1, 0, 0, 1,
    ]  # fmt: skip

    # λ = 1 is inverted and λ just below 10 searched, on the one uniform W each; λ = 10
    # goes to PTRS, which draws uniforms of its own after the W.
    def next_uniform(mean):
        rng = np.random.default_rng(0)
        poisson_counts(np.array([mean]), rng=rng)
        return rng.random()

    reference = np.random.default_rng(0)
    reference.random(1)
    after_w = reference.random()
    assert next_uniform(1.0) == after_w
    assert next_uniform(np.nextafter(1.0, 2.0)) == after_w
    assert next_uniform(np.nextafter(10.0, 0.0)) == after_w
    assert next_uniform(10.0) != after_w


def test_a_pool_running_out_gives_the_same_counts(monkeypatch):
    # PTRS draws its uniforms in pools of at most POOL_LIMIT; a block whose pool runs out
    # is drawn again from its first uniform in the next pool.
    lam = np.concatenate([np.linspace(0, 40, 500), np.geomspace(10, 1e6, 300)])
    lam = np.random.default_rng(4).permutation(lam)
    large = poisson_counts(lam, rng=np.random.default_rng(9))
    calls = []
    draw = noise._draw_large

    def counted(*args):
        calls.append(args[3])
        return draw(*args)

    monkeypatch.setattr(noise, "_draw_large", counted)
    for limit in (1000, 100, 7, 3, 2, 1):  # the large first: a lost uniform may hang a small one
        monkeypatch.setattr(noise, "POOL_LIMIT", limit)
        calls.clear()
        small = poisson_counts(lam, rng=np.random.default_rng(9))
        assert small.tobytes() == large.tobytes()
        # each call after the first brings at most `limit` uniforms, one or more a mean
        assert len(calls) - 1 >= np.count_nonzero(lam >= noise.REJECTION_LIMIT) / limit


def test_largest_means_beyond_the_compiled_draws_and_a_zero_uniform():
    n, lam = 20_000, noise.LARGEST_MEAN
    counts = poisson_counts(np.full(n, lam), rng=np.random.default_rng(6))
    assert counts.max() < 2**32
    # sd(mean) = sqrt(λ/n), sd(var) = sqrt((2λ² + λ)/n); 5 sd.
    assert abs(counts.mean() - lam) < 5 * np.sqrt(lam / n)
    assert abs(counts.var() - lam) < 5 * np.sqrt((2 * lam**2 + lam) / n)
    assert poisson_counts(np.array([np.nan, 20.0]), rng=np.random.default_rng(0))[0] == 0
    # beyond LARGEST_MEAN (an ICCD image of a bright scene has no count type to bound it):
    # numpy's PTRS, after the pools; the same moments (5 sd as above)
    huge = 1e11
    counts = poisson_counts(np.r_[5.0, 30.0, np.full(n, huge)], rng=np.random.default_rng(6))
    assert abs(counts[2:].mean() - huge) < 5 * np.sqrt(huge / n)
    assert abs(counts[2:].var() - huge) < 5 * np.sqrt((2 * huge**2 + huge) / n)
    with pytest.raises(ValueError):
        poisson_counts(np.array([5.0, np.inf]), rng=np.random.default_rng(0))
    # a uniform of exactly 0 is a rejected try (k = -inf), not a division error
    k, u_s = noise._candidate(10.0, *noise._hat(10.0), 0.0)
    assert u_s == 0.0 and k < 0
    assert not noise._accepted(10.0, *noise._hat(10.0), k, u_s, 0.5)


def test_log_pmf_of_the_rejection_test_is_accurate():
    log_pmf = noise._log_pmf
    # Against scipy's k ln λ − λ − ln k!, accurate to ~1e-11 at these λ (both sides of the
    # table's end, k = 2048).
    for lam in (10.0, 30.0, 1e3, 2500.0):
        k = np.arange(int(lam + 30 * math.sqrt(lam)))
        mine = np.array([log_pmf(float(x), lam) for x in k])
        assert np.abs(mine - stats.poisson.logpmf(k, lam)).max() < 1e-9
    # At large λ that formula loses λ ln λ · 2⁻⁵³ (8e-6 at 4e9): check the ratios
    # P(k + 1)/P(k) = λ/(k + 1), to twice the error of ln P: 1e-12 + 2⁻⁵¹|k − λ| (the
    # roundings of log1p's argument, of log1p and of its product with k, each <= 2⁻⁵²|k − λ|
    # or half that), and the sum of P over ±40 sd (by the trapezoid rule with steps of
    # sd/40, exact to far below 1e-12 for a pmf this smooth).
    for lam in (1e7, 1e9, noise.LARGEST_MEAN):
        sd = math.sqrt(lam)
        for z in np.linspace(-10, 10, 41):
            k = float(round(lam + z * sd))
            ratio = math.log1p((lam - k - 1) / (k + 1))
            error = 2 * (1e-12 + 2**-51 * abs(k - lam))
            assert abs(log_pmf(k + 1, lam) - log_pmf(k, lam) - ratio) < error
        step = round(sd / 40)
        ks = np.arange(round(lam - 40 * sd), round(lam + 40 * sd), step, dtype=np.float64)
        total = step * sum(math.exp(log_pmf(k, lam)) for k in ks)
        assert abs(total - 1) < 1e-9


# The torch path (workers.backends.backend's torch backend): torch's draws, the same law.


def has_cuda():
    """Whether torch is installed and sees a CUDA device."""
    try:
        import torch
    except ImportError:
        return False
    return torch.cuda.is_available()


@pytest.fixture(
    params=[
        "cpu",
        pytest.param("cuda", marks=pytest.mark.skipif(not has_cuda(), reason="no CUDA")),
    ]
)
def device(request):
    """The device of the torch draws: the CPU, and CUDA where there is one."""
    return request.param


def torch_generator(seed, device):
    """A seeded torch generator on `device` (the test skips without torch)."""
    torch = pytest.importorskip("torch")
    return torch, torch.Generator(device=device).manual_seed(seed)


@pytest.mark.parametrize("lam", [1e-3, 0.5, 5.0, 30.0, 1e3, 1e7], ids=lambda v: f"{v:g}")
def test_torch_poisson_counts_have_mean_and_variance_lambda(lam, device):
    torch, rng = torch_generator(11, device)
    n = 200_000
    counts = shot_noise(torch.full((n,), lam, dtype=torch.float32, device=device), rng=rng)
    assert isinstance(counts, torch.Tensor) and counts.dtype == torch.float32
    assert counts.device.type == device
    counts = counts.cpu().numpy().astype(np.float64)
    assert np.all(counts == np.round(counts))
    # the standard errors of a Poisson(λ) sample's mean and variance, as above: 5 sd
    assert abs(counts.mean() - lam) < 5 * np.sqrt(lam / n)
    assert abs(counts.var() - lam) < 5 * np.sqrt((2 * lam**2 + lam) / n)


@pytest.mark.parametrize(
    ("lam", "excess"),
    [(20.0, 1.6), (2.0, 5.0), (0.3, 40.0)],
    ids=["large-shapes", "shapes-below-one", "mostly-below-one"],
)
def test_torch_gain_and_excess_noise_factor(lam, excess, device):
    """E = Gλ, Var = G²Fλ, with Gamma shapes n/(F − 1) above and below 1."""
    torch, rng = torch_generator(5, device)
    n, gain = 400_000, 50.0
    expected = torch.full((n,), lam, dtype=torch.float32, device=device)
    counts = shot_noise(expected, rng=rng, gain=gain, excess_noise=excess)
    assert counts.dtype == torch.float32 and counts.device.type == device
    counts = counts.cpu().numpy().astype(np.float64)
    mean, var = gain * lam, gain**2 * excess * lam
    # sd(mean) = sqrt(var/n); sd of the variance estimate from the 4th cumulant of the
    # compound Poisson–Gamma count, κ4 = λ E[Y⁴] with Y ~ Gamma(1/(F−1), G(F−1))
    alpha, theta = 1 / (excess - 1), gain * (excess - 1)
    fourth = lam * theta**4 * alpha * (alpha + 1) * (alpha + 2) * (alpha + 3)
    assert abs(counts.mean() - mean) < 5 * np.sqrt(var / n)
    assert abs(counts.var() - var) < 5 * np.sqrt((fourth + 2 * var**2) / n)


@pytest.mark.parametrize("alpha", [0.05, 0.7, 1.0, 3.0, 1e6], ids=lambda v: f"{v:g}")
def test_torch_gamma_has_mean_and_variance_alpha(alpha, device):
    torch, rng = torch_generator(9, device)
    n = 200_000
    shapes = torch.full((n,), alpha, dtype=torch.float64, device=device)
    draws = noise._torch_gamma(shapes, rng=rng).cpu().numpy()
    assert np.all(draws >= 0) and np.all(np.isfinite(draws))
    # Gamma(α, 1): mean α, variance α, 4th central moment 3α² + 6α: 5 sd of each estimate
    assert abs(draws.mean() - alpha) < 5 * np.sqrt(alpha / n)
    assert abs(draws.var() - alpha) < 5 * np.sqrt((3 * alpha**2 + 6 * alpha - alpha**2) / n)


def test_torch_same_seed_same_bytes_and_zero_mean_gives_zero(device):
    torch, _ = torch_generator(0, device)
    lam = torch.from_numpy(np.geomspace(1e-4, 1e6, 5000).astype(np.float32)).to(device)
    lam[0] = 0.0
    for options in ({}, {"gain": 30.0, "excess_noise": 1.8}):
        a, b, c = (
            shot_noise(lam, rng=torch_generator(seed, device)[1], **options).cpu().numpy()
            for seed in (2, 2, 3)
        )
        assert a.tobytes() == b.tobytes()
        assert a.tobytes() != c.tobytes()
        assert a[0] == 0 and a.shape == lam.shape


def test_noise_seed_is_the_noise_streams_first_draw():
    from workers.settings.seeds import SampleSeed

    seed = SampleSeed(root=7, point=3, realisation=2)
    assert seed.noise_seed() == SampleSeed(root=7, point=3, realisation=2).noise_seed()
    assert seed.noise_seed() == int(seed.noise_rng().integers(2**63))
    others = {SampleSeed(7, p, r).noise_seed() for p in range(3) for r in range(3)}
    assert len(others) == 9 and all(0 <= s < 2**63 for s in others)
