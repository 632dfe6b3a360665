r"""Directional ocean wave spectra and the gravity–capillary dispersion relation.

A spectrum is a frozen dataclass. A subclass supplies two functions of the wavenumber
magnitude :math:`k` (rad/m) and the angle :math:`\varphi` (rad) measured from the wind
direction:

- :meth:`Spectrum.omnidirectional`, :math:`S(k)` in m³, with
  :math:`\operatorname{Var}\eta = \int_0^\infty S(k)\,dk`;
- :meth:`Spectrum.spreading`, :math:`\Phi(k, \varphi)` in 1/rad, with
  :math:`\int_{-\pi}^{\pi} \Phi\,d\varphi = 1`.

The base class derives from them the directional density per unit area of the
wavevector plane, :meth:`Spectrum.directional`, and the moments
:meth:`Spectrum.variance` and :meth:`Spectrum.slope_variance` (numerical quadrature in
:math:`\ln k`), in the way GSTools derives covariance and spectrum from a model's
correlation function. Sampling a surface from a spectrum lives in
:mod:`workers.sea.surface`.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

GRAVITY = 9.81
"""Acceleration of gravity, m/s²."""

SURFACE_TENSION = 0.074
"""Surface tension of sea water against air, N/m."""

WATER_DENSITY = 1025.0
"""Density of sea water, kg/m³."""

# Search grid for the support of a moment integrand: 1e-10 .. 1e10 rad/m, 8 points per
# unit of ln k. Panels of the Gauss–Legendre rule are at most _PANEL wide in ln k: the
# narrowest feature of the spectra here, the JONSWAP peak enhancement, has a standard
# deviation of about 0.14 in ln k.
_LN_K_SEARCH = np.linspace(math.log(1e-10), math.log(1e10), 369)
_NEGLIGIBLE = 1e-15
_PANEL = 0.05
_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(16)


def dispersion(k, *, gravity=GRAVITY, surface_tension=SURFACE_TENSION, density=WATER_DENSITY):
    r"""Angular frequency of deep-water gravity–capillary waves.

    .. math::

        \omega^2 = g k + \frac{\sigma}{\rho} k^3

    Parameters
    ----------
    k : array_like
        Wavenumber magnitude, rad/m (k ≥ 0).
    gravity : float, optional
        Acceleration of gravity g, m/s².
    surface_tension : float, optional
        Surface tension σ, N/m.
    density : float, optional
        Water density ρ, kg/m³.

    Returns
    -------
    numpy.ndarray
        Angular frequency ω, rad/s (float64, the shape of ``k``).

    Notes
    -----
    With the defaults the phase speed ω/k has its minimum 0.231 m/s at
    :math:`k = \sqrt{\rho g / \sigma} = 369` rad/m, the values c_m = 0.23 m/s and
    k_m = 370 rad/m of Elfouhaily et al. (1997).

    References
    ----------
    .. [1] Lamb, H. (1932). Hydrodynamics, 6th ed., ch. IX. Cambridge University Press.
    """
    k = np.asarray(k, dtype=np.float64)
    return np.sqrt(gravity * k + (surface_tension / density) * k**3)


def _on_positive(k, function: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """Evaluate ``function`` where k > 0 and return 0 elsewhere (float64, shape of k)."""
    k = np.asarray(k, dtype=np.float64)
    out = np.zeros(k.shape)
    positive = k > 0
    out[positive] = function(k[positive])
    return out[()] if out.ndim == 0 else out


def _wrap_angle(phi) -> np.ndarray:
    """Map angles (rad) to [-π, π)."""
    return np.mod(np.asarray(phi, dtype=np.float64) + np.pi, 2.0 * np.pi) - np.pi


@dataclass(frozen=True, kw_only=True)
class Spectrum(ABC):
    r"""Directional wave spectrum of a homogeneous Gaussian sea (base class).

    Subclasses supply :meth:`omnidirectional` and :meth:`spreading`; this class derives
    the directional density and its moments.

    Parameters
    ----------
    wind_speed : float
        Wind speed U₁₀ at 10 m above the sea, m/s (> 0).
    wind_direction : float, optional
        Direction the wind blows towards, rad, counter-clockwise from +x.

    Notes
    -----
    The directional density per unit area of the wavevector plane is

    .. math::

        \Psi(k_x, k_y) = \frac{S(k)\,\Phi(k, \varphi)}{k},\qquad
        \operatorname{Var}\eta = \iint \Psi\,dk_x\,dk_y,

    in m⁴, with :math:`\varphi` the angle of the wavevector from the wind direction.
    A wave component of wavevector **k** travels towards **k**.
    """

    wind_speed: float
    wind_direction: float = 0.0

    def __post_init__(self):
        if not (math.isfinite(self.wind_speed) and self.wind_speed > 0):
            raise ValueError(f"wind_speed must be a positive number of m/s, got {self.wind_speed}")
        if not math.isfinite(self.wind_direction):
            raise ValueError(f"wind_direction must be finite, got {self.wind_direction}")

    @abstractmethod
    def omnidirectional(self, k):
        """Omnidirectional elevation spectrum S(k), m³ (0 at k = 0).

        Parameters
        ----------
        k : array_like
            Wavenumber magnitude, rad/m.

        Returns
        -------
        numpy.ndarray
            S(k), m³, with Var η = ∫₀^∞ S(k) dk.
        """

    @abstractmethod
    def spreading(self, k, phi):
        """Directional spreading function Φ(k, φ), 1/rad.

        Parameters
        ----------
        k : array_like
            Wavenumber magnitude, rad/m (> 0).
        phi : array_like
            Angle of the wavevector from the wind direction, rad (broadcast with ``k``).

        Returns
        -------
        numpy.ndarray
            Φ(k, φ), 1/rad, with ∫ Φ dφ = 1 over φ ∈ [-π, π).
        """

    def directional(self, kx, ky):
        r"""Directional elevation spectrum per unit wavevector area, m⁴.

        .. math::

            \Psi(k_x, k_y) = \frac{S(k)\,\Phi(k, \varphi)}{k},\quad
            k = \sqrt{k_x^2 + k_y^2},\quad
            \varphi = \operatorname{atan2}(k_y, k_x) - \theta_w

        Parameters
        ----------
        kx, ky : array_like
            Wavevector components along x and y, rad/m (broadcast together).

        Returns
        -------
        numpy.ndarray
            Ψ, m⁴ (float64); 0 at k = 0.
        """
        kx, ky = np.broadcast_arrays(
            np.asarray(kx, dtype=np.float64), np.asarray(ky, dtype=np.float64)
        )
        k = np.hypot(kx, ky)
        out = np.zeros(k.shape)
        positive = k > 0
        kp = k[positive]
        phi = np.arctan2(ky[positive], kx[positive]) - self.wind_direction
        out[positive] = self.omnidirectional(kp) * self.spreading(kp, phi) / kp
        return out[()] if out.ndim == 0 else out

    def variance(self, *, k_min=0.0, k_max=math.inf):
        r"""Elevation variance of the waves with k_min ≤ k ≤ k_max, m².

        .. math:: \operatorname{Var}\eta = \int_{k_{min}}^{k_{max}} S(k)\,dk

        Parameters
        ----------
        k_min, k_max : float, optional
            Wavenumber band, rad/m.

        Returns
        -------
        float
            Variance, m² (``inf`` if the integral diverges).

        Notes
        -----
        See :meth:`slope_variance` for the quadrature.
        """
        return self._moment(0, k_min, k_max)

    def slope_variance(self, *, k_min=0.0, k_max=math.inf):
        r"""Mean square slope (both components) of the waves with k_min ≤ k ≤ k_max.

        .. math::

            \overline{\eta_x^2} + \overline{\eta_y^2}
            = \int_{k_{min}}^{k_{max}} k^2 S(k)\,dk

        Parameters
        ----------
        k_min, k_max : float, optional
            Wavenumber band, rad/m.

        Returns
        -------
        float
            Mean square slope, dimensionless (``inf`` if the integral diverges, as it
            does for a k⁻³ tail with ``k_max = inf``).

        Notes
        -----
        The integral is taken in u = ln k, :math:`\int k^{n+1} S(k)\,du`. The integrand
        is tabulated on 10⁻¹⁰ ≤ k ≤ 10¹⁰ rad/m to find where it exceeds 10⁻¹⁵ of its
        maximum; that support, cut to the band, is integrated by 16-point
        Gauss–Legendre panels at most 0.05 wide in u, with panel edges at the
        wavenumbers where S is not smooth (relative error ≲ 10⁻¹²). If the
        integrand is still above that threshold at an end of the table and the band
        extends past it, the integral is reported as divergent (``inf``).
        """
        return self._moment(2, k_min, k_max)

    @property
    def _kinks(self) -> tuple[float, ...]:
        """Wavenumbers (rad/m) where S(k) is not smooth: quadrature panel edges."""
        return ()

    def _moment(self, power: int, k_min: float, k_max: float) -> float:
        """∫ k^power S(k) dk over [k_min, k_max] by quadrature in ln k."""
        if not (0 <= k_min <= k_max):
            raise ValueError(f"need 0 <= k_min <= k_max, got k_min={k_min}, k_max={k_max}")
        if k_min == k_max:
            return 0.0

        def integrand(u):
            k = np.exp(u)
            return k ** (power + 1) * self.omnidirectional(k)

        values = integrand(_LN_K_SEARCH)
        peak = values.max()
        if peak <= 0:
            return 0.0
        significant = np.flatnonzero(values > _NEGLIGIBLE * peak)
        first, last = significant[0], significant[-1]
        u_min = math.log(k_min) if k_min > 0 else -math.inf
        u_max = math.log(k_max) if math.isfinite(k_max) else math.inf
        if (last == _LN_K_SEARCH.size - 1 and u_max > _LN_K_SEARCH[-1]) or (
            first == 0 and u_min < _LN_K_SEARCH[0]
        ):
            return math.inf
        lower = max(u_min, _LN_K_SEARCH[max(first - 1, 0)])
        upper = min(u_max, _LN_K_SEARCH[min(last + 1, _LN_K_SEARCH.size - 1)])
        if upper <= lower:
            return 0.0
        panels = max(1, math.ceil((upper - lower) / _PANEL))
        kinks = np.log(np.asarray(self._kinks, dtype=np.float64))
        edges = np.union1d(
            np.linspace(lower, upper, panels + 1), kinks[(kinks > lower) & (kinks < upper)]
        )
        half = 0.5 * np.diff(edges)
        nodes = (edges[:-1] + half)[:, None] + half[:, None] * _GL_NODES
        return float(np.sum(half * (integrand(nodes) @ _GL_WEIGHTS)))


@dataclass(frozen=True, kw_only=True)
class Phillips(Spectrum):
    r"""Phillips spectrum in the form of Tessendorf (2001), with a small-wave cutoff.

    .. math::

        \Psi(\mathbf k) = A\,\frac{e^{-1/(kL)^2}}{k^4}\,
        |\hat{\mathbf k}\cdot\hat{\mathbf w}|^2\,e^{-k^2\ell^2},\qquad
        L = \frac{U^2}{g},\qquad A = \frac{\alpha}{2\pi},

    so that :math:`S(k) = \tfrac{\alpha}{2} k^{-3} e^{-1/(kL)^2} e^{-k^2\ell^2}` and
    :math:`\Phi = \cos^2\varphi / \pi`.

    Parameters
    ----------
    wind_speed : float
        Wind speed U₁₀, m/s.
    wind_direction : float, optional
        Direction the wind blows towards, rad, counter-clockwise from +x.
    alpha : float, optional
        Phillips' saturation constant α (dimensionless), the α of the frequency
        spectrum :math:`\alpha g^2 \omega^{-5}`; 0.0081 is the value of Pierson &
        Moskowitz (1964).
    small_wave_cutoff : float or None, optional
        Length ℓ below which waves are suppressed, m (> 0). ``None`` means ℓ = L/1000.

    Notes
    -----
    Tessendorf leaves the amplitude A free. Here A is fixed by Phillips' saturation
    range: with deep-water dispersion ω² = gk, the frequency spectrum
    :math:`\alpha g^2\omega^{-5}` is the wavenumber spectrum
    :math:`\tfrac{\alpha}{2}k^{-3}`, and
    :math:`S(k) = \int \Psi\,k\,d\varphi = \pi A e^{\dots}/k^3`, hence
    A = α/(2π). Far above the peak and below 1/ℓ, S(k) → (α/2) k⁻³.

    Tessendorf asks only for ℓ ≪ L; the default ℓ = L/1000 is the usual choice in
    implementations of his method. Without the cutoff the mean square slope diverges
    logarithmically. Closed forms (K_ν the modified Bessel functions):
    :math:`\operatorname{Var}\eta = \tfrac{\alpha}{2}\,\ell L\,K_1(2\ell/L)`
    (→ αL²/4 as ℓ → 0) and mean square slope
    :math:`\tfrac{\alpha}{2} K_0(2\ell/L)`.

    The spreading :math:`\cos^2\varphi` puts as much energy on waves running against
    the wind as with it (Tessendorf's optional damping of those is not applied).

    References
    ----------
    .. [1] Tessendorf, J. (2001). Simulating ocean water. SIGGRAPH 2001 course notes
       "Simulating Nature: Realistic and Interactive Techniques", course 47.
    .. [2] Phillips, O. M. (1958). The equilibrium range in the spectrum of
       wind-generated waves. J. Fluid Mech. 4(4), 426–434.
    .. [3] Pierson, W. J., & Moskowitz, L. (1964). A proposed spectral form for fully
       developed wind seas based on the similarity theory of S. A. Kitaigorodskii.
       J. Geophys. Res. 69(24), 5181–5190.
    """

    alpha: float = 0.0081
    small_wave_cutoff: float | None = None

    def __post_init__(self):
        super().__post_init__()
        if not self.alpha > 0:
            raise ValueError(f"alpha must be positive, got {self.alpha}")
        if self.small_wave_cutoff is not None and not self.small_wave_cutoff > 0:
            raise ValueError(
                f"small_wave_cutoff must be positive (m), got {self.small_wave_cutoff}"
            )

    @property
    def length_scale(self) -> float:
        """L = U²/g, the largest wave arising from a continuous wind, m."""
        return self.wind_speed**2 / GRAVITY

    @property
    def cutoff_length(self) -> float:
        """ℓ, the small-wave cutoff in use, m."""
        if self.small_wave_cutoff is None:
            return self.length_scale / 1000.0
        return self.small_wave_cutoff

    def omnidirectional(self, k):
        """Omnidirectional spectrum, m³: (α/2) k⁻³ exp(-1/(kL)²) exp(-k²ℓ²).

        Parameters
        ----------
        k : array_like
            Wavenumber magnitude, rad/m.

        Returns
        -------
        numpy.ndarray
            S(k), m³.
        """
        big, small = self.length_scale, self.cutoff_length
        return _on_positive(
            k,
            lambda k: (
                0.5 * self.alpha * k**-3.0 * np.exp(-1.0 / (k * big) ** 2 - (k * small) ** 2)
            ),
        )

    def spreading(self, k, phi):
        """Spreading function cos²φ / π, 1/rad.

        Parameters
        ----------
        k : array_like
            Wavenumber magnitude, rad/m (unused: the spreading is the same at all k).
        phi : array_like
            Angle from the wind direction, rad.

        Returns
        -------
        numpy.ndarray
            Φ, 1/rad.
        """
        k, phi = np.broadcast_arrays(np.asarray(k, float), np.asarray(phi, float))
        return np.cos(phi) ** 2 / np.pi


@dataclass(frozen=True, kw_only=True)
class _FrequencySpectrum(Spectrum, ABC):
    """A spectrum defined in frequency, with the sech² spreading of Donelan et al.

    Subclasses supply :meth:`frequency_spectrum` and :attr:`peak_frequency`.
    """

    @property
    @abstractmethod
    def peak_frequency(self) -> float:
        """Angular frequency ω_p of the spectral peak, rad/s."""

    @abstractmethod
    def frequency_spectrum(self, omega):
        """Frequency spectrum S(ω), m²·s, with Var η = ∫₀^∞ S(ω) dω.

        Parameters
        ----------
        omega : array_like
            Angular frequency, rad/s (> 0).

        Returns
        -------
        numpy.ndarray
            S(ω), m²·s.
        """

    def omnidirectional(self, k):
        """Wavenumber spectrum S(k) = S(ω) dω/dk with ω = √(gk), m³.

        Parameters
        ----------
        k : array_like
            Wavenumber magnitude, rad/m.

        Returns
        -------
        numpy.ndarray
            S(k), m³.

        Notes
        -----
        The conversion uses gravity-wave dispersion, ω = √(gk), for which the
        frequency spectra were fitted; capillarity changes ω by less than 1 % below
        k = 50 rad/m. The time evolution of a synthesised surface still uses
        :func:`dispersion`.
        """

        def convert(k):
            omega = np.sqrt(GRAVITY * k)
            return self.frequency_spectrum(omega) * 0.5 * omega / k

        return _on_positive(k, convert)

    def spreading(self, k, phi):
        r"""Spreading function of Donelan, Hamilton & Hui (1985), 1/rad.

        .. math::

            \Phi = \frac{\beta}{2\tanh(\beta\pi)}\operatorname{sech}^2(\beta\varphi),
            \quad
            \beta = \begin{cases}
            2.61\,(\omega/\omega_p)^{1.3} & 0.56 < \omega/\omega_p < 0.95\\
            2.28\,(\omega/\omega_p)^{-1.3} & 0.95 \le \omega/\omega_p < 1.6\\
            1.24 & \text{otherwise}
            \end{cases}

        with ω = √(gk) and φ wrapped to [-π, π).

        Parameters
        ----------
        k : array_like
            Wavenumber magnitude, rad/m (> 0).
        phi : array_like
            Angle from the wind direction, rad.

        Returns
        -------
        numpy.ndarray
            Φ, 1/rad.

        Notes
        -----
        Donelan et al. normalise (β/2) sech²(βφ) over the whole real line; the factor
        1/tanh(βπ) (at most 1.001 here) renormalises it on [-π, π). They fitted β for
        0.56 < ω/ω_p < 1.6 and proposed 1.24 outside that range, which is used here
        (Banner's 1990 high-frequency extension is not); β jumps by at most 1 % at
        the range limits.

        References
        ----------
        .. [1] Donelan, M. A., Hamilton, J., & Hui, W. H. (1985). Directional spectra
           of wind-generated waves. Phil. Trans. R. Soc. Lond. A 315, 509–562.
        """
        k, phi = np.broadcast_arrays(np.asarray(k, float), np.asarray(phi, float))
        ratio = np.sqrt(GRAVITY * k) / self.peak_frequency
        beta = np.full(ratio.shape, 1.24)
        rising = (ratio > 0.56) & (ratio < 0.95)
        falling = (ratio >= 0.95) & (ratio < 1.6)
        beta[rising] = 2.61 * ratio[rising] ** 1.3
        beta[falling] = 2.28 * ratio[falling] ** -1.3
        return beta / (2.0 * np.tanh(beta * np.pi) * np.cosh(beta * _wrap_angle(phi)) ** 2)


@dataclass(frozen=True, kw_only=True)
class PiersonMoskowitz(_FrequencySpectrum):
    r"""Pierson–Moskowitz spectrum of a fully developed sea.

    .. math::

        S(\omega) = \alpha g^2 \omega^{-5}
        \exp\!\left[-\tfrac54\left(\frac{\omega_p}{\omega}\right)^4\right],
        \quad \alpha = 0.0081,\quad
        \omega_p = \left(\tfrac45\beta\right)^{1/4}\frac{g}{U_{19.5}},\quad
        \beta = 0.74,

    converted to wavenumber with ω = √(gk); spreading as
    :meth:`_FrequencySpectrum.spreading` (Donelan et al. 1985).

    Parameters
    ----------
    wind_speed : float
        Wind speed U₁₀, m/s.
    wind_direction : float, optional
        Direction the wind blows towards, rad, counter-clockwise from +x.

    Notes
    -----
    Pierson & Moskowitz wrote :math:`\exp[-\beta(g/U_{19.5}\omega)^4]` with the wind at
    19.5 m; the form above is the same function written with its peak frequency. The
    wind is taken as U₁₉.₅ = 1.026 U₁₀ (Stewart 2008), so ω_p = 0.855 g/U₁₀.
    Var η = αg²/(5ω_p⁴). The k⁻³ tail makes the mean square slope diverge
    logarithmically: pass a finite ``k_max`` to :meth:`slope_variance`.

    References
    ----------
    .. [1] Pierson, W. J., & Moskowitz, L. (1964). A proposed spectral form for fully
       developed wind seas based on the similarity theory of S. A. Kitaigorodskii.
       J. Geophys. Res. 69(24), 5181–5190.
    .. [2] Stewart, R. H. (2008). Introduction to Physical Oceanography, ch. 16. Texas
       A&M University.
    """

    @property
    def alpha(self) -> float:
        """Phillips constant α = 0.0081 (dimensionless)."""
        return 0.0081

    @property
    def peak_frequency(self) -> float:
        """ω_p = (0.8 × 0.74)^¼ g / (1.026 U₁₀), rad/s."""
        return (0.8 * 0.74) ** 0.25 * GRAVITY / (1.026 * self.wind_speed)

    def frequency_spectrum(self, omega):
        """Frequency spectrum S(ω), m²·s.

        Parameters
        ----------
        omega : array_like
            Angular frequency, rad/s (> 0).

        Returns
        -------
        numpy.ndarray
            S(ω), m²·s.
        """
        omega = np.asarray(omega, dtype=np.float64)
        return (
            self.alpha
            * GRAVITY**2
            * omega**-5.0
            * np.exp(-1.25 * (self.peak_frequency / omega) ** 4)
        )


@dataclass(frozen=True, kw_only=True)
class Jonswap(_FrequencySpectrum):
    r"""JONSWAP spectrum of a fetch-limited sea (Hasselmann et al. 1973).

    .. math::

        S(\omega) = \alpha g^2 \omega^{-5}
        \exp\!\left[-\tfrac54\left(\frac{\omega_p}{\omega}\right)^4\right]
        \gamma^{\exp[-(\omega-\omega_p)^2 / (2\sigma^2\omega_p^2)]},

    .. math::

        \alpha = 0.076\,\tilde x^{-0.22},\quad
        \omega_p = 2\pi \cdot 3.5\,\frac{g}{U_{10}}\,\tilde x^{-0.33},\quad
        \tilde x = \frac{g F}{U_{10}^2},\quad
        \sigma = \begin{cases}0.07 & \omega \le \omega_p\\
        0.09 & \omega > \omega_p\end{cases}

    converted to wavenumber with ω = √(gk); spreading as
    :meth:`_FrequencySpectrum.spreading` (Donelan et al. 1985).

    Parameters
    ----------
    wind_speed : float
        Wind speed U₁₀, m/s.
    fetch : float
        Fetch F, the distance over which the wind has blown, m (> 0).
    gamma : float, optional
        Peak enhancement factor γ ≥ 1 (3.3 is the JONSWAP mean).
    wind_direction : float, optional
        Direction the wind blows towards, rad, counter-clockwise from +x.

    Notes
    -----
    The fetch laws are applied at any fetch; beyond x̃ ≈ 2×10⁴ they put the peak
    below the Pierson–Moskowitz one of the same wind, a sea more than fully
    developed, which the caller should avoid. With γ = 1 the spectrum is the
    Pierson–Moskowitz shape with this α and ω_p. The k⁻³ tail makes the mean square
    slope diverge logarithmically: pass a finite ``k_max`` to :meth:`slope_variance`.

    References
    ----------
    .. [1] Hasselmann, K., et al. (1973). Measurements of wind-wave growth and swell
       decay during the Joint North Sea Wave Project (JONSWAP). Dtsch. Hydrogr. Z.,
       Suppl. A 8(12), 1–95.
    """

    fetch: float
    gamma: float = 3.3

    def __post_init__(self):
        super().__post_init__()
        if not (math.isfinite(self.fetch) and self.fetch > 0):
            raise ValueError(f"fetch must be a positive number of metres, got {self.fetch}")
        if not self.gamma >= 1:
            raise ValueError(f"gamma must be >= 1, got {self.gamma}")

    @property
    def dimensionless_fetch(self) -> float:
        """x̃ = gF/U₁₀² (dimensionless)."""
        return GRAVITY * self.fetch / self.wind_speed**2

    @property
    def alpha(self) -> float:
        """Phillips constant α = 0.076 x̃^-0.22 (dimensionless)."""
        return 0.076 * self.dimensionless_fetch**-0.22

    @property
    def peak_frequency(self) -> float:
        """ω_p = 2π · 3.5 (g/U₁₀) x̃^-0.33, rad/s."""
        return 2.0 * np.pi * 3.5 * GRAVITY / self.wind_speed * self.dimensionless_fetch**-0.33

    @property
    def _kinks(self) -> tuple[float, ...]:
        """The width σ of the peak enhancement jumps at ω_p, k = ω_p²/g."""
        return (self.peak_frequency**2 / GRAVITY,)

    def frequency_spectrum(self, omega):
        """Frequency spectrum S(ω), m²·s.

        Parameters
        ----------
        omega : array_like
            Angular frequency, rad/s (> 0).

        Returns
        -------
        numpy.ndarray
            S(ω), m²·s.
        """
        omega = np.asarray(omega, dtype=np.float64)
        peak = self.peak_frequency
        sigma = np.where(omega <= peak, 0.07, 0.09)
        enhancement = self.gamma ** np.exp(-((omega - peak) ** 2) / (2.0 * (sigma * peak) ** 2))
        return (
            self.alpha
            * GRAVITY**2
            * omega**-5.0
            * np.exp(-1.25 * (peak / omega) ** 4)
            * enhancement
        )


@dataclass(frozen=True, kw_only=True)
class Elfouhaily(Spectrum):
    r"""Unified gravity–capillary spectrum of Elfouhaily, Chapron, Katsaros & Vandemark.

    Curvature spectrum :math:`B = k^3 S = B_l + B_h` (equation numbers of the paper):

    .. math::

        B_l = \tfrac12 \alpha_p \frac{c_p}{c} F_p,\quad
        F_p = L_{PM} J_p
        \exp\!\left[-\frac{\Omega}{\sqrt{10}}\left(\sqrt{k/k_p}-1\right)\right]
        \quad (31, 32)

    .. math::

        B_h = \tfrac12 \alpha_m \frac{c_m}{c} F_m,\quad
        F_m = L_{PM}\exp\!\left[-\tfrac14\left(\frac{k}{k_m}-1\right)^2\right]
        \quad (40, 41)

    with :math:`L_{PM} = e^{-\frac54 (k_p/k)^2}`, :math:`J_p = \gamma^\Gamma`,
    :math:`\Gamma = \exp[-(\sqrt{k/k_p}-1)^2/(2\sigma^2)]`,
    γ = 1.7 (Ω_c < 1) or 1.7 + 6 log₁₀ Ω_c, σ = 0.08 (1 + 4 Ω_c⁻³) (eq. 3);
    :math:`k_p = \Omega_c^2 g / U_{10}^2`, :math:`c(k) = \sqrt{(g/k)(1 + (k/k_m)^2)}`,
    c_p = c(k_p), Ω = U₁₀/c_p; α_p = 6×10⁻³ √Ω (34);
    α_m = 10⁻² [1 + ln(u*/c_m)] for u* ≤ c_m, 10⁻² [1 + 3 ln(u*/c_m)] above (44),
    and 0 below u* = c_m/e (see Notes);
    c_m = 0.23 m/s, k_m = 370 rad/m. The friction velocity comes from the wave-age
    dependent roughness of Donelan et al. (1993) (60, 66):

    .. math::

        u_* = \frac{\kappa U_{10}}{\ln(10/z_0)},\quad
        z_0 = 3.7\times10^{-5}\,\frac{U_{10}^2}{g}\,\Omega_c^{0.9},\quad
        \kappa = 0.41.

    Spreading (49, 57, 59):

    .. math::

        \Phi = \frac{1 + \Delta(k)\cos 2\varphi}{2\pi},\quad
        \Delta = \tanh\!\left[a_0 + a_p (c/c_p)^{2.5} + a_m (c_m/c)^{2.5}\right],

    a₀ = ln 2 / 4, a_p = 4, a_m = 0.13 u*/c_m.

    Parameters
    ----------
    wind_speed : float
        Wind speed U₁₀, m/s.
    wind_direction : float, optional
        Direction the wind blows towards, rad, counter-clockwise from +x.
    inverse_wave_age : float, optional
        Ω_c = U₁₀/c_p, from 0.84 (fully developed sea, the default) to 5 (young sea),
        the range of the paper.

    Notes
    -----
    Departure from the paper: F_m as given in eq. (41) has no long-wave cutoff, so
    B_h ∝ k^{1/2} and S ∝ k^{-5/2} as k → 0 and the elevation variance diverges.
    F_m is multiplied here by L_PM, as in the implementation of Bruneton et al.
    (2010). L_PM > 0.987 for k > 10 k_p, and the factor lowers the mean square slope
    by less than 1 %.

    Departure from the paper: the short-wave equilibrium parameter of eq. (44) is a
    logarithmic law in u*/c_m, negative below u* = c_m/e = 0.085 m/s (U₁₀ = 2.68 m/s
    for Ω_c = 0.84, 2.39 m/s for Ω_c = 5). B_h is then negative and, where B_l has
    decayed, so is B = B_l + B_h (over 75–1400 rad/m at U₁₀ = 0.5 m/s, 240–2300 rad/m
    at 2 m/s): a negative energy density, whose square root, the amplitude of a
    Fourier mode of the surface, is NaN. An energy density cannot be negative: α_m
    is taken here as the law while it is positive and 0 below,
    :math:`\alpha_m = \max(0, \dots)`, i.e. no gravity–capillary saturation range
    under winds too weak to raise ripples (where the law itself reaches 0), and
    B = B_l alone. The clamp is continuous in U₁₀ (α_m → 0 at the threshold) and
    leaves the spectrum at stronger winds unchanged to the last bit.

    Assumptions: κ = 0.41 in eq. (60), the value used by Bruneton et al. (2010) for
    these equations; c_p = c(k_p) with the capillary term, as the paper writes it; Ω_c
    is an input here rather than derived from a fetch.

    The paper builds the spectrum to agree with the clean-surface mean square slope
    of Cox & Munk (1954), 0.003 + 5.12×10⁻³ U ± 0.004. The full-band
    :meth:`Spectrum.slope_variance` of this implementation (Ω_c = 0.84) is 0.0229,
    0.0322, 0.0422, 0.0622 at U₁₀ = 3, 5, 7, 10 m/s against 0.0184, 0.0286, 0.0388,
    0.0542: within that scatter at 5 and 7 m/s, above it at 3 and 10 m/s. The
    long-wave part alone gives 0.021 at every wind speed of a fully developed sea.
    With κ = 0.4 the values are 0.0225, 0.0319, 0.0411, 0.0611.

    References
    ----------
    .. [1] Elfouhaily, T., Chapron, B., Katsaros, K., & Vandemark, D. (1997). A unified
       directional spectrum for long and short wind-driven waves. J. Geophys. Res.
       102(C7), 15781–15796.
    .. [2] Donelan, M. A., Dobson, F. W., Smith, S. D., & Anderson, R. J. (1993). On the
       dependence of sea surface roughness on wave development. J. Phys. Oceanogr. 23,
       2143–2149.
    .. [3] Bruneton, E., Neyret, F., & Holzschuch, N. (2010). Real-time realistic ocean
       lighting using seamless transitions from geometry to BRDF. Computer Graphics
       Forum 29(2), 487–496.
    .. [4] Cox, C., & Munk, W. (1954). Measurement of the roughness of the sea surface
       from photographs of the sun's glitter. J. Opt. Soc. Am. 44(11), 838–850.
    """

    inverse_wave_age: float = 0.84

    C_M = 0.23
    """Minimum phase speed c_m, m/s."""
    K_M = 370.0
    """Wavenumber k_m of the minimum phase speed, rad/m."""
    VON_KARMAN = 0.41
    """Von Kármán constant κ."""

    def __post_init__(self):
        super().__post_init__()
        if not 0.84 <= self.inverse_wave_age <= 5.0:
            raise ValueError(
                f"inverse_wave_age must lie in [0.84, 5] (the paper's range), "
                f"got {self.inverse_wave_age}"
            )

    @property
    def peak_wavenumber(self) -> float:
        """k_p = Ω_c² g / U₁₀², rad/m."""
        return self.inverse_wave_age**2 * GRAVITY / self.wind_speed**2

    @property
    def friction_velocity(self) -> float:
        """u* = κ U₁₀ / ln(10 m / z₀) with the roughness z₀ of eq. (66), m/s."""
        u = self.wind_speed
        z0 = 3.7e-5 * u**2 / GRAVITY * self.inverse_wave_age**0.9
        return self.VON_KARMAN * u / math.log(10.0 / z0)

    @property
    def short_wave_equilibrium(self) -> float:
        """α_m of eq. (44), held at 0 below u* = c_m/e (see Notes), dimensionless."""
        ratio = self.friction_velocity / self.C_M
        fitted = 1e-2 * (1.0 + (1.0 if ratio <= 1.0 else 3.0) * math.log(ratio))
        return max(fitted, 0.0)

    def _phase_speed(self, k):
        """c(k) = √((g/k)(1 + (k/k_m)²)), m/s."""
        return np.sqrt(GRAVITY / k * (1.0 + (k / self.K_M) ** 2))

    def curvature(self, k):
        """Omnidirectional curvature (saturation) spectrum B(k) = k³ S(k), dimensionless.

        Parameters
        ----------
        k : array_like
            Wavenumber magnitude, rad/m.

        Returns
        -------
        numpy.ndarray
            B(k) = B_l + B_h (dimensionless).
        """
        return _on_positive(k, self._curvature)

    def _curvature(self, k):
        omega_c = self.inverse_wave_age
        k_p = self.peak_wavenumber
        c = self._phase_speed(k)
        c_p = float(self._phase_speed(k_p))
        omega = self.wind_speed / c_p
        gamma = 1.7 if omega_c < 1.0 else 1.7 + 6.0 * math.log10(omega_c)
        sigma = 0.08 * (1.0 + 4.0 * omega_c**-3)
        root = np.sqrt(k / k_p) - 1.0
        l_pm = np.exp(-1.25 * (k_p / k) ** 2)
        j_p = gamma ** np.exp(-(root**2) / (2.0 * sigma**2))
        f_p = l_pm * j_p * np.exp(-omega / math.sqrt(10.0) * root)
        b_long = 0.5 * 6e-3 * math.sqrt(omega) * (c_p / c) * f_p
        f_m = l_pm * np.exp(-0.25 * (k / self.K_M - 1.0) ** 2)
        b_short = 0.5 * self.short_wave_equilibrium * (self.C_M / c) * f_m
        return b_long + b_short

    def omnidirectional(self, k):
        """Omnidirectional spectrum S(k) = B(k)/k³, m³.

        Parameters
        ----------
        k : array_like
            Wavenumber magnitude, rad/m.

        Returns
        -------
        numpy.ndarray
            S(k), m³.
        """
        return _on_positive(k, lambda k: self._curvature(k) / k**3)

    def spreading(self, k, phi):
        """Spreading function (1 + Δ(k) cos 2φ) / (2π), 1/rad.

        Parameters
        ----------
        k : array_like
            Wavenumber magnitude, rad/m (> 0).
        phi : array_like
            Angle from the wind direction, rad.

        Returns
        -------
        numpy.ndarray
            Φ, 1/rad.
        """
        k, phi = np.broadcast_arrays(np.asarray(k, float), np.asarray(phi, float))
        c = self._phase_speed(k)
        c_p = float(self._phase_speed(self.peak_wavenumber))
        a_m = 0.13 * self.friction_velocity / self.C_M
        delta = np.tanh(math.log(2.0) / 4.0 + 4.0 * (c / c_p) ** 2.5 + a_m * (self.C_M / c) ** 2.5)
        return (1.0 + delta * np.cos(2.0 * phi)) / (2.0 * np.pi)
