"""Water-column optics: Petzold IOPs, Wells' small-angle MTF, gated water backscatter.

Paper §4.4 and §4.6; docs/model.md §4–5.

Units: coefficients in 1/m, β(π) in 1/(m·sr), angles in rad, spatial frequencies in
cycles/m, angular frequencies ψ in cycles/rad, depths and ranges in m (depth positive
down).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np
from scipy import special

from workers.optics.phase import BETA_PI_PER_BACKSCATTER, fit_fournier_forand, fournier_forand

__all__ = [
    "BETA_PI_PER_BACKSCATTER",
    "PRESETS",
    "WaterOptics",
    "fournier_forand_mtf_exponent",
    "hankel_mtf_exponent",
    "paper_mtf_exponent",
    "paper_phase_function",
    "slab_backscatter_centroid",
    "slab_backscatter_reflectance",
    "wells_mtf_exponent",
    "wells_phase_function",
]

# Petzold (1972) via Mobley (1994), Light and Water, Table 3.10 (λ ≈ 514 nm):
# absorption a, scattering b [1/m] and backscatter fraction B = b_b/b [1].
_PETZOLD = {
    "clear_ocean": (0.114, 0.037, 0.044),
    "coastal": (0.179, 0.219, 0.013),
    "turbid_harbour": (0.366, 1.824, 0.019),
}

PRESETS = MappingProxyType(
    {
        name: MappingProxyType({"absorption": a, "scattering": b, "backscatter": fraction * b})
        for name, (a, b, fraction) in _PETZOLD.items()
    }
)
"""Petzold water types: name → read-only ``{absorption, scattering, backscatter}`` [1/m].

