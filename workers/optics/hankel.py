"""Wells' MTF exponent of any small-angle phase function, by Hankel transform, and its tables.

Shared by every phase function (`workers.optics.phases`): a function gives its small-angle
form s(θ), and this module turns it into D(ψ), once per function, tabulated in ln ψ.

Units: angles in rad, angular frequencies ψ in cycles/rad, phase functions in 1/sr.
"""

from __future__ import annotations

import numpy as np
from scipy import special

__all__ = ["exponent_table", "hankel_mtf_exponent", "tabled_exponent"]

_THETA_MIN = 1e-12  # lower end of the quadrature grid [rad]
_THETA_INF = 1e4  # upper end of the grid when theta_max is infinite [rad]
_LOG_STEP = 0.02  # quadrature step in ln θ
_BLOCK = 128  # ψ values per quadrature block (bounds memory at ~2 MB per array)
_TABLE_PSI = (1e-4, 1e6)  # range of the tabulated paper D(ψ) [cycles/rad]
_TABLE_PER_DECADE = 48


def _lambda(x):
    """Λ(x) = (1/x) ∫₀ˣ J0(t) dt, with Λ(0) = 1."""
    small = x < 1e-6
    integral, _ = special.itj0y0(np.where(small, 1.0, x))
    return np.where(small, 1 - x * x / 12, integral / np.where(small, 1.0, x))


def _lambda_antiderivative(x):
    """P(x) with ∫ Λ(x) dx/x = ln x − P(x): P = Λ(x) + ∫₀ˣ (1 − J0(t))/t dt."""
    return _lambda(x) + special.it2j0y0(x)[0]


def _tail_exponent(near, far, step, *, end):
    """Local power-law exponent d ln g / d ln θ from two positive samples `step` apart."""
    exponent = np.log(far / near) / step
    decaying = exponent > 0 if end == "lower" else exponent < 0
    if not decaying:
        raise ValueError(
            f"s(θ)·θ² must vanish at the {end} end of the θ range: the phase function "
            "is not integrable there (2π∫ s θ dθ diverges)"
        )
    return abs(exponent)


