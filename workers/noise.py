"""Sensor noise: Poisson shot noise and an optional intensifier (ICCD) gain stage."""

from __future__ import annotations

import numpy as np

__all__ = ["shot_noise"]


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
        :math:`n \sim \mathrm{Poisson}(\lambda)` (paper §4.7).

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
    counts = rng.poisson(np.asarray(expected, dtype=np.float64))
    if excess_noise > 1.0:
        spread = excess_noise - 1.0
        amplified = np.zeros(counts.shape)
        lit = counts > 0
        amplified[lit] = rng.gamma(counts[lit] / spread, gain * spread)
        return amplified.astype(np.float32)
    return (gain * counts).astype(np.float32)
