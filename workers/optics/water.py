"""Water-column optics: Petzold IOPs, Wells' small-angle MTF, gated water backscatter.

Paper §4.4 and §4.6; docs/model.md §4–5.

Units: coefficients in 1/m, β(π) in 1/(m·sr), angles in rad, spatial frequencies in
cycles/m, angular frequencies ψ in cycles/rad, depths and ranges in m (depth positive
down).
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType

import numpy as np
from scipy import special

from workers.optics.phases.base import PHASE_FUNCTIONS, PhaseFunction, phase_named

__all__ = [
    "PRESETS",
    "WaterOptics",
    "slab_backscatter_centroid",
    "slab_backscatter_reflectance",
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
    phase_function : str
        Name of a registered phase function (`workers.optics.phases`), built for this
        water (`phase`): its small-angle form gives the MTF exponent and it gives β(π)/b_b.
    theta0 : float
        Angular scale θ0 of the phase functions that have one [rad] (paper: 0.12).
    refractive_index : float
        Refractive index of the water [1] (paper: 1.34); carried for the interface.

    Notes
    -----
    Derived coefficients: beam attenuation c = a + b, forward scattering b_f = b − b_b,
    diffuse attenuation K = c − b_f = a + b_b (the paper's K_d), and β(π) from b_b with
    the phase function's ratio β(π)/b_b (Petzold's average particle ratio 0.174 sr⁻¹ for
    ``fournier_forand``, ``paper`` and ``wells``).

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
        if self.phase_function not in PHASE_FUNCTIONS:
            raise ValueError(
                f"phase_function must be one of {', '.join(sorted(PHASE_FUNCTIONS))}, not "
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
        """Volume scattering function at 180°, β(π) = (β(π)/b_b) · b_b [1/(m·sr)]."""
        if self.backscatter == 0:  # then no phase function need be built
            return 0.0
        return self.phase().backscatter_pi_per_backscatter() * self.backscatter

    def phase(self) -> PhaseFunction:
        """The water's phase function (`workers.optics.phases`), built for its b_b/b and θ0."""
        fraction = self.backscatter / self.scattering if self.scattering > 0 else float("nan")
        return phase_named(self.phase_function).for_water(
            backscatter_fraction=fraction, theta0=self.theta0
        )

    def small_angle_phase_function(self):
        """The small-angle form of this water's phase function (`PhaseFunction.small_angle`).

        Returns
        -------
        function : callable
            s(θ) for an ndarray of θ [rad] [1/sr], in the small-angle measure θ dθ (any
            normalisation): what `mtf_exponent` transforms.
        theta_max : float
            Upper end of its support [rad].
        """
        return self.phase().small_angle()

    def mtf_exponent(self, psi):
        """Wells' MTF exponent D(ψ) of this water's phase function [1].

        Parameters
        ----------
        psi : float or array_like
            Angular frequency ψ [cycles/rad].

        Returns
        -------
        float or ndarray
            D(ψ), see `workers.optics.phases.base.PhaseFunction.mtf_exponent`; 1 when
            b_f = 0 (D is then multiplied by 0).
        """
        if self.forward_scattering == 0:  # D is then multiplied by b_f = 0
            return np.ones_like(np.asarray(psi, dtype=np.float64))[()]
        return self.phase().mtf_exponent(psi)

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