``backscatter`` is b_b = B·b with the backscatter fraction B of the same table
(clear ocean 0.044, coastal 0.013, turbid harbour 0.019). Source: Petzold (1972), as
tabulated in Mobley (1994), *Light and Water*, Table 3.10.
"""

_THETA_MIN = 1e-12  # lower end of the quadrature grid [rad]
_THETA_INF = 1e4  # upper end of the grid when theta_max is infinite [rad]
_LOG_STEP = 0.02  # quadrature step in ln θ
_BLOCK = 128  # ψ values per quadrature block (bounds memory at ~2 MB per array)
_TABLE_PSI = (1e-4, 1e6)  # range of the tabulated paper D(ψ) [cycles/rad]
_TABLE_PER_DECADE = 48


def wells_phase_function(theta, *, theta0):
    r"""Evaluate Wells' small-angle phase function, the one with a closed-form MTF exponent.

    Parameters
    ----------
    theta : float or array_like
        Scattering angle θ ≥ 0 [rad], small-angle (plane) variable on [0, ∞).
    theta0 : float
        Angular scale θ0 > 0 [rad].

    Returns
    -------
    float or ndarray
        :math:`s(\theta) = \frac{\theta_0}{2\pi(\theta_0^2+\theta^2)^{3/2}}` [1/sr],
        normalised so that :math:`2\pi\int_0^\infty s(\theta)\,\theta\,d\theta = 1`.

    References
    ----------
    Wells, W. H. (1973). Theory of small angle scattering. In *Optics of the Sea*, AGARD
    Lecture Series 61, §3.3. NATO AGARD, Neuilly-sur-Seine.
    """
    theta = np.asarray(theta, dtype=np.float64)
    return (theta0 / (2 * np.pi) * (theta0 * theta0 + theta * theta) ** -1.5)[()]


@functools.lru_cache(maxsize=16)
def _paper_normalisation(theta0):
    """Integral of θ^(-1/2) (θ0² + θ²)^(-1/2) over [0, π] (Legendre form, see below)."""
    return special.ellipkinc(2 * np.arctan(np.sqrt(np.pi / theta0)), 0.5) / np.sqrt(theta0)


def paper_phase_function(theta, *, theta0):
    r"""Evaluate the paper's small-angle phase function (§4.4), normalised so Σ(0) = 1.

    Parameters
    ----------
    theta : float or array_like
        Scattering angle θ > 0 [rad] (s diverges at θ = 0).
    theta0 : float
        Angular scale θ0 > 0 [rad] (paper: 0.12).

    Returns
    -------
    float or ndarray
        :math:`s(\theta) = s_0\,\theta^{-3/2}(\theta_0^2+\theta^2)^{-1/2}` on
        0 < θ ≤ π and 0 beyond [1/sr], with s0 such that
        :math:`\Sigma(0) = 2\pi\int_0^\pi s(\theta)\,\theta\,d\theta = 1`.

    Notes
    -----
    The normalising integral reduces (u = √θ) to
    :math:`\int_0^\pi \theta^{-1/2}(\theta_0^2+\theta^2)^{-1/2}d\theta
    = F\!\left(2\arctan\sqrt{\pi/\theta_0}\,\middle|\,\tfrac12\right)/\sqrt{\theta_0}`,
    an incomplete elliptic integral of the first kind (parameter m = 1/2), evaluated with
    :func:`scipy.special.ellipkinc`.

    References
    ----------
    Carmona, R., Cérou, F. & Blasco, B. (2000). Lidar imaging through the ocean surface,
    §4.4 "Scattering Computations".
    """
    theta = np.asarray(theta, dtype=np.float64)
    s0 = 1 / (2 * np.pi * _paper_normalisation(float(theta0)))
    s = s0 * theta**-1.5 / np.sqrt(theta0 * theta0 + theta * theta)
    return np.where(theta <= np.pi, s, 0.0)[()]


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


def wells_mtf_exponent(psi, *, theta0):
    r"""Closed-form MTF exponent D(ψ) of `wells_phase_function`.

    Parameters
    ----------
    psi : float or array_like
        Angular frequency ψ [cycles/rad]; the sign is ignored.
    theta0 : float
        Angular scale θ0 [rad].

    Returns
    -------
    float or ndarray
        :math:`D(\psi) = \frac{1 - e^{-2\pi\theta_0\psi}}{2\pi\theta_0\psi}` [1], with
        D(0) = 1 (evaluated as ``exprel(-2π θ0 ψ)``, no cancellation near 0).

    Notes
    -----
    Σ(ψ) = exp(−2πθ0ψ) is the Hankel transform of the phase function on θ ∈ [0, ∞).

    References
    ----------
    Wells, W. H. (1973). Theory of small angle scattering. In *Optics of the Sea*, AGARD
    Lecture Series 61, §3.3. NATO AGARD, Neuilly-sur-Seine.
    """
    psi = np.abs(np.asarray(psi, dtype=np.float64))
    return special.exprel(-2 * np.pi * theta0 * psi)[()]


def _exponent_table(phase_function, theta_max):
    """(ln ψ, D(ψ)) of a small-angle phase function on a log grid; read-only arrays."""
    low, high = _TABLE_PSI
    count = round(np.log10(high / low) * _TABLE_PER_DECADE) + 1
    psi = np.geomspace(low, high, count)
    exponent = hankel_mtf_exponent(phase_function, psi, theta_max=theta_max)
    log_psi = np.log(psi)
    log_psi.flags.writeable = False
    exponent.flags.writeable = False
    return log_psi, exponent


def _tabled_exponent(table, psi, *, tail):
    """D(ψ) interpolated in ln ψ from `table`, 1 below it, ψ^-`tail` beyond it."""
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


@functools.lru_cache(maxsize=16)
def _paper_exponent_table(theta0):
    return _exponent_table(functools.partial(paper_phase_function, theta0=theta0), np.pi)


def _forward_fournier_forand(backscatter_fraction):
    """The fitted Fournier–Forand function in the small-angle measure θ dθ, and its μ."""
    n, mu = fit_fournier_forand(backscatter_fraction)

    def forward(theta):
        return fournier_forand(theta, n=n, mu=mu) * np.sin(theta) / theta

    return forward, mu


@functools.lru_cache(maxsize=64)
def _fournier_forand_exponent_table(backscatter_fraction):
    forward, mu = _forward_fournier_forand(backscatter_fraction)
    return _exponent_table(forward, 0.5 * np.pi), mu


def fournier_forand_mtf_exponent(psi, *, backscatter_fraction):
    r"""MTF exponent D(ψ) of the forward half of the fitted Fournier–Forand function.

    Parameters
    ----------
    psi : float or array_like
        Angular frequency ψ [cycles/rad]; the sign is ignored.
    backscatter_fraction : float
        b_b/b of the water, in `workers.optics.phase.FF_FRACTIONS` [1].

    Returns
    -------
    float or ndarray
        D(ψ) in (0, 1], decreasing, D(0) = 1 [1], same shape as `psi`.

    Notes
    -----
    The phase function is `workers.optics.phase.fit_fournier_forand`'s, the one the Monte Carlo
    renderer samples by default (same b_b/b, β(π) = 0.174 b_b), on 0 < θ ≤ π/2: its
    forward part, scattered at the rate b_f = b − b_b; its β̃ sin θ / θ is transformed
    (`hankel_mtf_exponent`), so that Wells' small-angle measure θ dθ integrates the 3-D
    function's sin θ dθ. Tabulated once per b_b/b as `paper_mtf_exponent`; beyond the
    table D follows this function's large-ψ law :math:`D \propto \psi^{-(\mu-3)}` (from
    its :math:`\tilde\beta \propto \theta^{-(5-\mu)}` core), μ its Junge slope.

    References
    ----------
    Fournier, G. R. & Jonasz, M. (1999). Computer-based underwater imaging analysis.
    Proc. SPIE 3761, 62–70.
    """
    table, mu = _fournier_forand_exponent_table(float(backscatter_fraction))
    return _tabled_exponent(table, psi, tail=mu - 3.0)


def paper_mtf_exponent(psi, *, theta0):
    r"""MTF exponent D(ψ) of `paper_phase_function`, from a cached table.

    Parameters
    ----------
    psi : float or array_like
        Angular frequency ψ [cycles/rad]; the sign is ignored.
    theta0 : float
        Angular scale θ0 [rad] (paper: 0.12).

    Returns
    -------
    float or ndarray
        D(ψ) in (0, 1], decreasing, D(0) = 1 [1], same shape as `psi`.

    Notes
    -----
    D is computed once per θ0 (``functools.lru_cache``, ~0.2 s) with
    `hankel_mtf_exponent` on 481 points log-spaced over ψ ∈ [1e-4, 1e6] and then
    interpolated linearly in ln ψ (interpolation error below 3e-5 in D). Below the table
    D = 1 (the true deficit there is below 1e-8). Beyond it D follows the exact
    large-ψ law of this phase function, :math:`D \propto \psi^{-1/2}` (from its
    :math:`\theta^{-3/2}` core), continued from the last tabulated value; the next-order
    correction is below 0.1 % there.

    References
    ----------
    Carmona, R., Cérou, F. & Blasco, B. (2000). Lidar imaging through the ocean surface,
    §4.4 "Scattering Computations".
    """
    return _tabled_exponent(_paper_exponent_table(float(theta0)), psi, tail=0.5)


def _slab(top, bottom, diffuse_attenuation):
    """Slab bounds and K as float64 arrays, checked (top <= bottom, K >= 0)."""
    top, bottom, k = (np.asarray(v, dtype=np.float64) for v in (top, bottom, diffuse_attenuation))
    if np.any(bottom < top) or np.any(k < 0):
        raise ValueError("need top <= bottom and diffuse_attenuation >= 0")
    return top, bottom, k


def slab_backscatter_reflectance(*, backscatter_pi, diffuse_attenuation, top, bottom, reference):
    r"""Effective Lambertian reflectance of the water backscatter from a depth slab.

    Parameters
    ----------
    backscatter_pi : float or array_like
        Volume scattering function at 180°, β(π) [1/(m·sr)].
    diffuse_attenuation : float or array_like
        Diffuse attenuation coefficient K ≥ 0 [1/m] (the paper's K_d).
    top, bottom : float or array_like
        Depths of the slab's top and bottom, ``top <= bottom`` [m].
    reference : float or array_like
        Depth of the plane carrying the reflectance [m]; round-trip attenuation is
        referred to it.

    Returns
    -------
    float or ndarray
        Reflectance R [1] (dimensionless, Lambertian convention).

    Notes
    -----
    Single scattering, with two-way attenuation e^(−2K·) counted from the reference
    plane:

    .. math::

        R = \pi\beta(\pi)\int_{z_{top}}^{z_{bot}} e^{-2K(z - z_{ref})}\,dz
          = \pi\beta(\pi)\,e^{-2K(z_{top}-z_{ref})}\,
            \frac{1 - e^{-2K\Delta Z}}{2K},\qquad \Delta Z = z_{bot} - z_{top}.

    With ``reference = top`` this is the paper's :math:`R = \frac{s_b}{2K}
    (1 - e^{-2K_d\Delta Z_g})` with :math:`s_b = \pi\beta(\pi)`. The paper places R on
    the plane at the *bottom* of the gate while referring the attenuation to its top;
    here the plane and the attenuation reference coincide, so the light reaching the
    plane (which already carries e^(−K z_ref) each way) is not attenuated twice. The
    paper writes :math:`s_b \approx \pi s(\pi)` with its small-angle s; that s is a
    forward-peak model, so β(π) is taken from b_b instead (`WaterOptics.backscatter_pi`).
    The factor (1 − e^(−2KΔZ))/(2K) is evaluated as ΔZ·exprel(−2KΔZ), finite at K = 0
    (R = πβ(π)ΔZ).

    References
    ----------
    Carmona, R., Cérou, F. & Blasco, B. (2000). Lidar imaging through the ocean surface,
    §4.6 "Backscattering in the Gated Region".
    """
    top, bottom, k = _slab(top, bottom, diffuse_attenuation)
    thickness = bottom - top
    slab = thickness * special.exprel(-2 * k * thickness)
    return (np.pi * backscatter_pi * slab * np.exp(-2 * k * (top - reference)))[()]


def slab_backscatter_centroid(*, diffuse_attenuation, top, bottom):
    r"""Depth of the e^(−2Kz)-weighted centroid of a slab (where its backscatter comes from).

    Parameters
    ----------
    diffuse_attenuation : float or array_like
        Diffuse attenuation coefficient K ≥ 0 [1/m].
    top, bottom : float or array_like
        Depths of the slab's top and bottom, ``top <= bottom`` [m].

    Returns
    -------
    float or ndarray
        Centroid depth [m], in [top, (top + bottom)/2]; the midpoint when K = 0.

    Notes
    -----
    .. math::

        \bar z = \frac{\int z\,e^{-2Kz}dz}{\int e^{-2Kz}dz}
               = z_{top} + \Delta Z\left(\frac1x - \frac{1}{e^x - 1}\right),
        \qquad x = 2K\Delta Z,

    with the series :math:`\frac12 - \frac{x}{12} + \frac{x^3}{720}` for x < 1e-3
    (no cancellation, exact midpoint at K = 0). Using it as the reference plane of
    `slab_backscatter_reflectance` takes the blur of the backscatter at a representative
    depth rather than at a gate boundary; this choice is ours (the paper uses the gate
    bottom).

    References
    ----------
    Carmona, R., Cérou, F. & Blasco, B. (2000). Lidar imaging through the ocean surface,
    §4.6 "Backscattering in the Gated Region".
    """
    top, bottom, k = _slab(top, bottom, diffuse_attenuation)
    thickness = bottom - top
    x = 2 * k * thickness
    small = x < 1e-3
    safe = np.where(small, 1.0, x)
    direct = 1 / safe - np.exp(-safe) / -np.expm1(-safe)
    fraction = np.where(small, 0.5 - x / 12 + x**3 / 720, direct)
    return (top + thickness * fraction)[()]


@dataclass(frozen=True, kw_only=True, slots=True)
class WaterOptics:
    r"""Inherent optical properties of a homogeneous water column and its small-angle MTF.

    Parameters
    ----------
    absorption : float
        Absorption coefficient a ≥ 0 [1/m].
    scattering : float
        Scattering coefficient b ≥ 0 [1/m].
    backscatter : float
        Backscattering coefficient b_b, 0 ≤ b_b ≤ b [1/m].
    phase_function : {"fournier_forand", "paper", "wells"}
        Small-angle phase function for the MTF exponent: the forward half of the
        Fournier–Forand function fitted to b_b/b that the Monte Carlo renderer samples
        (`fournier_forand_mtf_exponent`), the paper's (§4.4) or Wells' (closed-form D).
    theta0 : float
        Angular scale θ0 of the phase function [rad] (paper: 0.12).
    refractive_index : float
        Refractive index of the water [1] (paper: 1.34); carried for the interface.

    Notes
    -----
    Derived coefficients: beam attenuation c = a + b, forward scattering b_f = b − b_b,
    diffuse attenuation K = c − b_f = a + b_b (the paper's K_d), and β(π) from b_b with
    Petzold's average particle ratio `BETA_PI_PER_BACKSCATTER`.

    References
    ----------
    Petzold, T. J. (1972). *Volume scattering functions for selected ocean waters*.
    SIO Ref. 72-78, Scripps Institution of Oceanography, La Jolla.

    Mobley, C. D. (1994). *Light and Water: Radiative Transfer in Natural Waters*.
    Academic Press, Table 3.10.

    Wells, W. H. (1973). Theory of small angle scattering. In *Optics of the Sea*, AGARD
    Lecture Series 61. NATO AGARD, Neuilly-sur-Seine.
    """

    absorption: float
    scattering: float
    backscatter: float
    phase_function: str = "fournier_forand"
    theta0: float = 0.12
    refractive_index: float = 1.34

    def __post_init__(self):
        if not (self.absorption >= 0 and self.scattering >= 0):
            raise ValueError("absorption and scattering must be >= 0")
        if not 0 <= self.backscatter <= self.scattering:
            raise ValueError("backscatter must lie in [0, scattering]")
        if self.phase_function not in ("fournier_forand", "paper", "wells"):
            raise ValueError(
                "phase_function must be 'fournier_forand', 'paper' or 'wells', not "
                f"{self.phase_function!r}"
            )
        if not self.theta0 > 0:
            raise ValueError("theta0 must be > 0")
        if not self.refractive_index >= 1:
            raise ValueError("refractive_index must be >= 1")

    @classmethod
    def from_preset(cls, name, **overrides):
        """Water of a Petzold type (`PRESETS`), with any field overridden by keyword.

        Parameters
        ----------
        name : {"clear_ocean", "coastal", "turbid_harbour"}
            Petzold water type.
        **overrides
            Any `WaterOptics` field, e.g. ``theta0=0.1`` or ``absorption=0.2`` [SI units].

        Returns
        -------
        WaterOptics
        """
        if name not in PRESETS:
            raise ValueError(f"unknown water preset {name!r}; choose from {sorted(PRESETS)}")
        return cls(**{**PRESETS[name], **overrides})

    @property
    def attenuation(self):
        """Beam attenuation coefficient c = a + b [1/m]."""
        return self.absorption + self.scattering

    @property
    def forward_scattering(self):
        """Forward scattering coefficient b_f = b − b_b [1/m]."""
        return self.scattering - self.backscatter

    @property
    def diffuse_attenuation(self):
        """Diffuse attenuation coefficient K = c − b_f = a + b_b [1/m] (paper: K_d)."""
        return self.attenuation - self.forward_scattering

    @property
    def backscatter_pi(self):
        """Volume scattering function at 180°, β(π) = 0.174 sr⁻¹ · b_b [1/(m·sr)]."""
        return BETA_PI_PER_BACKSCATTER * self.backscatter

    def small_angle_phase_function(self):
        """The small-angle phase function of this water, and the end of its support.

        Returns
        -------
        function : callable
            s(θ) for an ndarray of θ [rad] [1/sr], in the small-angle measure θ dθ (any
            normalisation): what `mtf_exponent` transforms.
        theta_max : float
            Upper end of its support [rad] (π/2: the Fournier–Forand function's forward
            half; π: the paper's; ∞: Wells').
        """
        if self.phase_function == "wells":
            return functools.partial(wells_phase_function, theta0=self.theta0), np.inf
        if self.phase_function == "paper":
            return functools.partial(paper_phase_function, theta0=self.theta0), np.pi
        forward, _ = _forward_fournier_forand(self.backscatter / self.scattering)
        return forward, 0.5 * np.pi

    def mtf_exponent(self, psi):
        """Wells' MTF exponent D(ψ) of this water's phase function [1].

        Parameters
        ----------
        psi : float or array_like
            Angular frequency ψ [cycles/rad].

        Returns
        -------
        float or ndarray
            D(ψ), see `fournier_forand_mtf_exponent`, `paper_mtf_exponent` and
            `wells_mtf_exponent`.
        """
        if self.phase_function == "wells":
            return wells_mtf_exponent(psi, theta0=self.theta0)
        if self.phase_function == "paper":
            return paper_mtf_exponent(psi, theta0=self.theta0)
        if self.forward_scattering == 0:  # D is then multiplied by b_f = 0
            return np.ones_like(np.asarray(psi, dtype=np.float64))[()]
        return fournier_forand_mtf_exponent(
            psi, backscatter_fraction=self.backscatter / self.scattering
        )

    def mtf(self, frequency, *, distance):
        r"""Small-angle MTF of a water path, sampled at spatial frequencies on a plane.

        Parameters
        ----------
        frequency : float or array_like
            Spatial frequency magnitude f on the plane [cycles/m], any shape (e.g. the
            ``hypot`` of an ``rfft2`` frequency grid); the sign is ignored.
        distance : float
            Water path length z from the source/receiver plane to this plane, ≥ 0 [m].

        Returns
        -------
        numpy.float32 or ndarray of float32
            MTF values [1], shape of `frequency`: e^(−Kz) at f = 0, decreasing to e^(−cz)
            at high frequency.

        Notes
        -----
        .. math:: \mathrm{MTF}(f; z) = \exp\left(-cz + b_f z\,D(\psi)\right),
                  \qquad \psi = f z,

        ψ in cycles/rad: a pattern of f cycles/m at range z subtends f·z cycles per
        radian (small angles). The paper's "e^(−ct)" is e^(−cz).

        References
        ----------
        Wells, W. H. (1973). Theory of small angle scattering. In *Optics of the Sea*,
        AGARD Lecture Series 61. NATO AGARD, Neuilly-sur-Seine.

        Carmona, R., Cérou, F. & Blasco, B. (2000). Lidar imaging through the ocean
        surface, §4.4.
        """
        if not distance >= 0:
            raise ValueError("distance must be >= 0")
        psi = np.abs(np.asarray(frequency, dtype=np.float64)) * distance
        exponent = self.forward_scattering * distance * self.mtf_exponent(psi)
        return np.exp(exponent - self.attenuation * distance).astype(np.float32)
