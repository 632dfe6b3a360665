"""Detectors of a target in gated images, and the metrics of a detection test.

Pure numpy/scipy: every detector maps a batch of samples' gated images to one score per
sample (larger: more target-like), and the metrics turn the scores of samples with a target
(positives) and without (negatives) into a receiver operating characteristic (ROC), its
area (AUC) with a bootstrap interval, and the probability of detection at a fixed
false-alarm rate. ``service.detect`` pairs the samples of a sweep and runs these on its
cluster.

Rows of `positives` and `negatives` are realisations: row i of both saw the same sea
(common random numbers), so resampling for intervals draws realisations, keeping each
pair together.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter
from scipy.stats import rankdata

from workers.detectors.marginal import sea_likelihoods

__all__ = [
    "DETECTORS",
    "MIN_FALSE_ALARMS",
    "LogisticModel",
    "auc",
    "bootstrap_auc",
    "evaluate_pair",
    "fit_logistic",
    "gate_features",
    "held_out",
    "ideal_observer",
    "matched_filter",
    "matched_filter_weights",
    "pd_at_pfa",
    "roc_curve",
    "score_metrics",
    "sea_auc_error",
]

MIN_FALSE_ALARMS = 2
"""Fewest negatives that must lie above the threshold for Pd at a false-alarm rate α to be
reported: Pd at α needs at least ``MIN_FALSE_ALARMS / α`` negatives (200 at α = 10⁻²)."""

SEA_RESAMPLES = 200
"""Bootstrap resamples of the seas behind the sea-marginal observer's Monte Carlo error."""

BOOTSTRAP_BLOCK = 100
"""Resamples ranked at once: bounds the bootstrap's memory to ~100 x 2n scores."""

FEATURE_SMOOTHING = 3
"""Side of the box (pixels) averaged before the brightest and darkest pixel features."""

DETECTORS = {
    "ideal_observer": (
        "Poisson log-likelihood ratio of the noisy images between the expected images with "
        "and without the target under the sample's own sea (signal and sea known exactly): "
        "the most powerful test given the sea, an upper bound for any detector."
    ),
    "sea_marginal_observer": (
        "Poisson likelihood ratio with the sea integrated out: the mean likelihood of the "
        "image over the expected images with the target of the training realisations' seas, "
        "over the same without it (Monte Carlo over seas drawn from the same spectrum, in log "
        "space), evaluated on the held-out realisations. Knows the target and the sea's law, "
        "not the sea: the ceiling of a detector that sees only the image."
    ),
    "matched_filter": (
        "Prewhitened matched filter fused over gates: sum over pixels and gates of "
        "(m1 - m0) / v0 * (x - m0), with m1, m0 the mean expected images with and without "
        "the target over realisations and v0 = mean + variance over realisations of the "
        "target-free expected image (shot noise and sea clutter, pixels independent). "
        "Knows the target's mean signature, not the sea; shadows (m1 < m0) count as evidence."
    ),
    "logistic_regression": (
        "L2-regularised logistic regression on per-gate features (mean, standard deviation, "
        "brightest and darkest 3x3 box mean), trained on the even realisations and "
        "evaluated on the odd (held-out) ones; knows neither the sea nor the target."
    ),
}
"""Detector name -> description (with its assumptions), in the order the dataset holds them."""