def hankel_mtf_exponent(phase_function, psi, *, theta_max, theta_min=_THETA_MIN, step=_LOG_STEP):
    r"""Wells' MTF exponent D(ψ) of any small-angle phase function, by Hankel transform.

    Parameters
    ----------
    phase_function : callable
        ``s(theta)`` for an ndarray of angles θ > 0 [rad], returning non-negative values
        (any normalisation: it is normalised here so that Σ(0) = 1) [1/sr].
    psi : float or array_like
        Angular frequency ψ ≥ 0 [cycles/rad]; the sign is ignored (D is even).
    theta_max : float
        Upper end of the phase function's support [rad], ``numpy.inf`` for the
        small-angle convention θ ∈ [0, ∞).
    theta_min : float, optional
        Lower end of the quadrature grid [rad]; below it s(θ)θ² is continued as a power
        law (default 1e-12).
    step : float, optional
        Quadrature step in ln θ (default 0.02; the error scales as step²).

    Returns
    -------
    float or ndarray
        D(ψ) [1], same shape as `psi`; D(0) = 1.

    Notes
    -----
    With the normalised s,

    .. math::

        \Sigma(\psi) = 2\pi\int_0^{\theta_{max}} s(\theta)\,J_0(2\pi\theta\psi)\,\theta\,
        d\theta, \qquad
        D(\psi) = \frac{1}{\psi}\int_0^\psi\Sigma(\psi')\,d\psi'
                = 2\pi\int_0^{\theta_{max}} s(\theta)\,\theta\,\Lambda(2\pi\theta\psi)\,
                d\theta,

    where :math:`\Lambda(x) = \frac1x\int_0^x J_0(t)\,dt`
    :math:`= J_0(x) + \frac{\pi}{2}\left(J_1(x)H_0(x) - J_0(x)H_1(x)\right)` (Struve
    H); the integral of J0 is taken from :func:`scipy.special.itj0y0`, which agrees with
    the Struve form and is ~40 times faster. (The paper prints Σ with the upper limit
    2π where the support of s, π, is meant.)

    The substitution t = ln θ turns the integral into
    :math:`2\pi\int s\,\theta^2\,\Lambda\,dt`, which removes an integrable singularity
    of s at θ = 0 such as the paper's θ^(-3/2): the integrand decays exponentially in t.
    On a uniform t grid, :math:`g = s\theta^2` is taken constant over each cell and Λ is
    integrated exactly over the cell,
    :math:`\int\Lambda\,dt = [\ln x - \Lambda(x) - \int_0^x (1-J_0)/t\,dt]`
    (:func:`scipy.special.it2j0y0`), a product-integration rule that stays accurate when
    Λ oscillates faster than the grid (large ψθ) and converges as step². Below
    `theta_min`, and beyond ``1e4`` rad when `theta_max` is infinite, g is continued as
    the power law through its two end samples and Λ is held at its end value (exact as
    ψ → 0, and a negligible share of D otherwise). The normalisation uses the same rule,
    so D(0) = 1 to rounding. With the default step, D matches Wells' closed form to
    3e-5 (relative) for ψ ≤ 1e3, and the paper's phase function to 1e-5 against adaptive
    quadrature.

    References
    ----------
    Wells, W. H. (1973). Theory of small angle scattering. In *Optics of the Sea*, AGARD
    Lecture Series 61, §3. NATO AGARD, Neuilly-sur-Seine.

    Carmona, R., Cérou, F. & Blasco, B. (2000). Lidar imaging through the ocean surface,
    §4.4 "Scattering Computations".
    """
    if not 0 < theta_min < theta_max:
        raise ValueError("need 0 < theta_min < theta_max")
    infinite = np.isinf(theta_max)
    upper = _THETA_INF if infinite else theta_max
    count = int(np.ceil(np.log(upper / theta_min) / step)) + 1
    t = np.linspace(np.log(theta_min), np.log(upper), count)
    h = t[1] - t[0]
    theta = np.exp(t)
    g = np.asarray(phase_function(theta), dtype=np.float64) * theta * theta
    edges = np.concatenate([t[:1], 0.5 * (t[1:] + t[:-1]), t[-1:]])
    width = np.diff(edges)

    lower_tail = g[0] / _tail_exponent(g[0], g[1], h, end="lower") if g[0] > 0 else 0.0
    upper_tail = 0.0
    if infinite and g[-1] > 0:
        upper_tail = g[-1] / _tail_exponent(g[-2], g[-1], h, end="upper")
    norm = width @ g + lower_tail + upper_tail

    psi = np.abs(np.asarray(psi, dtype=np.float64))
    flat = psi.reshape(-1)
    out = np.empty_like(flat)
    for start in range(0, flat.size, _BLOCK):
        x = 2 * np.pi * flat[start : start + _BLOCK, None] * np.exp(edges)
        cells = width - np.diff(_lambda_antiderivative(x), axis=-1)
        total = cells @ g + lower_tail * _lambda(x[:, 0]) + upper_tail * _lambda(x[:, -1])
        out[start : start + _BLOCK] = total / norm
    return out.reshape(psi.shape)[()]


def exponent_table(phase_function, theta_max):
    """D(ψ) of a small-angle phase function tabulated on a log grid of ψ.

    Parameters
    ----------
    phase_function : callable
        s(θ) [1/sr], as for `hankel_mtf_exponent`.
    theta_max : float
        Upper end of its support [rad] (``numpy.inf`` allowed).

    Returns
    -------
    log_psi, exponent : ndarray
        ln ψ [ln cycles/rad] on 481 points over ψ ∈ [1e-4, 1e6] and D there [1];
        read-only.
    """
    low, high = _TABLE_PSI
    count = round(np.log10(high / low) * _TABLE_PER_DECADE) + 1
    psi = np.geomspace(low, high, count)
    exponent = hankel_mtf_exponent(phase_function, psi, theta_max=theta_max)
    log_psi = np.log(psi)
    log_psi.flags.writeable = False
    exponent.flags.writeable = False
    return log_psi, exponent


def tabled_exponent(table, psi, *, tail):
    """D(ψ) interpolated in ln ψ from a table of `exponent_table`.

    Parameters
    ----------
    table : tuple of ndarray
        (ln ψ, D) from `exponent_table`.
    psi : float or array_like
        Angular frequency ψ [cycles/rad]; the sign is ignored.
    tail : float
        Exponent a of the law D ∝ ψ^-a continued beyond the table [1].

    Returns
    -------
    float or ndarray
        D(ψ) [1], shape of `psi`: 1 below the table, interpolated linearly in ln ψ on it.
    """
    log_table, d_table = table
    psi = np.abs(np.asarray(psi, dtype=np.float64))
    tiny = np.finfo(np.float64).tiny
    exponent = np.interp(np.log(np.maximum(psi, tiny)), log_table, d_table, left=1.0)
    psi_max = _TABLE_PSI[1]
    beyond = psi > psi_max
    if np.any(beyond):
        continued = d_table[-1] * (psi_max / np.maximum(psi, psi_max)) ** tail
        exponent = np.where(beyond, continued, exponent)
    return exponent[()]
