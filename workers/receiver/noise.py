"""Sensor noise: Poisson shot noise and an optional intensifier (ICCD) gain stage."""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["poisson_counts", "shot_noise"]

INVERSION_LIMIT = 1.0
"""Largest mean count λ drawn by vectorised inversion; larger means by `_draw_large`."""

REJECTION_LIMIT = 10.0
"""Smallest mean count λ drawn by transformed rejection (PTRS); smaller ones by search."""

LARGEST_MEAN = 4e9
"""Largest mean count λ drawn by the compiled search and PTRS (counts λ + 20√λ < 2³², the
table of ln k! and Stirling's series checked to there); larger means by ``rng.poisson``."""

POOL_LIMIT = 1 << 20
"""Most uniforms drawn at once for transformed rejection; the counts do not depend on it."""

_INVERSION_STEPS = 40
"""Most counts inversion can return: P(N > 40) < 1e-48 for λ <= 1, far below 2⁻⁵³."""

_SEARCH_STEPS = 60
"""Most counts sequential search can return: P(N > 60) < 1e-27 for λ < 10."""

_BLOCK = 64
"""Values drawn together: their searches at once, their PTRS first tries before the rest."""

_UNIFORMS_PER_MEAN = 1.5
"""Pool uniforms drawn for each mean left to PTRS: 1.25 (large λ) to 1.66 (λ = 10) used."""

_LOG_FACTORIALS = np.array([math.lgamma(k + 1.0) for k in range(2048)])
"""ln k! for k < 2048, for PTRS's full test."""


def poisson_counts(expected, *, rng, dtype=np.int64):
    r"""Exact Poisson counts, fast for any means (dim gated images or bright ones).

    Parameters
    ----------
    expected : array_like
        Mean counts λ >= 0 [photoelectrons], finite, any shape.
    rng : numpy.random.Generator
        Source of randomness.
    dtype : numpy dtype, optional
        Of the result; float32 holds counts exactly up to 2²⁴.

    Returns
    -------
    ndarray
        Counts :math:`n \sim \mathrm{Poisson}(\lambda)`, shape of `expected`.

    Raises
    ------
    ValueError
        From ``rng.poisson``, for an infinite mean or one beyond about 9.2e18.

    Notes
    -----
    ``rng.poisson`` spends 10–25 ns per value at small λ, which for the dim images of a
    gated receiver (λ ~ 10⁻³) dominated the render, and about 50 ns at the λ ~ 5–35000 of
    absolute radiometry. Here one uniform W ∈ [0, 1) is drawn per value (all of them, in
    C order), then:

    - values with λ <= `INVERSION_LIMIT` by inversion of the tail Q(k) = P(N > k): N > k
      iff W < Q(k), with :math:`Q(0) = 1 - e^{-\lambda}` (``-expm1(-λ)``, accurate for
      small λ) and :math:`Q(k) = Q(k-1) - e^{-\lambda}\lambda^k/k!`. Since Q(0) <= λ, only
      values with W < λ need any arithmetic; the loop over k runs on the shrinking set of
      values still above k;
    - values with 1 < λ < `REJECTION_LIMIT` by sequential search on their own W: N is the
      least k with W < P(N <= k), the running sum of :math:`e^{-\lambda}\lambda^j/j!`
      (for the values of a block of `_BLOCK` at once, a loop the compiler vectorises);
    - values with λ >= `REJECTION_LIMIT` by Hörmann's transformed rejection with squeeze
      (PTRS, the method of ``numpy.random``), two uniforms (U, V) a try, 0.75 (λ = 10) to
      0.89 (large λ) of the tries accepted. A value's first try takes its W as U; every
      other uniform comes from pools drawn from `rng` after the W (at most `POOL_LIMIT` at
      once), taken in order by blocks of `_BLOCK` values (C order): the V of the first
      tries of the block's values, then, for each value in turn that the squeeze did not
      accept, its further tries (U, V). The full test compares with ln P(N = k), from a
      table of ln k! below k = 2048 and above from Stirling's series and ``log1p`` (errors
      against 50-digit arithmetic below 2e-12 up to λ = 1e3, 7e-12 at 1e7, 1.5e-10 at 4e9,
      twelve standard deviations out, where k ln λ − λ − ln k! loses about λ ln λ · 2⁻⁵³:
      8e-6 at 4e9);
    - values with λ > `LARGEST_MEAN` (an ICCD image of a very bright scene: its counts are
      not bounded by a store type) by ``rng.poisson``, in C order after the pools.

    A block whose pool runs out is drawn again from its first uniform, carried on into the
    next pool: the counts do not depend on the pool size, only the generator's state
    afterwards does (a fixed function of the means with the default pools). The law is
    exact up to the 2⁻⁵³ resolution of the uniforms and float64 rounding (absolute errors
    ~1e-15 in the probabilities). The draws differ from a plain ``rng.poisson(expected)``;
    those of λ > 1 also differ from this function's before search and PTRS (which called
    ``rng.poisson`` on them), those of λ <= 1 do not. The same seed gives the same counts
    with the same code.

    References
    ----------
    Hörmann, W. (1993). The transformed rejection method for generating Poisson random
    variables. Insurance: Mathematics and Economics 12(1), 39–45. Devroye, L. (1986).
    Non-Uniform Random Variate Generation, §X.3 (sequential search). Springer.
    """
    lam = np.asarray(expected, dtype=np.float64)
    shape = lam.shape
    lam = lam.ravel()
    counts = np.zeros(lam.size, dtype=dtype)
    w = rng.random(lam.size)
    if (lam > INVERSION_LIMIT).any():
        _large_counts(lam, w, counts, rng)
    index = np.flatnonzero((w < lam) & (lam <= INVERSION_LIMIT))
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