def ideal_observer(image, *, signal, background):
    r"""Poisson log-likelihood ratio of noisy images, signal and background known exactly.

    Parameters
    ----------
    image : array_like, shape (samples, ...)
        Noisy photoelectron counts [photoelectrons], Poisson given the means.
    signal : array_like, shape of `image`
        Expected counts with the target, λ₁ [photoelectrons].
    background : array_like, shape of `image`
        Expected counts without the target under the same sea, λ₀ [photoelectrons].

    Returns
    -------
    ndarray of float64, shape (samples,)
        .. math::
            \Lambda = \sum_i x_i \ln(\lambda_{1i}/\lambda_{0i}) - (\lambda_{1i} - \lambda_{0i})

        summed over every axis but the first; ±inf where a count is possible under one
        hypothesis only (a pixel with x > 0 and λ = 0 under the other).

    Notes
    -----
    With independent Poisson pixels this is the log of the likelihood ratio (the
    :math:`\ln x_i!` terms cancel), the Neyman–Pearson optimal statistic when both means are
    known: for a realisation's sea it is the best any detector can do, and pooled over
    realisations (the sea is equally likely under both hypotheses) its ROC bounds every
    detector's. Pixels with λ₁ = λ₀ contribute nothing, 0 · ln 0 is 0.
    """
    x = np.asarray(image, dtype=np.float64)
    lam1 = np.asarray(signal, dtype=np.float64)
    lam0 = np.asarray(background, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        weight = np.where(lam1 == lam0, 0.0, np.log(lam1) - np.log(lam0))
        term = np.where(x > 0, x * weight, 0.0) - (lam1 - lam0)
    return term.reshape(term.shape[0], -1).sum(axis=1)


def matched_filter_weights(*, signal_mean, background_mean, background_variance):
    r"""Prewhitened template of a target: :math:`w = (m_1 - m_0) / v_0`.

    Parameters
    ----------
    signal_mean, background_mean : array_like, shape (frames, gates, y, x)
        Mean expected images with and without the target [photoelectrons].
    background_variance : array_like, shape (frames, gates, y, x)
        Variance of a target-free pixel [photoelectrons²]: shot noise (its mean) plus the
        sea's clutter (the variance of its expected value over realisations).

    Returns
    -------
    ndarray of float64
        Weights [1/photoelectrons]; 0 where the variance is 0.

    Notes
    -----
    With Gaussian pixels of a common diagonal covariance this is the Fisher discriminant;
    here pixels are Poisson mixtures whose covariance across pixels (the sea's caustics)
    is ignored, so the filter is not optimal, only the best linear one for independent
    pixels.
    """
    difference = np.asarray(signal_mean, np.float64) - np.asarray(background_mean, np.float64)
    variance = np.asarray(background_variance, dtype=np.float64)
    return np.divide(difference, variance, out=np.zeros_like(difference), where=variance > 0)


def matched_filter(image, *, weights, background_mean):
    r"""Matched-filter statistic of every gate: :math:`t_g = \sum w (x - m_0)`.

    Parameters
    ----------
    image : array_like, shape (samples, frames, gates, y, x)
        Noisy images [photoelectrons].
    weights : array_like, shape (frames, gates, y, x)
        Template from `matched_filter_weights` [1/photoelectrons].
    background_mean : array_like, shape (frames, gates, y, x)
        Mean target-free image [photoelectrons].

    Returns
    -------
    ndarray of float64, shape (samples, gates)
        One statistic per gate [1]; their sum over gates is the fused detector.
    """
    x = np.asarray(image, dtype=np.float64) - np.asarray(background_mean, dtype=np.float64)
    return (x * weights).sum(axis=(1, 3, 4))


def gate_features(image):
    """Features of a sample's gates that know neither sea nor target.

    Parameters
    ----------
    image : array_like, shape (samples, frames, gates, y, x)
        Noisy images [photoelectrons].

    Returns
    -------
    ndarray of float64, shape (samples, 4 * gates)
        Per gate (averaged over frames): mean, standard deviation, largest and smallest
        `FEATURE_SMOOTHING`² box mean [photoelectrons], gate-major.
    """
    x = np.asarray(image, dtype=np.float64)
    box = uniform_filter(x, size=(1, 1, 1, FEATURE_SMOOTHING, FEATURE_SMOOTHING), mode="nearest")
    features = np.stack(
        [
            x.mean(axis=(3, 4)),
            x.std(axis=(3, 4)),
            box.max(axis=(3, 4)),
            box.min(axis=(3, 4)),
        ],
        axis=-1,
    ).mean(axis=1)
    return features.reshape(features.shape[0], -1)


@dataclass(frozen=True)
class LogisticModel:
    """A fitted logistic regression on standardised features.

    Attributes
    ----------
    center, scale : ndarray, shape (features,)
        Training mean and standard deviation of each feature (scale 1 where constant).
    coefficients : ndarray, shape (features + 1,)
        Intercept first, then one weight per standardised feature.
    """

    center: np.ndarray
    scale: np.ndarray
    coefficients: np.ndarray

    def decision(self, features) -> np.ndarray:
        """Log-odds of a target for each row of `features` (the detector's score)."""
        z = (np.asarray(features, dtype=np.float64) - self.center) / self.scale
        return self.coefficients[0] + z @ self.coefficients[1:]


def fit_logistic(features, labels, *, penalty=1.0, iterations=50, tolerance=1e-10):
    r"""Fit an L2-penalised logistic regression by Newton's method (IRLS).

    Parameters
    ----------
    features : array_like, shape (samples, features)
        Training features (any units; standardised here).
    labels : array_like of bool, shape (samples,)
        True for samples with a target.
    penalty : float, keyword-only
        Weight λ of :math:`\frac{\lambda}{2}\lVert\beta\rVert^2` on the standardised
        features' weights (not the intercept) [1]; keeps separable data finite.
    iterations : int, keyword-only
        Most Newton steps.
    tolerance : float, keyword-only
        Stop when no coefficient moves more than this.

    Returns
    -------
    LogisticModel
    """
    x = np.asarray(features, dtype=np.float64)
    y = np.asarray(labels, dtype=np.float64)
    center = x.mean(axis=0)
    scale = x.std(axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    design = np.column_stack([np.ones(len(x)), (x - center) / scale])
    ridge = np.full(design.shape[1], float(penalty))
    ridge[0] = 0.0
    beta = np.zeros(design.shape[1])
    for _ in range(iterations):
        p = 0.5 * (1.0 + np.tanh(0.5 * (design @ beta)))  # logistic, without overflow
        gradient = design.T @ (y - p) - ridge * beta
        hessian = (design * (p * (1 - p))[:, np.newaxis]).T @ design + np.diag(ridge)
        step = np.linalg.solve(hessian + 1e-12 * np.eye(len(beta)), gradient)
        beta = beta + step
        if np.max(np.abs(step)) < tolerance:
            break
    return LogisticModel(center=center, scale=scale, coefficients=beta)


def held_out(realisations: int) -> np.ndarray:
    """Which realisations evaluate the trained detector (True) or train it: the odd ones."""
    return np.arange(realisations) % 2 == 1


def roc_curve(*, positives, negatives):
    """Empirical ROC: detection against false-alarm probability over every threshold.

    Parameters
    ----------
    positives, negatives : array_like, shape (n,) and (m,)
        Scores of samples with and without a target; a sample is declared a detection
        when its score is at least the threshold.

    Returns
    -------
    pfa, pd : ndarray of float64, shape (thresholds + 1,)
        From (0, 0) (threshold above every score) to (1, 1), one vertex per distinct score.
    """
    s1 = np.asarray(positives, dtype=np.float64)
    s0 = np.asarray(negatives, dtype=np.float64)
    thresholds = np.unique(np.concatenate([s1, s0]))[::-1]
    pd = (s1[np.newaxis, :] >= thresholds[:, np.newaxis]).mean(axis=1)
    pfa = (s0[np.newaxis, :] >= thresholds[:, np.newaxis]).mean(axis=1)
    return np.concatenate([[0.0], pfa]), np.concatenate([[0.0], pd])


def _auc_rows(s1, s0):
    """AUC of each row of `s1` (…, n) against the same row of `s0` (…, m)."""
    n, m = s1.shape[-1], s0.shape[-1]
    ranks = rankdata(np.concatenate([s1, s0], axis=-1), axis=-1)
    return (ranks[..., :n].sum(axis=-1) - n * (n + 1) / 2) / (n * m)


def auc(*, positives, negatives) -> float:
    r"""Area under the ROC: :math:`P(S_1 > S_0) + \tfrac12 P(S_1 = S_0)` (Mann–Whitney).

    Parameters
    ----------
    positives, negatives : array_like, shape (n,) and (m,)
        Scores of samples with and without a target.

    Returns
    -------
    float
        In [0, 1]; 0.5 for a detector that cannot tell the classes apart.
    """
    s1 = np.asarray(positives, dtype=np.float64)
    s0 = np.asarray(negatives, dtype=np.float64)
    return float(_auc_rows(s1, s0))


def bootstrap_auc(*, positives, negatives, resamples=2000, level=0.95, seed=0):
    """Percentile bootstrap interval of the AUC, resampling realisations (pairs).

    Parameters
    ----------
    positives, negatives : array_like, shape (n,)
        Scores; row i of both comes from realisation i (the same sea), so realisations
        are drawn with replacement and each keeps both its scores.
    resamples : int, keyword-only
        Bootstrap resamples.
    level : float, keyword-only
        Coverage of the interval, in (0, 1).
    seed : int, keyword-only
        Seed of the resampling (fixed: the same scores give the same interval).

    Returns
    -------
    low, high : float
        The (1 − level)/2 and (1 + level)/2 quantiles of the resampled AUCs.
    """
    s1 = np.asarray(positives, dtype=np.float64)
    s0 = np.asarray(negatives, dtype=np.float64)
    if s1.shape != s0.shape:
        raise ValueError(f"paired scores must match: {s1.shape} positives, {s0.shape} negatives")
    rng = np.random.Generator(np.random.PCG64(seed))
    picks = rng.integers(0, len(s1), size=(resamples, len(s1)))
    if np.isnan(s1).any() or np.isnan(s0).any():  # no order: as the ranks' NaN AUCs
        return float("nan"), float("nan")
    values = np.concatenate(
        [
            _resampled_aucs(s1, s0, block)
            for block in np.array_split(picks, -(-resamples // BOOTSTRAP_BLOCK))
        ]
    )
    low, high = np.quantile(values, [(1 - level) / 2, (1 + level) / 2])
    return float(low), float(high)


def _resampled_aucs(s1, s0, picks):
    """`_auc_rows` of ``s1[picks]`` against ``s0[picks]``, the scores sorted once.

    Each resample (row of `picks`, realisation indices) holds every score of realisation i
    as many times as it picks i: the scores are sorted once, and a resample's ranks (ties
    averaged, as `scipy.stats.rankdata`'s) follow from those counts by cumulative sums,
    instead of ranking 2n scores per resample. The rank sums are sums of half-integers,
    exact in float64, so the AUCs are `_auc_rows`'s to the bit.
    """
    n, rows = len(s1), len(picks)
    values = np.concatenate([s1, s0])
    order = np.argsort(values, kind="stable")
    ordered = values[order]
    new = np.concatenate([[True], ordered[1:] != ordered[:-1]])  # first of each tie
    group = np.cumsum(new) - 1
    positive = order < n
    counts = np.bincount((np.arange(rows)[:, None] * n + picks).ravel(), minlength=rows * n)
    copies = counts.reshape(rows, n)[:, order % n].astype(np.float64)
    ties = np.add.reduceat(copies, np.flatnonzero(new), axis=1)
    rank = np.cumsum(ties, axis=1) - (ties - 1) / 2  # the mean rank of each tie
    ranks = (copies[:, positive] * rank[:, group[positive]]).sum(axis=1)
    return (ranks - n * (n + 1) / 2) / (n * len(s0))


def sea_auc_error(likelihoods, *, positives, resamples=SEA_RESAMPLES, seed=0):
    r"""Monte Carlo error of the sea-marginal observer's AUC, from its sample of seas.

    Parameters
    ----------
    likelihoods : workers.detectors.marginal.SeaLikelihoods
        The images scored: the first `positives` rows with the target, the others without.
    positives : int, keyword-only
        Images with the target.
    resamples : int, keyword-only
        Bootstrap resamples of the seas.
    seed : int, keyword-only
        Seed of the resampling (fixed: the same images and seas give the same error).

    Returns
    -------
    dict of float
        ``sea_auc_se``: the standard deviation of the AUC over the seas resampled with
        replacement, the images held fixed [1]; ``auc_half_seas``: the mean AUC of two
        disjoint halves of the seas, each scoring every image [1]; ``effective_seas``: the
        median over the images of `SeaLikelihoods.effective_seas` [seas]; ``seas``: M.

    Notes
    -----
    The sea-marginal AUC has two independent errors: the images' (the realisation pairs'
    bootstrap, `bootstrap_auc`, as every detector's) and the seas' behind the estimate of
    Λ (this one: the bootstrap over seas estimates the spread of the AUC across
    independent samples of M seas, which falls as :math:`1/\sqrt M`); they add in
    quadrature. The estimate with M seas is itself a detector, so its AUC lies below the
    exact ratio's by a shortfall of second order in Λ's error, about c/M: the AUC with M
    seas less the AUC with M/2 estimates the shortfall left at M.
    """
    seas = likelihoods.with_target.shape[1]
    rng = np.random.Generator(np.random.PCG64(seed))
    counts = rng.multinomial(seas, np.full(seas, 1.0 / seas), size=resamples).astype(float)
    halves = np.zeros((2, seas))
    halves[0, : seas // 2] = halves[1, seas // 2 : 2 * (seas // 2)] = 1.0
    scores = likelihoods.scores(np.concatenate([counts, halves]))
    aucs = _auc_rows(scores[:, :positives], scores[:, positives:])
    return {
        "sea_auc_se": float(aucs[:resamples].std(ddof=1)),
        "auc_half_seas": float(aucs[resamples:].mean()),
        "effective_seas": float(np.median(likelihoods.effective_seas())),
        "seas": seas,
    }


def pd_at_pfa(*, positives, negatives, pfa, min_false_alarms=MIN_FALSE_ALARMS):
    """Probability of detection at a false-alarm probability, where the negatives allow.

    Parameters
    ----------
    positives, negatives : array_like, shape (n,) and (m,)
        Scores of samples with and without a target.
    pfa : float, keyword-only
        False-alarm probability α, in (0, 1).
    min_false_alarms : int, keyword-only
        Fewest negatives that must lie above the threshold: with fewer than
        ``min_false_alarms / α`` negatives the rate is not measured but extrapolated, and
        the result is unavailable.

    Returns
    -------
    float
        Fraction of positives above the threshold t, the ⌊α m⌋ + 1-th largest negative
        score (so at most a fraction α of negatives lies above it); NaN when unavailable.
    """
    s1 = np.asarray(positives, dtype=np.float64)
    s0 = np.sort(np.asarray(negatives, dtype=np.float64))[::-1]
    allowed = int(np.floor(pfa * len(s0) + 1e-9))
    if allowed < min_false_alarms or allowed >= len(s0):
        return float("nan")
    return float((s1 > s0[allowed]).mean())


def score_metrics(*, positives, negatives, pfa) -> dict:
    """One detector's metrics from its paired scores, NaN where it is not evaluated.

    Parameters
    ----------
    positives, negatives : array_like, shape (realisations,)
        Scores of the samples with and without the target, row i of both realisation i's;
        a realisation where either is NaN is left out (all of them: the detector is not
        evaluated, every metric NaN).
    pfa : sequence of float, keyword-only
        False-alarm probabilities at which to report the probability of detection.

    Returns
    -------
    dict
        ``evaluated`` (the pairs used), ``auc``, ``auc_low``, ``auc_high``
        (`bootstrap_auc`), ``pd`` (one per `pfa`, NaN where unavailable: `pd_at_pfa`).
    """
    s1, s0 = np.asarray(positives, np.float64), np.asarray(negatives, np.float64)
    rows = ~(np.isnan(s1) | np.isnan(s0))
    if not rows.any():  # not evaluated (e.g. the sea-marginal observer's inf - inf everywhere)
        nan = float("nan")
        return {
            "evaluated": 0,
            "auc": nan,
            "auc_low": nan,
            "auc_high": nan,
            "pd": np.full(len(pfa), nan),
        }
    s1, s0 = s1[rows], s0[rows]
    low, high = bootstrap_auc(positives=s1, negatives=s0)
    return {
        "evaluated": int(rows.sum()),
        "auc": auc(positives=s1, negatives=s0),
        "auc_low": low,
        "auc_high": high,
        "pd": np.array([pd_at_pfa(positives=s1, negatives=s0, pfa=alpha) for alpha in pfa]),
    }


def evaluate_pair(
    *, positive_image, positive_expected, negative_image, negative_expected, test, pfa
):
    """Scores and metrics of every detector on one positive point and its negatives.

    Parameters
    ----------
    positive_image, positive_expected : ndarray, shape (realisations, frames, gates, y, x)
        Noisy and expected images of the point with the target [photoelectrons].
    negative_image, negative_expected : ndarray, same shape
        The same realisations (the same seas) of the target-free point.
    test : ndarray of bool, shape (realisations,)
        Held-out realisations (the trained detector learns on the others).
    pfa : sequence of float
        False-alarm probabilities at which to report the probability of detection.

    Returns
    -------
    dict of ndarray
        ``score_positive``, ``score_negative`` (detector, realisation; NaN where a detector
        is not evaluated); ``auc``, ``auc_low``, ``auc_high``, ``evaluated``
        (detector,); ``pd`` (detector, pfa; NaN where unavailable); ``gate_auc``,
        ``gate_auc_low``, ``gate_auc_high`` (gates,): the matched filter of each gate alone;
        the sea-marginal observer's Monte Carlo error (`sea_auc_error`: ``sea_auc_se``,
        ``auc_half_seas``, ``effective_seas``, ``seas``), its seas the training
        realisations', its images the held-out ones.
    """
    realisations = positive_image.shape[0]
    signal_mean = positive_expected.mean(axis=0, dtype=np.float64)
    background_mean = negative_expected.mean(axis=0, dtype=np.float64)
    background_variance = background_mean + negative_expected.var(axis=0, dtype=np.float64)
    weights = matched_filter_weights(
        signal_mean=signal_mean,
        background_mean=background_mean,
        background_variance=background_variance,
    )
    gate_scores = [
        matched_filter(image, weights=weights, background_mean=background_mean)
        for image in (positive_image, negative_image)
    ]
    train = ~test
    model = fit_logistic(
        np.concatenate(
            [gate_features(positive_image[train]), gate_features(negative_image[train])]
        ),
        np.concatenate([np.ones(train.sum(), bool), np.zeros(train.sum(), bool)]),
    )
    marginal = sea_likelihoods(  # the training realisations' seas score the held-out ones
        np.concatenate([positive_image[test], negative_image[test]]),
        signal=positive_expected[train],
        background=negative_expected[train],
    )
    scores = np.full((len(DETECTORS), 2, realisations), np.nan)
    scores[1][:, test] = marginal.scores().reshape(2, -1)
    for column, image in enumerate((positive_image, negative_image)):
        scores[0, column] = ideal_observer(
            image, signal=positive_expected, background=negative_expected
        )
        scores[2, column] = gate_scores[column].sum(axis=1)
        scores[3, column, test] = model.decision(gate_features(image[test]))
    result = {
        "score_positive": scores[:, 0],
        "score_negative": scores[:, 1],
        "auc": np.full(len(DETECTORS), np.nan),
        "auc_low": np.full(len(DETECTORS), np.nan),
        "auc_high": np.full(len(DETECTORS), np.nan),
        "evaluated": np.zeros(len(DETECTORS), np.int32),
        "pd": np.full((len(DETECTORS), len(pfa)), np.nan),
        **sea_auc_error(marginal, positives=int(test.sum())),
    }
    for row in range(len(DETECTORS)):
        metrics = score_metrics(positives=scores[row, 0], negatives=scores[row, 1], pfa=pfa)
        for name, value in metrics.items():
            result[name][row] = value
    gates = gate_scores[0].shape[1]
    result["gate_auc"] = np.array(
        [auc(positives=gate_scores[0][:, g], negatives=gate_scores[1][:, g]) for g in range(gates)]
    )
    intervals = np.array(
        [
            bootstrap_auc(positives=gate_scores[0][:, g], negatives=gate_scores[1][:, g])
            for g in range(gates)
        ]
    ).reshape(gates, 2)
    result["gate_auc_low"], result["gate_auc_high"] = intervals[:, 0], intervals[:, 1]
    return result
