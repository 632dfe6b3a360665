"""Sensor noise: Poisson shot noise and an optional intensifier (ICCD) gain stage."""

from __future__ import annotations

import numpy as np

__all__ = ["poisson_counts", "shot_noise"]

INVERSION_LIMIT = 1.0
"""Largest mean count λ drawn by vectorised inversion; larger means use ``rng.poisson``."""

_INVERSION_STEPS = 40
"""Most counts inversion can return: P(N > 40) < 1e-48 for λ <= 1, far below 2⁻⁵³."""


def poisson_counts(expected, *, rng, dtype=np.int64):
    r"""Exact Poisson counts, fast when most means are small (dim gated images).

    Parameters
    ----------
    expected : array_like
        Mean counts λ >= 0 [photoelectrons], any shape.
    rng : numpy.random.Generator
        Source of randomness.
    dtype : numpy dtype, optional
        Of the result; float32 holds counts exactly up to 2²⁴.

    Returns
    -------
    ndarray
        Counts :math:`n \sim \mathrm{Poisson}(\lambda)`, shape of `expected`.

    Notes
    -----
    ``rng.poisson`` spends 10–25 ns per value whatever λ, which for the dim images of a
    gated receiver (λ ~ 10⁻³) dominated the render. Here one uniform W ∈ [0, 1) is drawn
    per value (all of them, in C order), then:

    - values with λ > `INVERSION_LIMIT` are drawn by ``rng.poisson`` (in C order, after the
      uniforms; their W is unused);
    - the others by inversion of the tail Q(k) = P(N > k): N > k iff W < Q(k), with
      :math:`Q(0) = 1 - e^{-\lambda}` (``-expm1(-λ)``, accurate for small λ) and
      :math:`Q(k) = Q(k-1) - e^{-\lambda}\lambda^k/k!`. Since Q(0) <= λ, only values with
      W < λ need any arithmetic; the loop over k runs on the shrinking set of values still
      above k.

    The law is exact up to the 2⁻⁵³ resolution of W and float64 rounding of Q (absolute
    errors ~1e-16 in the probabilities). The stream of draws differs from a plain
    ``rng.poisson(expected)``: the same seed gives the same counts as itself only.
    """
    lam = np.asarray(expected, dtype=np.float64)
    shape = lam.shape
    lam = lam.ravel()
    counts = np.zeros(lam.size, dtype=dtype)
    w = rng.random(lam.size)
    high = lam > INVERSION_LIMIT
    if high.any():
        counts[high] = rng.poisson(lam[high])
    index = np.flatnonzero((w < lam) & ~high)
    if index.size:
        w, lam = w[index], lam[index]
        term = np.exp(-lam)  # P(N = k), k = 0
        tail = -np.expm1(-lam)  # Q(0) = P(N > 0)
        for k in range(1, _INVERSION_STEPS + 1):
            above = w < tail
            if not above.all():
                index, w, lam, term, tail = (a[above] for a in (index, w, lam, term, tail))
            if not index.size:
                break
            counts[index] = k
            term *= lam / k
            tail -= term
    return counts.reshape(shape)


def shot_noise(expected, *, rng, gain=1.0, excess_noise=1.0):
    r"""Draw a noisy image from its expected photoelectron counts.

    Parameters
    ----------
    expected : ndarray
        Mean photoelectron count λ of every pixel [photoelectrons], >= 0.
    rng : numpy.random.Generator
        Source of randomness.
    gain : float, optional
        Mean output counts per photoelectron G of the intensifier [counts/photoelectron].
    excess_noise : float, optional
        Excess-noise factor F >= 1 of the gain stage [1].

    Returns
    -------
    ndarray, float32
        Counts. With ``gain == excess_noise == 1`` these are the photoelectron counts
        :math:`n \sim \mathrm{Poisson}(\lambda)` (paper §4.7), drawn by `poisson_counts`.

    Notes
    -----
    Each photoelectron is amplified independently with mean G and variance
    :math:`G^2(F-1)`. The sum of n such gains is drawn as one Gamma variable of shape
    n/(F-1) and scale G(F-1), so that

    .. math:: \mathrm{E}[c] = G\lambda,\qquad \mathrm{Var}[c] = G^2 F \lambda,

    the usual definition of the excess-noise factor. With F = 1 the gain is noiseless.

    References
    ----------
    Carmona, Cérou & Blasco (2000), §4.7. Hynecek, J. & Nishiwaki, T. (2003). Excess noise
    and other important characteristics of low light level imaging using charge
    multiplying CCDs. IEEE Trans. Electron Devices 50(1), 239–245.
    """
    counts = poisson_counts(expected, rng=rng, dtype=np.float32)
    if excess_noise > 1.0:
        spread = excess_noise - 1.0
        amplified = np.zeros(counts.shape)
        lit = counts > 0
        amplified[lit] = rng.gamma(counts[lit].astype(np.float64) / spread, gain * spread)
        return amplified.astype(np.float32)
    if gain != 1.0:
        return (gain * counts.astype(np.float64)).astype(np.float32)
    return counts