def _large_counts(lam, w, counts, rng):
    """Draw the `counts` of means λ > `INVERSION_LIMIT` (on `w` and pools, then numpy's).

    By search on `w` or by PTRS up to `LARGEST_MEAN`, then the larger ones by
    ``rng.poisson`` (in C order).
    """
    huge = lam > LARGEST_MEAN
    drawn = np.where(huge, 0.0, lam) if huge.any() else lam  # 0: skipped by the kernel
    pool, start = np.empty(0), 0
    while True:
        start, used = _draw_large(drawn, w, counts, start, pool)
        if start == drawn.size:
            break
        size = math.ceil(_UNIFORMS_PER_MEAN * np.count_nonzero(drawn[start:] >= REJECTION_LIMIT))
        fresh = rng.random(min(size, POOL_LIMIT))
        pool = np.concatenate((pool[used:], fresh)) if used < pool.size else fresh
    if huge.any():
        counts[huge] = rng.poisson(lam[huge])


@numba.njit(cache=True)
def _draw_large(lam, w, counts, start, pool):
    """Draw ``counts[i]`` of the means ``lam[i] > 1`` for i >= `start`, on `w` or `pool`.

    Means below `REJECTION_LIMIT` by search on their `w`, the others by PTRS, the first
    try (`w`, next of `pool`), the others on the next two of `pool`. Values go in blocks of
    `_BLOCK`: the first tries of a block's PTRS means, its searches, then the PTRS means
    their squeeze did not accept, one by one to the end (their first try's full test, then
    new tries). When `pool` runs out, returns the index of the block and the uniforms used
    before it (``lam.size`` and all used once all are drawn): the next call, with the rest
    of `pool` first, draws that block again from the same uniforms.
    """
    pending = np.empty(_BLOCK, dtype=np.int64)
    first = np.empty(_BLOCK, dtype=np.int64)
    found = np.empty(_BLOCK, dtype=np.int64)
    searched = np.empty((5, _BLOCK))
    used = 0
    for block in range(start, lam.size, _BLOCK):
        before, waiting, searching = used, 0, 0
        for i in range(block, min(block + _BLOCK, lam.size)):
            mean = lam[i]
            if not mean > INVERSION_LIMIT:
                continue
            if mean < REJECTION_LIMIT:
                found[searching], searched[0, searching], searched[1, searching] = i, mean, w[i]
                searching += 1
                continue
            if used + 1 > pool.size:
                return block, before
            b, a = _hat(mean)
            k, u_s = _candidate(mean, b, a, w[i])
            counts[i] = max(k, 0.0)
            pending[waiting], first[waiting] = i, used
            waiting += not _squeezed(b, u_s, pool[used])
            used += 1
        _search(searched, searching)
        for j in range(searching):
            counts[found[j]] = searched[4, j]
        retrying = 0
        for j in range(waiting):
            i, at = pending[j], first[j]
            b, a = _hat(lam[i])
            k, u_s = _candidate(lam[i], b, a, w[i])
            pending[retrying] = i
            retrying += not _accepted(lam[i], b, a, k, u_s, pool[at])
        for j in range(retrying):
            i = pending[j]
            b, a = _hat(lam[i])
            while True:
                if used + 2 > pool.size:
                    return block, before
                k, u_s = _candidate(lam[i], b, a, pool[used])
                v = pool[used + 1]
                used += 2
                if _squeezed(b, u_s, v) or _accepted(lam[i], b, a, k, u_s, v):
                    break
            counts[i] = k
    return lam.size, used


