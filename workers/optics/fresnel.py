"""The air/water interface: unpolarised Fresnel reflectance and vector Snell refraction.

Snell's law and Fresnel's formula are each written once as a compiled scalar function
(`snell_cos_t`, `fresnel_unpolarised`: numba, called by the Monte Carlo kernels) and once
as its array twin (`transmitted_cosine`, `fresnel_reflectance`: any array API namespace,
numpy or torch, for the fast renderer and `workers.setup.interface`), the twins held to
the scalars by ``tests/test_optics.py``. The array functions are vectorised over leading
axes, keep ``float32`` in → ``float32`` out, and take the refractive indices as
keyword-only arguments (air ``n = 1``, sea water ``n = 1.34`` in the paper); numba
functions take them by position. Directions are unit *propagation* vectors, last axis
(x, y, z); surface normals are unit vectors of either orientation.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from array_api_compat import array_namespace, is_array_api_obj

__all__ = [
    "fresnel_reflectance",
    "fresnel_unpolarised",
    "reflect",
    "refract",
    "snell_cos_t",
    "transmitted_cosine",
]


def _float_array(values):
    """`values` as an array of floating dtype (integers and bools become float64 ndarrays).

    An array of another array API namespace (a torch tensor) is returned as it is.
    """
    if is_array_api_obj(values) and not isinstance(values, np.ndarray):
        return values
    array = np.asarray(values)
    if not np.issubdtype(array.dtype, np.floating):
        array = array.astype(np.float64)
    return array


@numba.njit(cache=True)
def snell_cos_t(cos_i, n1, n2):
    r"""Cosine of the refracted angle, light going from `n1` into `n2` (Snell's law).

    Parameters
    ----------
    cos_i : float
        Cosine of the angle of incidence, from the surface normal [1]; only its square
        counts.
    n1 : float
        Refractive index of the medium the light comes from [1].
    n2 : float
        Refractive index of the medium the light goes into [1].

    Returns
    -------
    float
        :math:`\cos\theta_t = \sqrt{1 - (n_1/n_2)^2 (1 - \cos^2\theta_i)}` [1]; 0 at and
        beyond the critical angle (total internal reflection: no transmitted ray).
    """
    ratio = n1 / n2
    k = 1.0 - ratio * ratio * (1.0 - cos_i * cos_i)
    return math.sqrt(k) if k > 0.0 else 0.0


@numba.njit(cache=True)
def fresnel_unpolarised(cos_i, n1, n2):
    """Unpolarised Fresnel reflectance, light going from `n1` into `n2` [1] (scalar).

    Parameters
    ----------
    cos_i : float
        Cosine of the angle of incidence in [0, 1] [1].
    n1 : float
        Refractive index of the medium the light comes from [1].
    n2 : float
        Refractive index of the medium the light goes into [1].

    Returns
    -------
    float
        r in [0, 1] [1]: 1 where `snell_cos_t` finds no transmitted ray. The formula and
        its references are `fresnel_reflectance`'s, its array twin.
    """
    cos_t = snell_cos_t(cos_i, n1, n2)
    if cos_t == 0.0:
        return 1.0
    r_s = (n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t)
    r_p = (n2 * cos_i - n1 * cos_t) / (n2 * cos_i + n1 * cos_t)
    return 0.5 * (r_s * r_s + r_p * r_p)


def transmitted_cosine(cos_incidence, *, n1, n2):
    """Cosine of the refracted angle (Snell's law), the array twin of `snell_cos_t`.

    Parameters
    ----------
    cos_incidence : array_like
        Cosine of the angle of incidence [1] (numpy, or any array API namespace).
    n1 : float
        Refractive index of the medium the light comes from [1].
    n2 : float
        Refractive index of the medium the light goes into [1].

    Returns
    -------
    array
        cos θ_t [1], 0 at and beyond the critical angle; same namespace and floating dtype.
    """
    cos_i = _float_array(cos_incidence)
    xp = array_namespace(cos_i)
    ratio = n1 / n2
    return xp.sqrt(xp.clip(1 - ratio * ratio * (1 - cos_i * cos_i), min=0))


def fresnel_reflectance(cos_incidence, *, n1, n2):
    r"""Unpolarised Fresnel reflectance of a plane interface, light going from `n1` into `n2`.

    Parameters
    ----------
    cos_incidence : float or array_like
        Cosine of the angle of incidence θ' in medium `n1`, measured from the surface
        normal [1] (numpy, or any array API namespace: torch on its device). Its sign is
        ignored (either normal orientation may be used).
    n1 : float
        Refractive index of the medium the light comes from [1].
    n2 : float
        Refractive index of the medium the light goes into [1].

    Returns
    -------
    float or ndarray
        Reflectance r in [0, 1] [1], the fraction of the incident energy given to the
        reflected ray; the transmittance is ``1 - r``. Equal to 1 at and beyond the
        critical angle (total internal reflection, possible only when ``n1 > n2``).
        Same shape and namespace as `cos_incidence`; ``float32`` input gives ``float32``
        output.

    Notes
    -----
    The array twin of `fresnel_unpolarised`. With
    :math:`\cos\theta_t = \sqrt{1 - (n_1/n_2)^2 (1 - \cos^2\theta')}` (`transmitted_cosine`),

    .. math::

        r_s = \frac{n_1\cos\theta' - n_2\cos\theta_t}{n_1\cos\theta' + n_2\cos\theta_t},\quad
        r_p = \frac{n_2\cos\theta' - n_1\cos\theta_t}{n_2\cos\theta' + n_1\cos\theta_t},\quad
        r = \tfrac12\left(r_s^2 + r_p^2\right).

    This is the paper's formula (§4.3),

    .. math::

        r(\theta') = \frac12\left(\frac{\sin^2(\theta'-\theta_t)}{\sin^2(\theta'+\theta_t)}
        + \frac{\tan^2(\theta'-\theta_t)}{\tan^2(\theta'+\theta_t)}\right),

    written with cosines: the sine/tangent ratios are 0/0 at normal incidence, which the
    paper patches with the separate limit :math:`r(0) = ((n_w-1)/(n_w+1))^2`; the cosine
    form is regular there and needs no special case. The critical angle for water → air is
    :math:`\arcsin(1/1.34) = 48.27°` (the paper's "48 deg"). At exactly grazing incidence
    with ``n1 == n2`` (no interface) the ray never crosses and r is reported as 1.

    References
    ----------
    Mobley, C. D. (1994). *Light and Water: Radiative Transfer in Natural Waters*.
    Academic Press, §4.2 (Fresnel's formula for unpolarised light).

    Born, M. & Wolf, E. (1999). *Principles of Optics*, 7th ed. Cambridge University
    Press, §1.5.2 (Fresnel amplitude coefficients).

    Carmona, R., Cérou, F. & Blasco, B. (2000). Lidar imaging through the ocean surface,
    §4.3 "Fresnel's Reflectance".
    """
    cos_i = _float_array(cos_incidence)
    xp = array_namespace(cos_i)
    cos_i = xp.clip(xp.abs(cos_i), max=1)
    cos_t = transmitted_cosine(cos_i, n1=n1, n2=n2)
    total = cos_t == 0
    # Denominators vanish only inside `total` (grazing with cos_t = 0); there they are
    # replaced by 1, and so are those entries.
    a, b = n1 * cos_i, n2 * cos_t
    c, d = n2 * cos_i, n1 * cos_t
    r_s = (a - b) / xp.where(total, 1.0, a + b)
    r_p = (c - d) / xp.where(total, 1.0, c + d)
    reflectance = xp.where(total, 1.0, 0.5 * (r_s * r_s + r_p * r_p))
    return reflectance[()] if isinstance(reflectance, np.ndarray) else reflectance


def reflect(direction, normal):
    r"""Specular reflection of unit propagation directions at a surface.

    Parameters
    ----------
    direction : array_like, shape (..., 3)
        Unit propagation direction ξ' of the incident rays [1].
    normal : array_like, shape (..., 3)
        Unit surface normal n, either orientation [1]; broadcasts against `direction`.

    Returns
    -------
    ndarray, shape (..., 3)
        Unit direction of the reflected rays, :math:`\xi_r = \xi' - 2(\xi'\cdot n)\,n`
        (paper, Table 2), in the dtype of the inputs.

    References
    ----------
    Mobley, C. D. (1994). *Light and Water: Radiative Transfer in Natural Waters*.
    Academic Press, §4.2.
    """
    direction = _float_array(direction)
    normal = _float_array(normal)
    cos = np.einsum("...i,...i->...", direction, normal)
    return direction - (2 * cos)[..., None] * normal


def refract(direction, normal, *, n1, n2):
    r"""Vector Snell law: transmitted directions of rays crossing from `n1` into `n2`.

    Parameters
    ----------
    direction : array_like, shape (..., 3)
        Unit propagation direction ξ' of the incident rays, in the medium of index `n1`
        [1].
    normal : array_like, shape (..., 3)
        Unit surface normal, either orientation [1]; broadcasts against `direction`. It is
        oriented internally against the incident ray, so the transmitted ray always
        continues through the interface: with an upward normal an air → water ray goes
        down and a water → air ray goes up.
    n1 : float
        Refractive index on the incident side [1].
    n2 : float
        Refractive index on the transmitted side [1].

    Returns
    -------
    transmitted : ndarray, shape (..., 3)
        Unit direction ξ_t of the transmitted rays, dtype of the inputs. Where the ray is
        totally internally reflected it holds the *reflected* direction
        :math:`\xi' - 2(\xi'\cdot n)\,n` instead (all the energy goes there, and the
        array stays free of NaN); use `total_internal_reflection` to tell the cases apart.
    total_internal_reflection : ndarray of bool, shape (...)
        True where :math:`(n_1/n_2)^2 (1 - \cos^2\theta') \ge 1`, i.e. at and beyond the
        critical angle (at it the transmitted ray would graze the surface and carry
        nothing: Fresnel's r = 1 there); only possible when ``n1 >= n2``.

    Notes
    -----
    With η = n1/n2, c = ξ'·n for the given normal and
    :math:`\cos\theta_t = \sqrt{1 - \eta^2 (1 - c^2)}` (`transmitted_cosine`),

    .. math:: \xi_t = \eta\,\xi' + \left(\operatorname{sign}(c)\cos\theta_t - \eta c\right) n,

    which is the paper's Table 2 (air-incident :math:`\xi_t = (\xi' - c'n)/n_w`,
    water-incident :math:`\xi_t = n_w\xi' - c'n`) with the normal's orientation folded
    into the sign, so callers need not flip normals. The water-incident root reads
    :math:`\sqrt{n_w(\xi'\cdot n)^2 - n_w^2 + 1}` in our copy of the paper; the correct
    :math:`\cos\theta_t = \sqrt{n_w^2(\xi'\cdot n)^2 - n_w^2 + 1}` is used here. A ray
    exactly tangent to the surface (c = ±0) has no preferred side and is sent along the
    sign of that zero. Unit inputs give unit outputs to rounding; no renormalisation is
    done.

    References
    ----------
    Mobley, C. D. (1994). *Light and Water: Radiative Transfer in Natural Waters*.
    Academic Press, §4.2 (Snell's law in vector form, Fig. 4.2).

    Carmona, R., Cérou, F. & Blasco, B. (2000). Lidar imaging through the ocean surface,
    §4.3, Table 2 "Snell's law formulae".
    """
    direction = _float_array(direction)
    normal = _float_array(normal)
    dtype = np.result_type(direction, normal)
    ratio = dtype.type(n1 / n2)
    cos = np.einsum("...i,...i->...", direction, normal)
    cos_t = transmitted_cosine(cos, n1=n1, n2=n2)
    total = cos_t == 0
    coefficient = np.copysign(cos_t, cos) - ratio * cos
    scale = ratio
    if np.any(total):
        coefficient = np.where(total, -2 * cos, coefficient)
        scale = np.where(total, 1, ratio)[..., None]
    transmitted = scale * direction + coefficient[..., None] * normal
    return transmitted, total
