"""The sea-marginal observer against closed forms: a flat sea, a two-sea mixture, a sea whose
pixels vary independently (the exact marginal a product of one-dimensional integrals)."""

import warnings

import numpy as np
import pytest
from scipy.special import roots_hermitenorm
from scipy.stats import poisson

from workers.detectors.detection import auc, bootstrap_auc, ideal_observer, sea_auc_error
from workers.detectors.marginal import sea_likelihoods, sea_marginal_observer


def rng(seed):
    return np.random.Generator(np.random.PCG64(seed))


def test_on_a_flat_sea_it_is_the_ideal_observer():
    # every sea the same: both sums are M times one likelihood, the ratio the ideal one
    draws = rng(1)
    background = draws.uniform(0.5, 4.0, (2, 3, 5))
    signal = background * draws.uniform(0.5, 2.0, background.shape)
    background[0, 0, 0] = signal[0, 0, 0] = 0.0  # dark everywhere: tells nothing
    background[0, 0, 1], signal[0, 0, 1] = 0.0, 0.3  # a count there is certain evidence
    counts = draws.poisson(np.broadcast_to(signal, (40, *signal.shape))).astype(float)
    seas = {"signal": np.stack([signal] * 7), "background": np.stack([background] * 7)}
    means = {k: np.broadcast_to(v[0], counts.shape) for k, v in seas.items()}
    exact = ideal_observer(counts, **means)
    estimate = sea_marginal_observer(counts, **seas)
    assert np.isposinf(exact[counts[:, 0, 0, 1] > 0]).all()
    assert np.array_equal(np.isposinf(estimate), np.isposinf(exact))
    finite = np.isfinite(exact)
    assert finite.sum() > 10
    np.testing.assert_allclose(estimate[finite], exact[finite], rtol=1e-10, atol=1e-9)


def test_a_two_sea_mixture_is_the_exact_mixture_likelihood_ratio():
    """Two pixels; sea A (prior 3/4) shows the target in pixel 1, sea B (1/4) in pixel 2,
    and each lights the other pixel more. The mixture's likelihood ratio is
    (3 P(n|A1) + P(n|B1)) / (3 P(n|A0) + P(n|B0)); its AUC, by enumerating the counts, lies
    below the AUC of the observer who knows the sea, and the sampled AUC of the estimate is
    the exact one within its interval."""
    lam0 = {"A": np.array([2.0, 3.0]), "B": np.array([3.0, 2.0])}
    lam1 = {"A": np.array([5.0, 3.0]), "B": np.array([3.0, 5.0])}
    prior = {"A": 0.75, "B": 0.25}
    k = np.arange(45)
    grid = np.stack(np.meshgrid(k, k, indexing="ij"), axis=-1).reshape(-1, 2)

    def law(means):
        return poisson.pmf(grid, means).prod(axis=1)

    mixture1 = sum(prior[s] * law(lam1[s]) for s in prior)
    mixture0 = sum(prior[s] * law(lam0[s]) for s in prior)
    seas = ["A", "A", "A", "B"]  # a Monte Carlo sample of seas drawn 3 : 1
    scores = sea_marginal_observer(
        grid,
        signal=np.stack([lam1[s] for s in seas]),
        background=np.stack([lam0[s] for s in seas]),
    )
    np.testing.assert_allclose(scores, np.log(mixture1) - np.log(mixture0), rtol=1e-12)

    def exact_auc(llr, p1, p0):
        values, index = np.unique(np.round(llr, 9), return_inverse=True)
        law1 = np.bincount(index, weights=p1, minlength=len(values))
        law0 = np.bincount(index, weights=p0, minlength=len(values))
        return np.sum(law1 * (np.cumsum(law0) - law0 / 2))

    marginal = exact_auc(scores, mixture1, mixture0)
    known = sum(
        prior[s]
        * exact_auc(np.log(law(lam1[s])) - np.log(law(lam0[s])), law(lam1[s]), law(lam0[s]))
        for s in prior
    )
    assert known - marginal > 0.05  # not knowing the sea costs (0.872 against 0.818)
    # sampled: each sample's sea drawn from the prior, the estimate scored over the 4 seas
    n, draws = 4000, rng(2)
    drawn = np.where(draws.random(n) < prior["A"], 0, 1)
    means1 = np.stack([lam1["A"], lam1["B"]])[drawn]
    means0 = np.stack([lam0["A"], lam0["B"]])[drawn]
    seas_means = {
        "signal": np.stack([lam1[s] for s in seas]),
        "background": np.stack([lam0[s] for s in seas]),
    }
    s1 = sea_marginal_observer(draws.poisson(means1), **seas_means)
    s0 = sea_marginal_observer(draws.poisson(means0), **seas_means)
    low, high = bootstrap_auc(positives=s1, negatives=s0)
    assert low <= marginal <= high


SIGMA, BACKGROUND, TARGET = 0.8, 2.0, np.array([0.0, 0.0, 2.5, 2.5, 0.0, 0.0])
"""An independent-pixel sea: each pixel's light scaled by its own lognormal factor g (mean 1,
log-standard deviation SIGMA): λ₀ = BACKGROUND g, λ₁ = (BACKGROUND + TARGET) g."""


