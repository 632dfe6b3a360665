r"""The sea-marginal observer: the Poisson likelihood ratio with the sea integrated out.

The ideal observer (`workers.detectors.detection.ideal_observer`) knows the sample's own sea. A
detector that sees only the image cannot: the best it can do is the likelihood ratio of the
image with the sea integrated out over its law (the wave spectrum),

.. math::
    \Lambda(n) = \frac{E_{\text{sea}}[P(n \mid \lambda_1(\text{sea}))]}
                      {E_{\text{sea}}[P(n \mid \lambda_0(\text{sea}))]},

the Neyman–Pearson optimal test for a sea unknown but drawn from the spectrum: the ceiling
of a detector trained on the dataset. Both expectations are estimated by Monte Carlo over M
seas: the expected images with (λ₁) and without (λ₀) the target of other realisations of
the same parameter point, drawn from the same spectrum, the same M seas above and below
(common random numbers), in log space.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp

__all__ = ["SeaLikelihoods", "sea_likelihoods", "sea_marginal_observer"]


@dataclass(frozen=True)
class SeaLikelihoods:
    r"""Log-likelihoods of images under each sea of a Monte Carlo sample, both hypotheses.

    Attributes
    ----------
    with_target, without_target : ndarray of float64, shape (samples, seas)
        :math:`\ln P(n_s \mid \lambda_{1j})` and :math:`\ln P(n_s \mid \lambda_{0j})` for
        image s and sea j, less :math:`\sum_i \ln n_{si}!` (the same in both: it cancels in
        every ratio); -inf where image s holds a count sea j cannot make.
    """

    with_target: np.ndarray
    without_target: np.ndarray

    def scores(self, counts=None) -> np.ndarray:
        r"""Log of the sea-marginal likelihood ratio of every image.

        Parameters
        ----------
        counts : array_like, shape (resamples, seas), optional
            How many times each sea enters each resample (a bootstrap over seas, or 0/1 to
            keep a subset); None: every sea once.

        Returns
        -------
        ndarray of float64, shape (samples,), or (resamples, samples) with `counts`
            .. math::
                \ln\hat\Lambda(n) = \ln \sum_j c_j P(n \mid \lambda_{1j})
                                  - \ln \sum_j c_j P(n \mid \lambda_{0j})

            (the common :math:`1/\sum_j c_j` cancels); +inf (-inf) where no sea without
            (with) the target can make the image, NaN where none of either can.
        """
        with np.errstate(invalid="ignore"):  # -inf - -inf: no sea can make the image, NaN
            if counts is None:
                return logsumexp(self.with_target, axis=1) - logsumexp(self.without_target, axis=1)
            c = np.asarray(counts, dtype=np.float64)
            return _log_sums(self.with_target, c) - _log_sums(self.without_target, c)

    def effective_seas(self) -> np.ndarray:
        r"""Effective number of seas weighting each image, :math:`1 / \sum_j w_j^2`.

        Returns
        -------
        ndarray of float64, shape (samples,)
            With :math:`w_j \propto P(n \mid \lambda_{0j})`, the posterior of the M seas
            given the image without the target (the self-normalised importance weights of
            the spectrum's draws): M when the image cannot tell the seas apart, 1 when one
            sea explains it far better than every other (then the estimate is that sea's
            likelihood ratio, and its Monte Carlo error is large). NaN for an image no sea
            can make.
        """
        log_w = self.without_target - logsumexp(self.without_target, axis=1, keepdims=True)
        return 1.0 / np.exp(2 * log_w).sum(axis=1)


def _log_sums(log_terms, counts):
    r""":math:`\ln \sum_j c_{bj} e^{L_{sj}}` for every resample b and row s: (resamples, rows).

    One product of the terms scaled by their row's largest (exact in float64 down to
    e^-700 of it); where a resample leaves out every term within that range of the row's
    largest, the sum is taken again in log space.
    """
    top = log_terms.max(axis=1)
    finite = np.isfinite(top)
    shifted = np.exp(log_terms - np.where(finite, top, 0.0)[:, np.newaxis])
    with np.errstate(divide="ignore"):
        sums = np.log(counts @ shifted.T) + top
    lost = np.isneginf(sums) & finite
    if lost.any():
        b, s = np.nonzero(lost)
        with np.errstate(divide="ignore"):
            sums[b, s] = logsumexp(log_terms[s] + np.log(counts[b]), axis=1)
    return sums


def _log_likelihoods(x, means):
    """`SeaLikelihoods`' matrix of images `x` (samples, pixels) under `means` (seas, pixels)."""
    zero = means == 0
    log_means = np.log(np.where(zero, 1.0, means))
    log_likelihood = x @ log_means.T - means.sum(axis=1)
    if zero.any():  # a count where a sea's mean is 0 is impossible under that sea
        impossible = (x > 0).astype(np.float64) @ zero.T > 0
        log_likelihood[impossible] = -np.inf
    return log_likelihood