@numba.njit(cache=True)
def _hat(mean):
    """PTRS's hat parameters b and a for mean λ >= 10 [1]."""
    b = 0.931 + 2.53 * math.sqrt(mean)
    return b, -0.059 + 0.02483 * b


@numba.njit(cache=True, error_model="numpy")
def _candidate(mean, b, a, uniform):
    """The candidate k (a float, maybe negative) of a PTRS try and its u_s = 0.5 − |U|.

    A uniform of exactly 0 gives u_s = 0 and k = −inf, a try `_accepted` rejects (as
    numpy's PTRS does), not a division error.
    """
    u = uniform - 0.5
    u_s = 0.5 - abs(u)
    return np.floor((2.0 * a / u_s + b) * u + mean + 0.43), u_s


@numba.njit(cache=True)
def _squeezed(b, u_s, v):
    """Whether the try (u_s, V) falls in PTRS's squeeze: accepted without the density."""
    return u_s >= 0.07 and v <= 0.9277 - 3.6224 / (b - 2.0)


@numba.njit(cache=True)
def _accepted(mean, b, a, k, u_s, v):
    """PTRS's test of a try (k, u_s, V) outside the squeeze: V·c/(a/u_s² + b) <= P(N = k).

    c = 1.1239 + 1.1328/(b − 3.4) is numpy's ``invalpha``.
    """
    if k < 0.0 or (u_s < 0.013 and v > u_s):
        return False
    inv_alpha = 1.1239 + 1.1328 / (b - 3.4)
    return math.log(v * inv_alpha / (a / (u_s * u_s) + b)) <= _log_pmf(k, mean)


@numba.njit(cache=True)
def _search(searched, m):
    """Sequential search, for the `m` values of a block at once (a loop numba vectorises).

    ``searched[4, :m]`` becomes the least k with W < P(N <= k), N ~ Poisson(λ), for the
    means λ < 10 (no underflow of e^-λ) in ``searched[0]`` and the uniforms W in
    ``searched[1]``; rows 2 and 3 hold the terms e^-λ λ^k/k! and their sums P(N <= k).
    """
    for j in range(m):
        searched[2, j] = math.exp(-searched[0, j])
        searched[3, j] = searched[2, j]
        searched[4, j] = 0.0
    for k in range(1, _SEARCH_STEPS + 1):
        going = False
        for j in range(m):
            above = searched[1, j] >= searched[3, j]
            searched[4, j] += above
            going |= above
            searched[2, j] *= searched[0, j] / k
            searched[3, j] += searched[2, j]
        if not going:
            return


@numba.njit(cache=True)
def _log_pmf(k, mean):
    """The logarithm ln P(N = k), N ~ Poisson(`mean`), of an integral k >= 0 (a float) [1].

    From the table of ln k! below 2048. Above, with d = k − λ: ln P = d − k ln(1 + d/λ) −
    ½ ln(2πk) − c(k), where c(k) = ln k! − (k ln k − k + ½ ln 2πk) is Stirling's series to
    k⁻⁷ (truncation error < 1e-32): no terms of size k ln λ cancel.
    """
    if k < _LOG_FACTORIALS.size:
        return k * math.log(mean) - mean - _LOG_FACTORIALS[int(k)]
    r = 1.0 / k
    r2 = r * r
    stirling = r * (1.0 / 12.0 - r2 * (1.0 / 360.0 - r2 * (1.0 / 1260.0 - r2 / 1680.0)))
    d = k - mean
    return d - k * math.log1p(d / mean) - 0.5 * math.log(2.0 * math.pi * k) - stirling