def wavy(seas, seed):
    g = np.exp(SIGMA * rng(seed).normal(size=(seas, len(TARGET))) - SIGMA**2 / 2)
    return (BACKGROUND + TARGET) * g, BACKGROUND * g


def exact_marginal(counts):
    """The exact sea-marginal log ratio of the independent-pixel sea: per pixel,
    E_g[P(n | λ g)] by Gauss–Hermite quadrature over the lognormal g."""
    z, w = roots_hermitenorm(80)
    g = np.exp(SIGMA * z - SIGMA**2 / 2)
    w = w / w.sum()
    total = 0.0
    for level, sign in ((BACKGROUND + TARGET, 1.0), (np.full(len(TARGET), BACKGROUND), -1.0)):
        pmf = poisson.pmf(counts[..., np.newaxis], level[:, np.newaxis] * g)  # (n, pixel, node)
        total = total + sign * np.log(pmf @ w).sum(axis=1)
    return total


@pytest.fixture(scope="module")
def wavy_test():
    """2000 test pairs, each on its own sea (the ideal observer's), and their counts."""
    signal, background = wavy(2000, seed=3)
    draws = rng(4)
    return signal, background, draws.poisson(signal), draws.poisson(background)


def test_on_a_wavy_sea_it_lies_between_chance_and_the_ideal_observer(wavy_test):
    signal, background, x1, x0 = wavy_test
    ideal = [ideal_observer(x, signal=signal, background=background) for x in (x1, x0)]
    seas = dict(zip(("signal", "background"), wavy(400, seed=5), strict=True))
    marginal = [sea_marginal_observer(x, **seas) for x in (x1, x0)]
    ideal_low, ideal_high = bootstrap_auc(positives=ideal[0], negatives=ideal[1])
    low, high = bootstrap_auc(positives=marginal[0], negatives=marginal[1])
    area = auc(positives=marginal[0], negatives=marginal[1])
    assert area <= ideal_high and low > 0.5
    # here the sea matters: the gap is far wider than either interval
    assert high < ideal_low
    # and the estimate is the exact marginal ratio's detector, within their intervals
    exact = [exact_marginal(x) for x in (x1, x0)]
    assert low <= auc(positives=exact[0], negatives=exact[1]) <= high


def test_its_auc_converges_as_the_seas_grow_and_its_error_shrinks_as_root_m(wavy_test):
    """16 independent samples of M seas each score the same 4000 images: the spread of their
    AUCs is the Monte Carlo error the bootstrap over one sample's seas estimates."""
    _, _, x1, x0 = wavy_test
    counts = np.concatenate([x1, x0])
    exact = exact_marginal(counts)
    exact_auc = auc(positives=exact[:2000], negatives=exact[2000:])
    errors, shortfalls = {}, {}
    for m in (25, 100, 400):
        pool_signal, pool_background = wavy(16 * m, seed=6)
        aucs, halves, bootstrapped = [], [], []
        for group in range(16):
            rows = slice(group * m, (group + 1) * m)
            likelihoods = sea_likelihoods(
                counts, signal=pool_signal[rows], background=pool_background[rows]
            )
            scores = likelihoods.scores()
            aucs.append(auc(positives=scores[:2000], negatives=scores[2000:]))
            error = sea_auc_error(likelihoods, positives=2000)
            assert error["seas"] == m
            halves.append(error["auc_half_seas"])
            bootstrapped.append(error["sea_auc_se"])
        # the standard deviation of 16 values is within ±36 % at 2 sigma; the bootstrap errs
        # high where the error falls faster than 1/√M (a resample holds 63 % of the seas)
        spread = np.std(aucs, ddof=1)
        assert 0.64 * spread < np.mean(bootstrapped) < 2 * spread
        errors[m] = np.mean(bootstrapped)
        assert np.mean(halves) < np.mean(aucs)  # half the seas: further below the ceiling
        shortfalls[m] = exact_auc - np.mean(aucs)
    # 4 times the seas: the error about halves (1/√M; 1/M would quarter it)
    for small, large in ((25, 100), (100, 400)):
        assert 1.5 < errors[small] / errors[large] < 3.0
    # and the AUC rises to the exact ratio's: the shortfall is positive and falls with M
    assert shortfalls[25] > shortfalls[100] > shortfalls[400] > 0
    assert shortfalls[400] < shortfalls[25] / 2


def test_an_image_no_sea_can_make_scores_nan_quietly():
    """Counts where every sea expects none, with and without the target: the likelihood
    ratio is 0/0, NaN (not evaluated), whole or bootstrapped, and no invalid-value warning
    (the service runs with warnings as errors; a Monte Carlo sweep's zero means met it)."""
    signal = np.array([[1.0, 0.0, 1.0], [2.0, 0.0, 1.0]])
    background = np.array([[0.5, 1.0, 0.0], [0.5, 1.0, 0.0]])
    image = np.array([[1.0, 0.0, 0.0], [1.0, 3.0, 2.0]])
    likelihoods = sea_likelihoods(image, signal=signal, background=background)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        whole = likelihoods.scores()
        resampled = likelihoods.scores(np.array([[1.0, 1.0], [2.0, 0.0]]))
    assert np.isfinite(whole[0]) and np.isnan(whole[1])
    assert np.isfinite(resampled[:, 0]).all() and np.isnan(resampled[:, 1]).all()