def sea_likelihoods(image, *, signal, background) -> SeaLikelihoods:
    """The log-likelihoods of `image` under every sea of a Monte Carlo sample.

    Parameters
    ----------
    image : array_like, shape (samples, ...)
        Noisy photoelectron counts [photoelectrons], Poisson given the means.
    signal, background : array_like, shape (seas, ...)
        Expected counts with (λ₁) and without (λ₀) the target, one row per sea of the Monte
        Carlo sample, row j of both on the same sea [photoelectrons]; never the seas of the
        images scored (the estimate would know the sea).

    Returns
    -------
    SeaLikelihoods

    Notes
    -----
    Pixels whose mean is 0 under every sea and both hypotheses tell nothing and are left
    out (as the ideal observer leaves out the pixels with λ₁ = λ₀): their counts are 0 in
    any image these means make.
    """
    x = np.asarray(image, dtype=np.float64)
    x = x.reshape(x.shape[0], -1)
    lam1 = np.asarray(signal, dtype=np.float64)
    lam1 = lam1.reshape(lam1.shape[0], -1)
    lam0 = np.asarray(background, dtype=np.float64).reshape(lam1.shape)
    lit = (lam1 > 0).any(axis=0) | (lam0 > 0).any(axis=0)
    x, lam1, lam0 = x[:, lit], lam1[:, lit], lam0[:, lit]
    return SeaLikelihoods(
        with_target=_log_likelihoods(x, lam1), without_target=_log_likelihoods(x, lam0)
    )


def sea_marginal_observer(image, *, signal, background):
    r"""Log of the sea-marginal likelihood ratio, estimated over a Monte Carlo sample of seas.

    Parameters
    ----------
    image : array_like, shape (samples, ...)
        Noisy photoelectron counts [photoelectrons].
    signal, background : array_like, shape (seas, ...)
        Expected counts with and without the target on each of M seas [photoelectrons].

    Returns
    -------
    ndarray of float64, shape (samples,)
        .. math::
            \ln\hat\Lambda(n) = \operatorname{logsumexp}_j \ln P(n \mid \lambda_{1j})
                              - \operatorname{logsumexp}_j \ln P(n \mid \lambda_{0j})

    Notes
    -----
    With the same seas above and below, the estimate is the self-normalised importance
    sampling estimate of :math:`E[\Lambda_{\text{sea}}(n) \mid n, H_0]`, the per-sea
    likelihood ratio averaged over the seas' posterior given the image, with the spectrum as
    proposal. For any fixed sample of seas it is a statistic of the image alone, so its ROC
    lies below the exact marginal ratio's (Neyman–Pearson) and its AUC is a lower bound of
    the ceiling that rises to it as M grows; the shortfall is second order in the
    estimate's error (the exact ratio is the optimum), so it falls as 1/M. On a flat sea
    (every sea the same) it is the ideal observer's statistic exactly.
    """
    return sea_likelihoods(image, signal=signal, background=background).scores()