def shot_noise(expected, *, rng, gain=1.0, excess_noise=1.0):
    r"""Draw a noisy image from its expected photoelectron counts.

    Parameters
    ----------
    expected : ndarray or torch.Tensor
        Mean photoelectron count λ of every pixel [photoelectrons], >= 0.
    rng : numpy.random.Generator or torch.Generator
        Source of randomness: a numpy generator for an ndarray, a torch generator on the
        tensor's device for a tensor (`workers.backends.backend.Backend.generator`).
    gain : float, optional
        Mean output counts per photoelectron G of the intensifier [counts/photoelectron].
    excess_noise : float, optional
        Excess-noise factor F >= 1 of the gain stage [1].

    Returns
    -------
    ndarray or torch.Tensor, float32
        Counts, on the backend of `expected`. With ``gain == excess_noise == 1`` these
        are the photoelectron counts :math:`n \sim \mathrm{Poisson}(\lambda)` (paper §4.7),
        drawn by `poisson_counts` for an ndarray, by ``torch.poisson`` for a tensor.

    Notes
    -----
    Each photoelectron is amplified independently with mean G and variance
    :math:`G^2(F-1)`. The sum of n such gains is drawn as one Gamma variable of shape
    n/(F-1) and scale G(F-1), so that

    .. math:: \mathrm{E}[c] = G\lambda,\qquad \mathrm{Var}[c] = G^2 F \lambda,

    the usual definition of the excess-noise factor. With F = 1 the gain is noiseless.
    A tensor's draws are torch's (`_torch_shot_noise`): the same law, not the same bytes
    as the numpy draws; the same generator seed gives the same bytes.

    References
    ----------
    Carmona, Cérou & Blasco (2000), §4.7. Hynecek, J. & Nishiwaki, T. (2003). Excess noise
    and other important characteristics of low light level imaging using charge
    multiplying CCDs. IEEE Trans. Electron Devices 50(1), 239–245.
    """
    if type(expected).__module__.partition(".")[0] == "torch":
        return _torch_shot_noise(expected, rng=rng, gain=gain, excess_noise=excess_noise)
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


def _torch_shot_noise(expected, *, rng, gain, excess_noise):
    """`shot_noise` of a torch tensor: ``torch.poisson`` and `_torch_gamma` on `rng`.

    The means are taken to float64 first; the counts (float64, exact) go through the
    gain stage in float64 and come back as float32 on the tensor's device.
    """
    import torch

    counts = torch.poisson(expected.to(torch.float64), generator=rng)
    if excess_noise > 1.0:
        spread = excess_noise - 1.0
        amplified = torch.zeros_like(counts)
        lit = counts > 0
        amplified[lit] = _torch_gamma(counts[lit] / spread, rng=rng) * (gain * spread)
        return amplified.to(torch.float32)
    if gain != 1.0:
        return (gain * counts).to(torch.float32)
    return counts.to(torch.float32)


def _torch_gamma(shape, *, rng):
    r"""Gamma(α, 1) draws for a float64 tensor of shapes α > 0, from a torch generator.

    Parameters
    ----------
    shape : torch.Tensor
        The shapes α [1], float64, any size (α < 1 and α ~ 10⁹ alike).
    rng : torch.Generator
        On the tensor's device; ``torch.distributions`` is not used (it draws from the
        global generator).

    Returns
    -------
    torch.Tensor
        The draws, float64, the shape of `shape`.

    Notes
    -----
    Marsaglia & Tsang's method for α >= 1: with d = α − 1/3, c = 1/√(9d), x standard
    normal and v = (1 + cx)³, accept dv if v > 0 and
    :math:`\ln U < x^2/2 + d - dv + d \ln v`; at least 95 % of the tries are accepted
    for every α >= 1. Vectorised: each round draws x (``torch.randn``) then U
    (``torch.rand``) for the values still waiting, in order, until none is. For α < 1
    it draws Gamma(α + 1) and multiplies by :math:`U^{1/\alpha}` (one more uniform per
    value, drawn for every value after the rounds), taken as exp(ln U / α): 0 where it
    underflows. The draws depend on the generator's state and the shapes only.

    References
    ----------
    Marsaglia, G. & Tsang, W. W. (2000). A simple method for generating gamma variables.
    ACM Trans. Math. Softw. 26(3), 363–372.
    """
    import torch

    options = {"generator": rng, "dtype": torch.float64, "device": shape.device}
    small = shape < 1.0
    d = torch.where(small, shape + 1.0, shape) - 1.0 / 3.0
    c = 1.0 / torch.sqrt(9.0 * d)
    d, c = d.reshape(-1), c.reshape(-1)
    draws = torch.empty_like(d)
    waiting = torch.arange(d.numel(), device=shape.device)
    while waiting.numel():
        dw, cw = d[waiting], c[waiting]
        x = torch.randn(waiting.shape, **options)
        u = torch.rand(waiting.shape, **options)
        v = (1.0 + cw * x) ** 3
        accept = (v > 0) & (torch.log(u) < 0.5 * x * x + dw - dw * v + dw * torch.log(v))
        draws[waiting[accept]] = (dw * v)[accept]
        waiting = waiting[~accept]
    boost = torch.exp(torch.log(torch.rand(shape.shape, **options)) / shape)
    return torch.where(small, draws.reshape(shape.shape) * boost, draws.reshape(shape.shape))
